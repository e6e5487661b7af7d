//! `paddock perf-cluster`: rollouts/s of one batch run locally and through a broker on
//! loopback (one episode per task), the overhead as a ratio, and the scaling from one
//! to two worker processes. The broker runs in this process; workers are `paddock
//! worker` child processes of the same executable. Results are checked to be equal.

use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use paddock_rollout::{EpisodeTask, Executor, LocalExecutor, Scenario, task_seed};
use paddock_sim::circuit::Circuits;

use crate::args::{self, outln};
use crate::remote::{Remote, RemoteExecutor};
use crate::serve_cmd::BrokerThread;

#[derive(Args)]
pub struct PerfClusterArgs {
    /// Episodes in the batch (one per task).
    #[arg(long, default_value_t = 200, value_parser = args::whole::<usize>(1, 1_000_000))]
    pub episodes: usize,
    /// Simulated seconds per episode.
    #[arg(long, default_value_t = 30.0, value_parser = args::above(0.0, 36_000.0))]
    pub time_limit: f64,
    /// Driver of the single car.
    #[arg(long, alias = "policy", default_value = "pure-pursuit")]
    pub driver: String,
    /// Map name or directory.
    #[arg(long, default_value = "lakeside")]
    pub map: String,
    /// Threads of the local pool and of each worker process (0: half the cores, so two
    /// workers fit the machine; at most 4 per core).
    #[arg(long, default_value_t = 0, value_parser = args::threads())]
    pub threads: usize,
    /// Times each measurement is repeated (the best is kept).
    #[arg(long, default_value_t = 2, value_parser = args::whole::<usize>(1, 100))]
    pub repeats: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Worker child processes, killed on drop.
struct Workers(Vec<Child>);

impl Workers {
    fn spawn(n: usize, backend: &str, threads: usize, maps: &std::path::Path) -> Result<Self> {
        let exe = std::env::current_exe().context("locating the paddock executable")?;
        let mut children = Vec::with_capacity(n);
        for _ in 0..n {
            let child = Command::new(&exe)
                .args(["worker", "--connect", backend, "--threads"])
                .arg(threads.to_string())
                .arg("--maps")
                .arg(maps)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .with_context(|| format!("starting {} worker", exe.display()))?;
            children.push(child);
        }
        Ok(Self(children))
    }
}

impl Drop for Workers {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn timed(exec: &dyn Executor, tasks: &[EpisodeTask], repeats: usize) -> Result<(f64, Vec<String>)> {
    let mut best = f64::INFINITY;
    let mut digest = Vec::new();
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        let results = exec.run_batch(tasks, &|_| {});
        let dt = t0.elapsed().as_secs_f64();
        best = best.min(dt);
        digest = Vec::with_capacity(results.len());
        for (k, r) in results.into_iter().enumerate() {
            let r = r.with_context(|| format!("episode {k}"))?;
            digest.push(serde_json::to_string(&r)?);
        }
    }
    Ok((tasks.len() as f64 / best, digest))
}

pub fn run(args: &PerfClusterArgs, circuits: &Circuits) -> Result<()> {
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = if args.threads > 0 {
        args.threads
    } else {
        (cores / 2).max(1)
    };
    let mut scenario = Scenario::single(&args.driver)?;
    scenario.map = args.map.clone();
    scenario.time_limit = args.time_limit;
    scenario.validate()?;
    let scenario = Arc::new(scenario);
    let tasks: Vec<EpisodeTask> = (0..args.episodes)
        .map(|k| EpisodeTask {
            scenario: scenario.clone(),
            seed: task_seed(7, k as u64),
            record: None,
        })
        .collect();
    let warmup = &tasks[..tasks.len().min(2 * threads)];

    // the local pool loads the circuit once from the registry, as a worker does
    circuits.get(&args.map)?;
    let local = LocalExecutor::new(threads, circuits.clone())?;
    local.run_batch(warmup, &|_| {});
    let (local_rate, local_digest) = timed(&local, &tasks, args.repeats)?;
    eprintln!("local, {threads} threads: {local_rate:.1} rollouts/s");

    let state = tempfile::tempdir()?;
    let broker = BrokerThread::start("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", state.path())?;
    let maps = state.path().join("worker-maps");
    let mut rates = Vec::new();
    for n in [1usize, 2] {
        let workers = Workers::spawn(n, &broker.back, threads, &maps)?;
        let mut remote = Remote::connect(&broker.front, circuits)?;
        remote.wait_for_workers(n, Duration::from_secs(30))?;
        let exec = RemoteExecutor::connect(&broker.front, circuits)?;
        // the first batch moves the map to the broker and the workers
        exec.run_batch(warmup, &|_| {});
        let (rate, digest) = timed(&exec, &tasks, args.repeats)?;
        if digest != local_digest {
            bail!("results through the broker with {n} workers differ from the local results");
        }
        eprintln!("broker, {n} worker process(es) x {threads} threads: {rate:.1} rollouts/s");
        rates.push(rate);
        drop(workers);
        if n == 1 {
            // let the broker declare the killed worker dead before the next round
            wait_gone(&remote)?;
        }
    }
    broker.stop()?;
    let overhead = local_rate / rates[0] - 1.0;
    let scaling = rates[1] / rates[0];
    let doc = serde_json::json!({
        "episodes": args.episodes,
        "time_limit_s": args.time_limit,
        "driver": args.driver,
        "map": args.map,
        "threads_per_process": threads,
        "cores": cores,
        "local_rollouts_per_s": local_rate,
        "broker_1_worker_rollouts_per_s": rates[0],
        "broker_2_workers_rollouts_per_s": rates[1],
        "broker_overhead": overhead,
        "scaling_1_to_2_workers": scaling,
        "identical_results": true,
    });
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        outln!(
            "{} episodes of {} s ({} on {}), {threads} threads per process, {cores} cores",
            args.episodes,
            args.time_limit,
            args.driver,
            args.map
        );
        outln!("local:                 {local_rate:>9.1} rollouts/s");
        outln!(
            "broker, 1 worker:      {:>9.1} rollouts/s  (overhead {:+.1}%)",
            rates[0],
            overhead * 100.0
        );
        outln!(
            "broker, 2 workers:     {:>9.1} rollouts/s  (scaling x{scaling:.2})",
            rates[1]
        );
        outln!("results identical to the local run: yes");
    }
    Ok(())
}

/// Waits until the broker has declared the killed workers dead (no worker left), so the
/// next measurement does not wait on a dead worker's tasks.
fn wait_gone(remote: &Remote) -> Result<()> {
    let mut remote = Remote::connect(&remote.endpoint, &remote.circuits)?;
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        if remote.status()?.workers.is_empty() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    bail!("killed workers were not declared dead within 10 s")
}
