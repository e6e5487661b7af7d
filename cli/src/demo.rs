//! `paddock demo`: one episode with the pure-pursuit driver, lap times printed.

use anyhow::{Context, Result};
use clap::Args;
use paddock_policy::{PurePursuit, PurePursuitParams};
use paddock_sim::collision::CollisionMode;
use paddock_sim::track::{Circuit, DEFAULT_MAP};
use paddock_sim::world::{Action, AgentStatus, Starts, World, WorldConfig};

#[derive(Args)]
pub struct DemoArgs {
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Number of cars.
    #[arg(long, default_value_t = 1)]
    agents: usize,
    /// Laps to drive.
    #[arg(long, default_value_t = 2)]
    laps: u32,
    /// Episode seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Time limit, simulated seconds.
    #[arg(long, default_value_t = 300.0)]
    time_limit: f64,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &DemoArgs) -> Result<()> {
    let name = args.map.as_deref().unwrap_or(DEFAULT_MAP);
    let circuit = Circuit::resolve(name, &[]).with_context(|| format!("loading map {name:?}"))?;
    let mut config = WorldConfig::with_agents(args.agents);
    config.laps = Some(args.laps);
    config.collision_mode = CollisionMode::Terminate;
    for a in &mut config.agents {
        // pure pursuit needs no LIDAR
        a.scan = false;
    }
    let mut world = World::new(circuit.clone(), config)?;
    world.reset(args.seed, &Starts::Random)?;
    let mut drivers: Vec<PurePursuit> = (0..args.agents)
        .map(|_| PurePursuit::on_circuit(&circuit, PurePursuitParams::default()))
        .collect();
    let steps = (args.time_limit / world.config().dt).ceil() as u64;
    let mut actions = vec![Action::default(); args.agents];
    for _ in 0..steps {
        let obs = world.observation()?;
        for (i, d) in drivers.iter_mut().enumerate() {
            let pose = paddock_sim::geometry::Pose::new(
                obs.poses_x[i],
                obs.poses_y[i],
                obs.poses_theta[i],
            );
            actions[i] = d.act_pose(pose, obs.linear_vels_x[i]);
        }
        world.step(&actions)?;
        if world.done() {
            break;
        }
    }
    let state = world.state()?;
    let agents: Vec<serde_json::Value> = state
        .agents
        .iter()
        .enumerate()
        .map(|(i, a)| {
            serde_json::json!({
                "agent": i,
                "status": a.status,
                "laps": a.laps.laps,
                "lap_times": a.laps.lap_times,
                "progress_m": a.laps.progress,
            })
        })
        .collect();
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "map": circuit.name,
                "seed": args.seed,
                "time_s": state.time,
                "agents": agents,
            }))?
        );
        return Ok(());
    }
    println!(
        "map {} ({:.1} m), seed {}, {:.2} s simulated",
        circuit.name,
        circuit.track.length(),
        args.seed,
        state.time
    );
    for (i, a) in state.agents.iter().enumerate() {
        let laps: Vec<String> = a
            .laps
            .lap_times
            .iter()
            .map(|t| format!("{t:.2} s"))
            .collect();
        let status = match a.status {
            AgentStatus::Racing => "still racing at the time limit",
            AgentStatus::Crashed => "crashed",
            AgentStatus::Finished => "finished",
        };
        println!(
            "car {i}: {status}; laps: {}",
            if laps.is_empty() {
                "none".to_string()
            } else {
                laps.join(", ")
            }
        );
    }
    Ok(())
}
