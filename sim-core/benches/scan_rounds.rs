//! The scan and world-step rates of every LIDAR code path this CPU has, measured in
//! alternating rounds, for honest figures on a busy machine:
//! `cargo bench -p paddock-sim --bench scan_rounds -- [rounds] [ms per round] [filter]`
//! (defaults 7 and 300; with a filter, only the configurations whose names contain it),
//! best pinned to one core (`taskset -c 1`).
//!
//! Each round times every configuration once, one after the other, so that load from
//! other processes spreads over all of them alike; the report gives the median and the
//! best round of each. On Linux the time is the thread's CPU time (from
//! `/proc/thread-self/schedstat`), which leaves out the time other processes held the
//! core; the wall-clock figures are printed too. Configurations: one 1080-beam scan from
//! centreline poses on the default shipped map (and on `$PADDOCK_SHARED/maps/Spa` when
//! that is set), the seeded noise of one scan, and `World::step` with 1 and 2 cars, with
//! scans on each path and without scans; each scan by the march and by the angular sweep
//! (`... sweep`).

use std::hint::black_box;
use std::time::Instant;

use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::{Lidar, LidarConfig, ScanPath, cpu_features, cpu_model};
use paddock_sim::map::Map;
use paddock_sim::rng::Rng;
use paddock_sim::track::Track;
use paddock_sim::world::{Action, Starts, StepEvents, World, WorldConfig};

/// Nanoseconds of CPU time this thread has run, if the OS says.
fn cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// One measured thing: `run(n)` does n units of work.
struct Case<'a> {
    name: String,
    unit: &'static str,
    run: Box<dyn FnMut(u64) + 'a>,
    /// Reported amount per unit of work (millions of rays per scan, thousands of
    /// agent-steps per world step).
    scale: f64,
    /// Units per round, calibrated on the first round.
    per_round: u64,
    cpu_rates: Vec<f64>,
    wall_rates: Vec<f64>,
}

fn scan_case<'a>(
    name: String,
    map: &'a Map,
    poses: Vec<Pose>,
    path: ScanPath,
    sweep: bool,
) -> Case<'a> {
    let lidar = Lidar::new(LidarConfig::default())
        .with_path(path)
        .expect("supported path")
        .with_sweep(sweep);
    let beams = lidar.num_beams();
    let mut out = vec![0.0; beams];
    let mut i = 0;
    Case {
        name,
        unit: "M rays/s",
        scale: beams as f64 / 1e6,
        run: Box::new(move |n| {
            for _ in 0..n {
                i = (i + 1) % poses.len();
                lidar.scan(map, black_box(poses[i]), &[], &mut out);
                black_box(&out);
            }
        }),
        per_round: 0,
        cpu_rates: Vec::new(),
        wall_rates: Vec::new(),
    }
}

fn world_case<'a>(
    circuit: &std::sync::Arc<Circuit>,
    agents: usize,
    path: Option<ScanPath>,
    sweep: bool,
) -> Case<'a> {
    let mut cfg = WorldConfig::with_agents(agents);
    cfg.collision_mode = CollisionMode::Ignore;
    for a in &mut cfg.agents {
        a.scan = path.is_some();
    }
    let mut w = World::new(circuit.clone(), cfg).expect("valid world");
    if let Some(p) = path {
        w.set_scan_path(p).expect("supported path");
    }
    w.set_scan_sweep(sweep);
    w.reset(0, &Starts::Random).expect("reset");
    let start = w.snapshot().expect("snapshot");
    let actions = vec![Action::new(0.05, 4.0); agents];
    // Stepped as rollouts and vector envs step a world: into events kept between steps.
    let mut events = StepEvents::default();
    let mut k = 0u32;
    let name = match path {
        Some(p) if sweep => format!("world {agents} car(s), scan {p} sweep"),
        Some(p) => format!("world {agents} car(s), scan {p}"),
        None => format!("world {agents} car(s), no scan"),
    };
    Case {
        name,
        unit: "k agent-steps/s",
        scale: agents as f64 / 1e3,
        run: Box::new(move |n| {
            for _ in 0..n {
                k += 1;
                if k.is_multiple_of(200) {
                    w.restore(&start).expect("restore");
                }
                w.step_into(black_box(&actions), &mut events).expect("step");
                black_box(&events);
            }
        }),
        per_round: 0,
        cpu_rates: Vec::new(),
        wall_rates: Vec::new(),
    }
}

/// The seeded noise of one default scan: 1080 Gaussian draws added to ranges near 5 m.
fn noise_case<'a>() -> Case<'a> {
    let lidar = Lidar::new(LidarConfig::default());
    let mut out = vec![5.0; lidar.num_beams()];
    let mut rng = Rng::new(7);
    Case {
        name: format!("noise, {} draws", out.len()),
        unit: "M draws/s",
        scale: out.len() as f64 / 1e6,
        run: Box::new(move |n| {
            for _ in 0..n {
                lidar.add_noise(black_box(&mut out), &mut rng);
                // Back near 5 m, so the values stay in range over many rounds.
                out.fill(5.0);
            }
        }),
        per_round: 0,
        cpu_rates: Vec::new(),
        wall_rates: Vec::new(),
    }
}

fn poses_along(track: &Track, n: usize) -> Vec<Pose> {
    (0..n)
        .map(|i| track.at(track.length() * i as f64 / n as f64).0)
        .collect()
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let rounds: usize = args.first().and_then(|a| a.parse().ok()).unwrap_or(7);
    let round_ms: f64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(300.0);
    let filter = args.get(2).cloned().unwrap_or_default();
    let paths: Vec<ScanPath> = ScanPath::ALL
        .into_iter()
        .filter(|p| p.supported())
        .collect();
    let circuit = Circuits::new()
        .default_circuit()
        .expect("the default map ships with the project");
    let spa = std::env::var_os("PADDOCK_SHARED")
        .map(|d| std::path::PathBuf::from(d).join("maps").join("Spa"))
        .filter(|d| d.is_dir())
        .map(|d| Circuit::load(&d).expect("Spa loads"));
    let mut cases: Vec<Case> = Vec::new();
    for sweep in [false, true] {
        let how = if sweep { " sweep" } else { "" };
        for &p in &paths {
            let poses = poses_along(&circuit.track, 97);
            let name = format!("scan {} {p}{how}", circuit.name);
            cases.push(scan_case(name, &circuit.map, poses, p, sweep));
        }
        if let Some(spa) = &spa {
            for &p in &paths {
                let poses = poses_along(&spa.track, 97);
                let name = format!("scan Spa {p}{how}");
                cases.push(scan_case(name, &spa.map, poses, p, sweep));
            }
        }
    }
    cases.push(noise_case());
    for agents in [1, 2] {
        cases.push(world_case(&circuit, agents, None, false));
        for sweep in [false, true] {
            for &p in &paths {
                cases.push(world_case(&circuit, agents, Some(p), sweep));
            }
        }
    }
    cases.retain(|c| c.name.contains(&filter));
    println!(
        "CPU {}, features: {}; {rounds} rounds of about {round_ms} ms per configuration",
        cpu_model(),
        cpu_features()
    );
    for round in 0..=rounds {
        for c in &mut cases {
            if c.per_round == 0 {
                // Calibrate: units for about one round.
                let t0 = Instant::now();
                let mut n = 1;
                while t0.elapsed().as_secs_f64() < round_ms / 4000.0 {
                    (c.run)(n);
                    n *= 2;
                }
                let per_s = (2 * n - 1) as f64 / t0.elapsed().as_secs_f64();
                c.per_round = ((per_s * round_ms / 1000.0) as u64).max(1);
            }
            let (w0, c0) = (Instant::now(), cpu_ns());
            (c.run)(c.per_round);
            let wall = w0.elapsed().as_secs_f64();
            let cpu = match (c0, cpu_ns()) {
                (Some(a), Some(b)) if b > a => (b - a) as f64 * 1e-9,
                _ => wall,
            };
            if round > 0 {
                // Round 0 warms up.
                c.cpu_rates.push(c.per_round as f64 * c.scale / cpu);
                c.wall_rates.push(c.per_round as f64 * c.scale / wall);
            }
        }
    }
    println!(
        "{:<34} {:>16} {:>10} {:>10} {:>12}",
        "configuration", "unit", "cpu med", "cpu best", "wall med"
    );
    for c in &cases {
        println!(
            "{:<34} {:>16} {:>10.2} {:>10.2} {:>12.2}",
            c.name,
            c.unit,
            median(&c.cpu_rates),
            c.cpu_rates.iter().copied().fold(0.0, f64::max),
            median(&c.wall_rates),
        );
    }
}
