//! `paddock`: the command-line front door of Paddock.

mod args;
mod bounds_args;
mod bridge_cmd;
mod demo;
mod jobs_cmd;
mod keys;
mod maps_generate;
mod onnx_cmd;
mod perf;
mod perf_cluster;
mod plots;
mod remote;
mod rollout_cmd;
mod serve_cmd;
mod sysid_cmd;
mod sysid_plots;
mod sysid_synth;
mod sysid_synth_runs;
mod tune_cmd;
mod video;

use std::path::PathBuf;

use anyhow::Result;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use paddock_sim::circuit::Circuits;

use crate::args::outln;

#[derive(Parser)]
#[command(
    name = "paddock",
    version,
    about = "Train, tune and evaluate F1TENTH race-car drivers in a fast deterministic simulator"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// This worker's or client's CURVE key file (from `paddock keys generate`), for a
    /// broker that requires keys; needs --broker-key.
    #[arg(long, global = true, env = "PADDOCK_KEY_FILE", value_name = "FILE")]
    key: Option<PathBuf>,
    /// The broker's public key file.
    #[arg(
        long,
        global = true,
        env = "PADDOCK_BROKER_KEY_FILE",
        value_name = "FILE"
    )]
    broker_key: Option<PathBuf>,
}

#[derive(Subcommand)]
enum Command {
    /// Tune a driver's parameters with CMA-ES for lap time (the main job).
    Tune(tune_cmd::TuneArgs),
    /// Measure the simulator's speed on one thread (agent-steps/s, LIDAR rays/s).
    Perf(perf::PerfArgs),
    /// Drive a demo episode (pure pursuit, or --driver NAME or model.onnx) and print lap
    /// times.
    Demo(demo::DemoArgs),
    /// Run a batch of seeded episodes of one driver and print per-episode results.
    Rollout(rollout_cmd::RolloutArgs),
    /// Run benchmark task b1 (time trial), b2 (unknown obstacles) or b3 (head to head).
    Benchmark(rollout_cmd::BenchmarkArgs),
    /// List the drivers (what drives a car: a built-in controller or a network) and
    /// their tunable parameters.
    Drivers {
        /// Print JSON: every driver with every parameter (an MLP's weights included).
        #[arg(long)]
        json: bool,
        /// List every parameter, an MLP's weights one by one too.
        #[arg(long)]
        verbose: bool,
    },
    /// The reality-gap tool: find and fit the physics a recording shows the simulator lacks
    /// (`paddock sysid synth` writes a recording with hidden effects).
    Sysid(Box<sysid_cmd::SysidArgs>),
    /// The ROS 2 bridge: a driver on the car, the software-in-the-loop car, recordings.
    Bridge(bridge_cmd::BridgeArgs),
    /// Shipped maps and the track generator.
    Maps {
        #[command(subcommand)]
        command: MapsCommand,
    },
    /// Run the broker: clients on --bind, workers on --worker-bind, jobs stored in --state.
    Broker(serve_cmd::BrokerArgs),
    /// Run a worker: connect to a broker and run its tasks on all cores.
    Worker(serve_cmd::WorkerArgs),
    /// A broker and local workers in one process on loopback; prints the client endpoint.
    Serve(serve_cmd::ServeArgs),
    /// A broker's workers, queue depth and throughput.
    Status(jobs_cmd::StatusArgs),
    /// The jobs a broker stores: list, status, wait, cancel, result.
    Jobs(jobs_cmd::JobsArgs),
    /// Measure rollouts/s through a broker against local runs, and 1 -> 2 worker scaling.
    PerfCluster(perf_cluster::PerfClusterArgs),
    /// CURVE keys for a broker open to the network.
    Keys {
        #[command(subcommand)]
        command: keys::KeysCommand,
    },
    /// Health check of a broker or worker container: its health file is fresh.
    Health(keys::HealthArgs),
    /// Check an ONNX policy against the observation contract; print its raw actions on
    /// seeded sample inputs as JSON.
    OnnxCheck(onnx_cmd::OnnxCheckArgs),
}

#[derive(Subcommand)]
enum MapsCommand {
    /// List the shipped maps and the maps in any directories given.
    List {
        /// More maps: a map's own folder, or a folder of map folders (F1TENTH racetracks
        /// layout).
        dirs: Vec<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Generate a seeded race track (map YAML + PNG + centerline + raceline CSV).
    Generate(maps_generate::GenerateArgs),
}

fn main() {
    // RustDDS warns about every datagram above 1500 bytes (each LIDAR scan): only its
    // errors unless RUST_LOG asks for more
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,rustdds=error")),
        )
        .with_writer(std::io::stderr)
        .init();
    let matches = args::allow_negative_numbers(Cli::command()).get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // the maps every command finds by name: folders of the user's own maps, looked up
    // before the shipped ones; each map is loaded once for the whole run
    let circuits = Circuits::with_dirs(
        std::env::var_os("PADDOCK_MAPS")
            .map(|v| {
                std::env::split_paths(&v)
                    .filter(|p| !p.as_os_str().is_empty())
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default(),
    );
    let circuits = &circuits;
    // The scan path of env sessions' and `paddock perf`'s worlds (`PADDOCK_SCAN_PATH`):
    // one this CPU cannot run, or no path at all, is refused here, naming the variable
    // and the value, whatever the command.
    if let Err(e) = paddock_worker::scan_path::scan_path_from_env() {
        eprintln!("error: {e}");
        std::process::exit(2);
    }
    let result = client_security(&cli).and_then(|()| match cli.command {
        Command::Tune(args) => match &args.endpoint {
            Some(endpoint) => jobs_cmd::tune_remote(&args, endpoint, args.detach, circuits),
            None => tune_cmd::run(&args, circuits),
        },
        Command::Perf(args) => perf::run(&args, circuits),
        Command::Demo(args) => demo::run(&args, circuits),
        Command::Rollout(args) => rollout_cmd::rollout(&args, circuits),
        Command::Benchmark(args) => rollout_cmd::benchmark(&args, circuits),
        Command::Drivers { json, verbose } => list_drivers(json, verbose),
        Command::Sysid(args) => sysid_cmd::run(&args, circuits),
        Command::Bridge(args) => bridge_cmd::run(&args, circuits),
        Command::Broker(args) => serve_cmd::broker(&args),
        Command::Worker(args) => serve_cmd::worker(&args, circuits),
        Command::Serve(args) => serve_cmd::serve(&args, circuits),
        Command::Status(args) => jobs_cmd::status(&args, circuits),
        Command::Jobs(args) => jobs_cmd::jobs(&args, circuits),
        Command::PerfCluster(args) => perf_cluster::run(&args, circuits),
        Command::Keys { command } => keys::run(&command),
        Command::Health(args) => keys::health(&args),
        Command::OnnxCheck(args) => onnx_cmd::run(&args),
        Command::Maps { command } => match command {
            MapsCommand::List { dirs, json } => maps_list(&dirs, json, circuits),
            MapsCommand::Generate(args) => maps_generate::run(&args),
        },
    });
    if let Err(e) = result {
        if args::is_broken_pipe(&e) {
            // the reader is done (`paddock drivers | head`): end quietly, as Unix tools do
            std::process::exit(0);
        }
        eprintln!("error: {}", args::error_line(&e));
        std::process::exit(1);
    }
}

fn maps_list(extra: &[PathBuf], json: bool, circuits: &Circuits) -> Result<()> {
    use paddock_sim::circuit::{Circuit, DEFAULT_MAP, list_circuit_dirs};
    use paddock_sim::shipped::shipped_maps;
    use paddock_sim::track::TrackError;
    let row = |source: &str,
               label: &str,
               path: String,
               loaded: Result<std::sync::Arc<Circuit>, TrackError>| match loaded {
        Ok(c) => serde_json::json!({
            "name": c.name,
            "source": source,
            "path": path,
            "hash": paddock_wire::circuit_bundle(&c, &c.name).map(|b| b.hash).unwrap_or_default(),
            "length_m": c.track.length(),
            "raceline": c.track.raceline().is_some(),
            "resolution": c.map.resolution(),
            "cells": [c.map.width(), c.map.height()],
            "default": source == "shipped" && c.name.eq_ignore_ascii_case(DEFAULT_MAP),
        }),
        Err(e) => serde_json::json!({
            "name": label,
            "source": source,
            "path": path,
            "error": e.to_string(),
        }),
    };
    let mut rows = Vec::new();
    // shipped maps are compiled into this binary
    for m in shipped_maps() {
        rows.push(row(
            "shipped",
            m.name,
            "(built in)".to_string(),
            circuits.shipped(m),
        ));
    }
    for (source, dirs) in [("PADDOCK_MAPS", circuits.dirs()), ("given", extra)] {
        for d in dirs {
            if !d.is_dir() {
                anyhow::bail!("not a directory of maps: {}", d.display());
            }
            // a map's own folder lists itself; a folder of map folders lists each
            let maps = if source == "given" && is_circuit_dir(d) {
                vec![d.clone()]
            } else {
                list_circuit_dirs(d)
            };
            if source == "given" && maps.is_empty() {
                anyhow::bail!(
                    "no maps in {}: neither a map folder (a *_map.yaml inside) nor a folder of map folders",
                    d.display()
                );
            }
            for dir in maps {
                let label = dir.file_name().map(|n| n.to_string_lossy().to_string());
                rows.push(row(
                    source,
                    label.as_deref().unwrap_or_default(),
                    dir.display().to_string(),
                    circuits.load(&dir),
                ));
            }
        }
    }
    if json {
        outln!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    outln!(
        "{:<16} {:<12} {:>9} {:>9} {:>12}  path",
        "name",
        "source",
        "length_m",
        "raceline",
        "cells"
    );
    for r in &rows {
        if let Some(err) = r.get("error") {
            outln!(
                "{:<16} {:<12} error: {}",
                r["name"].as_str().unwrap_or("?"),
                r["source"].as_str().unwrap_or("?"),
                err.as_str().unwrap_or("?")
            );
            continue;
        }
        let name = format!(
            "{}{}",
            r["name"].as_str().unwrap_or("?"),
            if r["default"].as_bool() == Some(true) {
                " *"
            } else {
                ""
            }
        );
        outln!(
            "{:<16} {:<12} {:>9.1} {:>9} {:>12}  {}",
            name,
            r["source"].as_str().unwrap_or("?"),
            r["length_m"].as_f64().unwrap_or(0.0),
            if r["raceline"].as_bool() == Some(true) {
                "yes"
            } else {
                "no"
            },
            format!("{}x{}", r["cells"][0], r["cells"][1]),
            r["path"].as_str().unwrap_or("?"),
        );
    }
    outln!("(* = the default map)");
    Ok(())
}

fn list_drivers(json: bool, verbose: bool) -> Result<()> {
    let drivers = paddock_policy::drivers();
    if json {
        outln!("{}", serde_json::to_string_pretty(&drivers)?);
        return Ok(());
    }
    for d in drivers {
        outln!(
            "{} ({}){}",
            d.name,
            d.about,
            if d.sensors.lidar {
                ", uses the LIDAR"
            } else {
                ""
            }
        );
        for group in param_groups(&d.params, verbose) {
            match group {
                [p] => outln!(
                    "  {:<18} {:>8} in [{}, {}]  {}",
                    p.name,
                    p.default,
                    p.lo,
                    p.hi,
                    p.doc
                ),
                [first, .., last] => outln!(
                    "  {:<18} {:>8} in [{}, {}]  {} ({} parameters; --verbose lists them)",
                    format!("{}..{}", first.name, last.name),
                    "",
                    first.lo,
                    first.hi,
                    first.doc,
                    group.len()
                ),
                [] => {}
            }
        }
    }
    Ok(())
}

/// The parameters as lines: runs of more than 4 alike parameters (same doc and bounds:
/// a network's weights) collapse into one line unless `verbose`.
fn param_groups(
    params: &[paddock_policy::ParamSpec],
    verbose: bool,
) -> Vec<&[paddock_policy::ParamSpec]> {
    let alike = |a: &paddock_policy::ParamSpec, b: &paddock_policy::ParamSpec| {
        a.doc == b.doc && a.lo == b.lo && a.hi == b.hi
    };
    let mut out = Vec::new();
    let mut start = 0;
    while start < params.len() {
        let mut end = start + 1;
        while end < params.len() && alike(&params[start], &params[end]) {
            end += 1;
        }
        if verbose || end - start <= 4 {
            out.extend((start..end).map(|i| &params[i..=i]));
        } else {
            out.push(&params[start..end]);
        }
        start = end;
    }
    out
}

/// Whether `dir` is itself a map's folder (holds a `*_map.yaml`).
fn is_circuit_dir(dir: &std::path::Path) -> bool {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| {
            e.file_name()
                .to_str()
                .is_some_and(|n| n.ends_with("_map.yaml"))
        })
}

/// Reads `--key` / `--broker-key` into the client security of this process.
fn client_security(cli: &Cli) -> Result<()> {
    match (&cli.key, &cli.broker_key) {
        (None, None) => Ok(()),
        (Some(key), Some(broker)) => {
            let keys = paddock_libzmq::KeyPair::read(key)?;
            let server_public = paddock_libzmq::read_public(broker)?;
            remote::set_security(paddock_libzmq::Curve::Client {
                keys,
                server_public,
            });
            Ok(())
        }
        (Some(_), None) => anyhow::bail!("--key needs --broker-key (the broker's public key file)"),
        (None, Some(_)) => anyhow::bail!("--broker-key needs --key (this peer's key file)"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every flag and positional of every command says what it is in `--help`.
    #[test]
    fn every_flag_has_help_text() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            let path = format!("{path} {}", cmd.get_name());
            for a in cmd.get_arguments() {
                let id = a.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                let has = a
                    .get_help()
                    .is_some_and(|h| !h.to_string().trim().is_empty())
                    || a.get_long_help().is_some();
                if !has {
                    missing.push(format!("{path}: --{}", a.get_long().unwrap_or(id)));
                }
            }
            for sub in cmd.get_subcommands() {
                walk(sub, &path, missing);
            }
        }
        let mut missing = Vec::new();
        walk(&Cli::command(), "", &mut missing);
        assert!(
            missing.is_empty(),
            "flags without help text:\n{}",
            missing.join("\n")
        );
    }

    #[test]
    fn the_command_tree_is_consistent() {
        args::allow_negative_numbers(Cli::command()).debug_assert();
    }

    #[test]
    fn weights_collapse_unless_verbose() {
        let mlp = paddock_policy::driver_info("mlp").unwrap();
        assert!(mlp.params.len() > 100);
        assert!(param_groups(&mlp.params, false).len() < 10);
        assert_eq!(param_groups(&mlp.params, true).len(), mlp.params.len());
        let pp = paddock_policy::driver_info("pure-pursuit").unwrap();
        assert_eq!(param_groups(&pp.params, false).len(), pp.params.len());
    }
}
