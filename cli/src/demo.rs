//! `paddock demo`: one episode (pure pursuit by default, or any driver or ONNX model),
//! lap times printed.

use crate::args::{self, outln};
use anyhow::{Context, Result};
use clap::Args;
use paddock_rollout::{AgentSpec, Scenario, Termination, run_episode};
use paddock_sim::circuit::{Circuits, DEFAULT_MAP};

#[derive(Args)]
pub struct DemoArgs {
    /// The driver of every car: a name (see `paddock drivers`) or an ONNX model file
    /// (`model.onnx`; docs/onnx.md).
    #[arg(long, alias = "policy", default_value = "pure-pursuit")]
    driver: String,
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Number of cars.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<usize>(1, 16))]
    agents: usize,
    /// Laps to drive.
    #[arg(long, default_value_t = 2, value_parser = args::whole::<u32>(1, 100))]
    laps: u32,
    /// Episode seed.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
    /// Time limit, simulated seconds.
    #[arg(long, default_value_t = 300.0, value_parser = args::above(0.0, 36_000.0))]
    time_limit: f64,
    /// Vehicle YAML of every car (as `paddock sysid` writes it; default: the f1tenth_gym
    /// vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: &DemoArgs, circuits: &Circuits) -> Result<()> {
    let driver = crate::rollout_cmd::resolve_driver("--driver", &args.driver, None, circuits)?;
    let mut scenario = Scenario::single(&driver)?;
    scenario.map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    let mut car = AgentSpec::with_defaults(&driver)?;
    car.vehicle = args::vehicle(args.vehicle.as_deref())?;
    scenario.agents = vec![car; args.agents];
    scenario.laps = args.laps;
    scenario.time_limit = args.time_limit;
    let episode = run_episode(circuits, &scenario, args.seed, None)
        .with_context(|| format!("running a demo episode on map {:?}", scenario.map))?;
    if args.json {
        let agents: Vec<serde_json::Value> = episode
            .agents
            .iter()
            .enumerate()
            .map(|(i, a)| {
                serde_json::json!({
                    "agent": i,
                    "status": a.termination,
                    "laps": a.lap_times.len(),
                    "lap_times": a.lap_times,
                    "progress_m": a.progress,
                })
            })
            .collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "map": episode.map,
                "driver": driver,
                "seed": args.seed,
                "time_s": episode.time,
                "agents": agents,
            }))?
        );
        return Ok(());
    }
    outln!(
        "{driver} on map {}, seed {}, {:.2} s simulated",
        episode.map,
        args.seed,
        episode.time
    );
    for (i, a) in episode.agents.iter().enumerate() {
        let laps: Vec<String> = a.lap_times.iter().map(|t| format!("{t:.2} s")).collect();
        let status = match a.termination {
            Termination::TimeLimit => "still racing at the time limit",
            Termination::Crashed => "crashed",
            Termination::Finished => "finished",
        };
        outln!(
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
