//! `paddock perf`: the simulator's speed on one thread.
//!
//! Cars driven by pure pursuit lap the map (episodes restart from seeded random starts);
//! only the time inside `World::step` is counted (by the wall clock, scaled by the share of
//! the measurement's wall time this thread ran on a CPU, so other processes on the machine
//! do not count against it; reading the thread's CPU clock around every step would cost a
//! system call each, a fifth of a step without the scan), so the figure is the simulator's own
//! cost: dynamics, collisions, laps and (unless disabled) the 1080-beam LIDAR of every
//! car. Rays/s times the LIDAR alone from poses recorded on the track. The report names
//! the map and the LIDAR's code path and the CPU's SIMD features, since the scan's speed
//! depends on them (`--scan-path` forces a narrower path, to measure what a CPU without
//! AVX-512 gets; `--scan-algorithm sweep` measures the angular sweep instead of the march). `--worlds N` steps N worlds of `--agents` cars as one batch
//! (`Worlds::step`, the way an env session of N envs steps them, each world's scans
//! written into one packed buffer), still on one thread.

use std::time::{Duration, Instant};

use crate::args::{self, outln};
use anyhow::{Context, Result};
use clap::Args;
use paddock_policy::{Driver, PurePursuit, PurePursuitParams};
use paddock_sim::circuit::{Circuit, Circuits, DEFAULT_MAP};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::{
    Lidar, LidarConfig, ScanAlgorithm, ScanPath, cpu_features, cpu_model, thread_scans_by_algorithm,
};
use paddock_sim::world::{
    Action, PackedObservations, Starts, StepEvents, World, WorldConfig, Worlds,
};
use serde::Serialize;

#[derive(Args)]
pub struct PerfArgs {
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Number of cars stepped together.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<usize>(1, 64))]
    agents: usize,
    /// Worlds (of `--agents` cars each) stepped as one batch, as an env session's envs.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<usize>(1, 1024))]
    worlds: usize,
    /// Skip the measurements with the LIDAR scan.
    #[arg(long)]
    no_scan: bool,
    /// Wall-clock seconds per measurement.
    #[arg(long, default_value_t = 3.0, value_parser = args::above(0.0, 3_600.0))]
    seconds: f64,
    /// LIDAR code path: portable, avx or avx512 (default: the widest this CPU has).
    #[arg(long)]
    scan_path: Option<String>,
    /// LIDAR algorithm: the march, the angular sweep over the map's wall faces, or auto
    /// (the default: the faster of the two, timed on the first scans of the map); all
    /// give the same ranges, at speeds that depend on the map and the CPU.
    #[arg(long, value_enum, default_value_t = AlgorithmArg::Auto)]
    scan_algorithm: AlgorithmArg,
    /// Vehicle YAML of every car (as `paddock sysid` writes it; default: the f1tenth_gym
    /// vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// `--scan-algorithm`: [`ScanAlgorithm`] by name.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AlgorithmArg {
    /// The faster of the two, timed on the first scans of the map and again every few
    /// thousand scans.
    Auto,
    /// Grid march accelerated by the clearance table.
    March,
    /// Angular sweep over the map's wall faces.
    Sweep,
}

impl From<AlgorithmArg> for ScanAlgorithm {
    fn from(a: AlgorithmArg) -> ScanAlgorithm {
        match a {
            AlgorithmArg::Auto => ScanAlgorithm::Auto,
            AlgorithmArg::March => ScanAlgorithm::March,
            AlgorithmArg::Sweep => ScanAlgorithm::Sweep,
        }
    }
}

/// The scans of a measurement: code path and algorithm.
#[derive(Clone, Copy)]
struct Scan {
    path: ScanPath,
    algorithm: ScanAlgorithm,
}

#[derive(Serialize)]
struct PerfReport {
    map: String,
    /// Grid width x height in cells, and metres per cell.
    map_cells: [usize; 2],
    map_resolution: f64,
    /// The LIDAR march's code path (`portable`, `avx`, `avx512`).
    scan_path: String,
    /// How that path reads the clearance table here (`gather` or `scalar loads`).
    scan_clearance_loads: String,
    /// The vectors of the angular sweep's per-beam loops on that path here (`256-bit`,
    /// `512-bit` or `none`).
    scan_sweep_vectors: String,
    /// `auto`, `march` or `sweep`.
    scan_algorithm: ScanAlgorithm,
    /// The share of the stepping measurement's scans the sweep computed (the rest the
    /// march): 1 or 0 when forced, measured under `auto`.
    scan_sweep_share: Option<f64>,
    /// The CPU as it names itself: brand, vendor, family and model.
    cpu: String,
    /// The CPU's SIMD features, space-separated.
    cpu_features: String,
    agents: usize,
    worlds: usize,
    agent_steps_per_s_scan: Option<f64>,
    agent_steps_per_s_noscan: f64,
    rays_per_s: Option<f64>,
}

struct Run {
    agent_steps: u64,
    busy: Duration,
    poses: Vec<Pose>,
}

/// Time spent inside the steps of one measurement: summed by the wall clock (a cheap
/// read), then scaled by the share of the measurement's wall time this thread was on a
/// CPU (two reads of its CPU clock in all).
struct StepClock {
    wall0: Instant,
    cpu0: Duration,
    in_steps: Duration,
}

impl StepClock {
    fn start() -> Self {
        Self {
            wall0: Instant::now(),
            cpu0: thread_cpu(),
            in_steps: Duration::ZERO,
        }
    }

    /// Runs `step`, adding its wall time.
    fn time<T>(&mut self, step: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let out = step();
        self.in_steps += t0.elapsed();
        out
    }

    /// Wall time inside the steps so far (to end the measurement on).
    fn wall(&self) -> Duration {
        self.in_steps
    }

    /// The steps' share of this thread's CPU time: their wall time times the share of
    /// the wall time the thread ran (1 on an idle machine).
    fn busy(&self) -> Duration {
        let wall = self.wall0.elapsed().as_secs_f64();
        let cpu = thread_cpu().saturating_sub(self.cpu0).as_secs_f64();
        let share = if wall > 0.0 && cpu > 0.0 {
            (cpu / wall).min(1.0)
        } else {
            1.0
        };
        self.in_steps.mul_f64(share)
    }
}

fn drive(
    circuit: &std::sync::Arc<Circuit>,
    agents: usize,
    worlds: usize,
    scan: Option<Scan>,
    seconds: f64,
    vehicle: &paddock_sim::params::VehicleParams,
) -> Result<Run> {
    if worlds > 1 {
        return drive_batch(circuit, agents, worlds, scan, seconds, vehicle);
    }
    let mut world = perf_world(circuit, agents, scan, vehicle)?;
    let mut drivers: Vec<PurePursuit> = (0..agents)
        .map(|_| PurePursuit::on_circuit(circuit, PurePursuitParams::default()))
        .collect();
    let mut actions = vec![Action::default(); agents];
    // Stepped as rollouts and vector envs step a world: into events kept from one step
    // to the next (`World::step` allocates them afresh, three small vectors a step).
    let mut events = StepEvents::default();
    let budget = Duration::from_secs_f64(seconds.max(0.1));
    let mut clock = StepClock::start();
    let mut agent_steps = 0u64;
    let mut poses = Vec::new();
    let mut seed = 0u64;
    while clock.wall() < budget {
        world.reset(seed, &Starts::Random)?;
        drivers.iter_mut().for_each(Driver::reset);
        seed += 1;
        for step in 0..3000u32 {
            let obs = world.observation()?;
            for (i, d) in drivers.iter_mut().enumerate() {
                if step.is_multiple_of(16) && poses.len() < 4096 {
                    poses.push(Pose::new(
                        obs.poses_x[i],
                        obs.poses_y[i],
                        obs.poses_theta[i],
                    ));
                }
                actions[i] = d.act(obs, i);
            }
            clock.time(|| world.step_into(&actions, &mut events))?;
            agent_steps += agents as u64;
        }
    }
    Ok(Run {
        agent_steps,
        busy: clock.busy(),
        poses,
    })
}

/// A world of `agents` cars of `vehicle` on `circuit` (Stop mode), scanning on `path`
/// unless it is `None`.
fn perf_world(
    circuit: &std::sync::Arc<Circuit>,
    agents: usize,
    scan: Option<Scan>,
    vehicle: &paddock_sim::params::VehicleParams,
) -> Result<World> {
    let mut config = WorldConfig::with_agents(agents);
    config.collision_mode = CollisionMode::Stop;
    for a in &mut config.agents {
        a.scan = scan.is_some();
        a.params = vehicle.clone();
    }
    let mut world = World::new(circuit.clone(), config)?;
    if let Some(scan) = scan {
        world.set_scan_path(scan.path)?;
        world.set_scan_algorithm(scan.algorithm);
    }
    Ok(world)
}

/// This thread's CPU time so far.
fn thread_cpu() -> Duration {
    use nix::time::{ClockId, clock_gettime};
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID).map_or(Duration::ZERO, Duration::from)
}

/// [`drive`] for `worlds` worlds stepped as one batch; pure pursuit drives every car.
fn drive_batch(
    circuit: &std::sync::Arc<Circuit>,
    agents: usize,
    worlds: usize,
    scan: Option<Scan>,
    seconds: f64,
    vehicle: &paddock_sim::params::VehicleParams,
) -> Result<Run> {
    let world = perf_world(circuit, agents, scan, vehicle)?;
    let beams = world.config().lidar.num_beams;
    let mut batch = Worlds::of(&world, worlds);
    let cars = worlds * agents;
    let mut drivers: Vec<PurePursuit> = (0..cars)
        .map(|_| PurePursuit::on_circuit(circuit, PurePursuitParams::default()))
        .collect();
    let mut actions = vec![Action::default(); cars];
    let mut scans = vec![0u8; if scan.is_some() { cars * beams * 4 } else { 0 }];
    let budget = Duration::from_secs_f64(seconds.max(0.1));
    let mut clock = StepClock::start();
    let mut agent_steps = 0u64;
    let mut poses = Vec::new();
    let mut seed = 0u64;
    while clock.wall() < budget {
        for w in 0..worlds {
            batch.reset(w, seed, &Starts::Random)?;
            seed += 1;
        }
        drivers.iter_mut().for_each(Driver::reset);
        for step in 0..3000u32 {
            for w in 0..worlds {
                let obs = batch.world(w).observation()?;
                for i in 0..agents {
                    let d = &mut drivers[w * agents + i];
                    if step.is_multiple_of(16) && poses.len() < 4096 {
                        poses.push(Pose::new(
                            obs.poses_x[i],
                            obs.poses_y[i],
                            obs.poses_theta[i],
                        ));
                    }
                    actions[w * agents + i] = d.act(obs, i);
                }
            }
            let mut out =
                PackedObservations::scans(&mut scans, if scan.is_some() { agents } else { 0 });
            clock.time(|| batch.step(&actions, &[], Some(&mut out)))?;
            agent_steps += cars as u64;
        }
    }
    Ok(Run {
        agent_steps,
        busy: clock.busy(),
        poses,
    })
}

pub fn run(args: &PerfArgs, circuits: &Circuits) -> Result<()> {
    let name = args.map.as_deref().unwrap_or(DEFAULT_MAP);
    let circuit = circuits
        .get(name)
        .with_context(|| format!("loading map {name:?}"))?;
    anyhow::ensure!(
        (1..=64).contains(&args.agents),
        "--agents {} is out of range: must be a whole number in [1, 64]",
        args.agents
    );
    let path = match args.scan_path.as_deref() {
        // else `PADDOCK_SCAN_PATH`'s (checked at start), else the widest
        None => paddock_worker::scan_path::scan_path_from_env()?.unwrap_or_else(ScanPath::best),
        Some(name) => ScanPath::from_name(name)
            .with_context(|| format!("--scan-path {name:?} is not one of portable, avx, avx512"))?,
    };
    let algorithm = ScanAlgorithm::from(args.scan_algorithm);
    let lidar = Lidar::new(LidarConfig::default())
        .with_path(path)?
        .with_algorithm(algorithm);
    let vehicle = args::vehicle(args.vehicle.as_deref())?;
    tracing::info!(map = %circuit.name, agents = args.agents, "measuring without scan");
    let noscan = drive(
        &circuit,
        args.agents,
        args.worlds,
        None,
        args.seconds,
        &vehicle,
    )?;
    let noscan_rate = noscan.agent_steps as f64 / noscan.busy.as_secs_f64();
    let (scan_rate, rays_rate, sweep_share) = if args.no_scan {
        (None, None, None)
    } else {
        tracing::info!(map = %circuit.name, agents = args.agents, "measuring with scan");
        let (march0, sweep0) = thread_scans_by_algorithm();
        let scan = drive(
            &circuit,
            args.agents,
            args.worlds,
            Some(Scan { path, algorithm }),
            args.seconds,
            &vehicle,
        )?;
        let (march1, sweep1) = thread_scans_by_algorithm();
        let swept = (sweep1 - sweep0) as f64;
        let share = swept / (swept + (march1 - march0) as f64).max(1.0);
        let scan_rate = scan.agent_steps as f64 / scan.busy.as_secs_f64();
        let beams = LidarConfig::default().num_beams;
        let mut out = vec![0.0; beams];
        let budget = Duration::from_secs_f64(args.seconds.max(0.1));
        let mut clock = StepClock::start();
        let mut scans = 0u64;
        let mut checksum = 0.0;
        while clock.wall() < budget {
            clock.time(|| {
                for p in &noscan.poses {
                    lidar.scan(&circuit.map, *p, &[], &mut out);
                    checksum += out[beams / 2];
                    scans += 1;
                }
            });
        }
        let rays = scans as f64 * beams as f64 / clock.busy().as_secs_f64();
        tracing::debug!(checksum, "rays measured");
        (Some(scan_rate), Some(rays), Some(share))
    };
    let report = PerfReport {
        map: circuit.name.clone(),
        map_cells: [circuit.map.width(), circuit.map.height()],
        map_resolution: circuit.map.resolution(),
        scan_path: path.name().to_string(),
        scan_clearance_loads: path.clearance_loads().to_string(),
        scan_sweep_vectors: path.sweep_vectors().to_string(),
        scan_algorithm: algorithm,
        scan_sweep_share: sweep_share,
        cpu: cpu_model(),
        cpu_features: cpu_features(),
        agents: args.agents,
        worlds: args.worlds,
        agent_steps_per_s_scan: scan_rate,
        agent_steps_per_s_noscan: noscan_rate,
        rays_per_s: rays_rate,
    };
    if args.json {
        outln!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    outln!(
        "map {} ({} x {} cells of {} m), {} agent(s) x {} world(s), one thread",
        report.map,
        report.map_cells[0],
        report.map_cells[1],
        report.map_resolution,
        report.agents,
        report.worlds
    );
    outln!("  CPU {}, features: {}", report.cpu, report.cpu_features);
    outln!(
        "  LIDAR path {}, clearances by {}, {}, {}",
        report.scan_path,
        report.scan_clearance_loads,
        match report.scan_sweep_vectors.as_str() {
            "none" => "sweep without SIMD".to_string(),
            v => format!("sweep in {v} vectors"),
        },
        match (report.scan_algorithm, report.scan_sweep_share) {
            (ScanAlgorithm::March, _) => "march".to_string(),
            (ScanAlgorithm::Sweep, _) => "angular sweep".to_string(),
            (ScanAlgorithm::Auto, Some(share)) => format!(
                "auto (timed: the angular sweep took {:.0} % of the scans, the march the rest)",
                100.0 * share
            ),
            (ScanAlgorithm::Auto, None) => "auto".to_string(),
        }
    );
    if let Some(r) = report.agent_steps_per_s_scan {
        outln!("  agent-steps/s with 1080-beam scan: {r:>14.0}");
    }
    outln!(
        "  agent-steps/s without scan:        {:>14.0}",
        report.agent_steps_per_s_noscan
    );
    if let Some(r) = report.rays_per_s {
        outln!("  LIDAR rays/s:                      {r:>14.0}");
    }
    Ok(())
}
