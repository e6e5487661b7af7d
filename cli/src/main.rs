//! `paddock`: the command-line front door of Paddock.

mod bridge_cmd;
mod cluster;
mod demo;
mod keys;
mod maps_generate;
mod onnx_cmd;
mod perf;
mod perf_cluster;
mod plots;
mod remote;
mod rollout_cmd;
mod sysid_cmd;
mod sysid_plots;
mod sysid_synth;
mod tune_cmd;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};

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
    /// Drive a demo episode with the pure-pursuit driver and print lap times.
    Demo(demo::DemoArgs),
    /// Run a batch of seeded episodes of one driver and print per-episode results.
    Rollout(rollout_cmd::RolloutArgs),
    /// Run benchmark task b1 (time trial), b2 (unknown obstacles) or b3 (head to head).
    Benchmark(rollout_cmd::BenchmarkArgs),
    /// List the drivers and their tunable parameters.
    Drivers {
        #[arg(long)]
        json: bool,
    },
    /// The reality-gap tool: find and fit the physics a recording shows the simulator lacks
    /// (`paddock sysid synth` writes a recording with hidden effects).
    Sysid(sysid_cmd::SysidArgs),
    /// The ROS 2 bridge: a driver on the car, the software-in-the-loop car, recordings.
    Bridge(bridge_cmd::BridgeArgs),
    /// Shipped maps and the track generator.
    Maps {
        #[command(subcommand)]
        command: MapsCommand,
    },
    /// Run the broker: clients on --bind, workers on --workers, jobs stored in --state.
    Broker(cluster::BrokerArgs),
    /// Run a worker: connect to a broker and run its tasks on all cores.
    Worker(cluster::WorkerArgs),
    /// A broker and local workers in one process on loopback; prints the client endpoint.
    Serve(cluster::ServeArgs),
    /// A broker's workers, queue depth and throughput.
    Status(cluster::StatusArgs),
    /// The jobs a broker stores: list, status, wait, cancel, result.
    Jobs(cluster::JobsArgs),
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
        /// More directories of maps (F1TENTH racetracks layout: one directory per map).
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
    let cli = Cli::parse();
    let result = client_security(&cli).and_then(|()| match cli.command {
        Command::Tune(args) => tune_cmd::run(&args),
        Command::Perf(args) => perf::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Rollout(args) => rollout_cmd::rollout(&args),
        Command::Benchmark(args) => rollout_cmd::benchmark(&args),
        Command::Drivers { json } => list_drivers(json),
        Command::Sysid(args) => sysid_cmd::run(&args),
        Command::Bridge(args) => bridge_cmd::run(&args),
        Command::Broker(args) => cluster::broker(&args),
        Command::Worker(args) => cluster::worker(&args),
        Command::Serve(args) => cluster::serve(&args),
        Command::Status(args) => cluster::status(&args),
        Command::Jobs(args) => cluster::jobs(&args),
        Command::PerfCluster(args) => perf_cluster::run(&args),
        Command::Keys { command } => keys::run(&command),
        Command::Health(args) => keys::health(&args),
        Command::OnnxCheck(args) => onnx_cmd::run(&args),
        Command::Maps { command } => match command {
            MapsCommand::List { dirs, json } => maps_list(&dirs, json),
            MapsCommand::Generate(args) => maps_generate::run(&args),
        },
    });
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn maps_list(extra: &[PathBuf], json: bool) -> Result<()> {
    use paddock_sim::track::{Circuit, DEFAULT_MAP, list_circuit_dirs, map_search_dirs};
    let mut rows = Vec::new();
    let shipped = map_search_dirs();
    for (source, dirs) in [("shipped", shipped.as_slice()), ("given", extra)] {
        for d in dirs {
            if !d.is_dir() {
                anyhow::bail!("not a directory of maps: {}", d.display());
            }
            for dir in list_circuit_dirs(d) {
                let row = match Circuit::load(&dir) {
                    Ok(c) => serde_json::json!({
                        "name": c.name,
                        "source": source,
                        "path": dir.display().to_string(),
                        "length_m": c.track.length(),
                        "raceline": c.track.raceline().is_some(),
                        "resolution": c.map.resolution(),
                        "cells": [c.map.width(), c.map.height()],
                        "default": source == "shipped" && c.name.eq_ignore_ascii_case(DEFAULT_MAP),
                    }),
                    Err(e) => serde_json::json!({
                        "name": dir.file_name().map(|n| n.to_string_lossy().to_string()),
                        "source": source,
                        "path": dir.display().to_string(),
                        "error": e.to_string(),
                    }),
                };
                rows.push(row);
            }
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "{:<16} {:<8} {:>9} {:>9} {:>12}  path",
        "name", "source", "length_m", "raceline", "cells"
    );
    for r in &rows {
        if let Some(err) = r.get("error") {
            println!(
                "{:<16} {:<8} error: {}",
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
        println!(
            "{:<16} {:<8} {:>9.1} {:>9} {:>12}  {}",
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
    println!("(* = the default map)");
    Ok(())
}

fn list_drivers(json: bool) -> Result<()> {
    let drivers = paddock_policy::drivers();
    if json {
        println!("{}", serde_json::to_string_pretty(&drivers)?);
        return Ok(());
    }
    for d in drivers {
        println!(
            "{} ({}){}",
            d.name,
            d.about,
            if d.sensors.lidar {
                ", uses the LIDAR"
            } else {
                ""
            }
        );
        for p in &d.params {
            println!(
                "  {:<18} {:>8} in [{}, {}]  {}",
                p.name, p.default, p.lo, p.hi, p.doc
            );
        }
    }
    Ok(())
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
