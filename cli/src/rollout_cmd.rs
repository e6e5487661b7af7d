//! `paddock rollout` and `paddock benchmark`: batches of episodes run locally on all
//! cores, or through a broker with `--endpoint`.

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use paddock_policy::{ParamSpec, driver_info, params_from_overrides};
use paddock_rollout::benchmark::{BenchmarkReport, BenchmarkSpec, Task};
use paddock_rollout::{
    AgentSpec, EpisodeResult, EpisodeTask, Executor, RolloutError, Scenario, task_seed,
};
use paddock_sim::track::DEFAULT_MAP;

/// Parse `--params`: either `name=value,name=value` (others keep their defaults) or a
/// full comma-separated vector in the driver's parameter order.
pub fn parse_params(driver: &str, text: Option<&str>) -> Result<Vec<f64>> {
    let info = driver_info(driver)?;
    let specs: &[ParamSpec] = &info.params;
    let Some(text) = text.map(str::trim).filter(|t| !t.is_empty()) else {
        return Ok(specs.iter().map(|s| s.default).collect());
    };
    if text.contains('=') {
        let mut overrides = Vec::new();
        for pair in text.split(',') {
            let (name, value) = pair
                .split_once('=')
                .with_context(|| format!("--params: {pair:?} is not name=value"))?;
            let v: f64 = value
                .trim()
                .parse()
                .with_context(|| format!("--params: {}: {value:?} is not a number", name.trim()))?;
            overrides.push((name.trim().to_string(), v));
        }
        Ok(params_from_overrides(info.name, specs, &overrides)?)
    } else {
        let v = text
            .split(',')
            .enumerate()
            .map(|(i, s)| {
                s.trim()
                    .parse::<f64>()
                    .with_context(|| format!("--params: value {i} ({s:?}) is not a number"))
            })
            .collect::<Result<Vec<f64>>>()?;
        paddock_policy::check_params(info.name, specs, &v)?;
        Ok(v)
    }
}

pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} episodes, {per_sec}, eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

pub fn run_tasks(
    exec: &dyn Executor,
    tasks: &[EpisodeTask],
    what: &str,
) -> Vec<Result<EpisodeResult, RolloutError>> {
    let bar = progress_bar(tasks.len() as u64, what);
    let results = exec.run_batch(tasks, &|done| bar.set_position(done as u64));
    bar.finish_and_clear();
    results
}

#[derive(Args)]
pub struct RolloutArgs {
    /// Driver name (see `paddock drivers`).
    #[arg(long, default_value = "pure-pursuit")]
    policy: String,
    /// Driver parameters: `name=value,...` or a full comma-separated vector.
    #[arg(long)]
    params: Option<String>,
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    #[arg(long, default_value_t = 1)]
    laps: u32,
    /// Simulated seconds before an episode is cut off.
    #[arg(long, default_value_t = 120.0)]
    time_limit: f64,
    /// Seeded random static obstacles on the track.
    #[arg(long, default_value_t = 0)]
    obstacles: usize,
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Run the episodes through the broker at this client endpoint instead of locally.
    #[arg(long, value_name = "URL")]
    endpoint: Option<String>,
    /// With --json: include each episode's trajectory, sampled every N steps.
    #[arg(long, value_name = "N")]
    trajectory: Option<u32>,
    #[arg(long)]
    json: bool,
}

/// A driver name or a `.onnx` model path given on the command line, as the driver name a
/// scenario carries: a model is checked and registered with this process
/// (`onnx:<sha256>`). Models do not travel to workers yet, so they run locally only.
fn resolve_driver(name: &str, endpoint: Option<&str>) -> Result<String> {
    let spec = paddock_policy::DriverSpec::parse(name)?;
    if endpoint.is_some() && matches!(spec, paddock_policy::DriverSpec::Onnx(_)) {
        bail!("--policy {name}: ONNX models run locally only for now (no --endpoint)");
    }
    Ok(spec.register()?)
}

pub fn rollout(args: &RolloutArgs) -> Result<()> {
    let policy = resolve_driver(&args.policy, args.endpoint.as_deref())?;
    let params = parse_params(&policy, args.params.as_deref())?;
    let mut scenario = Scenario::single(&policy)?;
    scenario.map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    scenario.agents[0].params = params.clone();
    scenario.laps = args.laps;
    scenario.time_limit = args.time_limit;
    scenario.obstacles.count = args.obstacles;
    scenario.validate()?;
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let scenario = Arc::new(scenario);
    let tasks: Vec<EpisodeTask> = (0..args.episodes)
        .map(|k| EpisodeTask {
            scenario: scenario.clone(),
            seed: task_seed(args.seed, k as u64),
            record: args.trajectory.map(|n| n.max(1)),
        })
        .collect();
    let exec = crate::remote::executor(args.endpoint.as_deref(), args.threads)?;
    let results = run_tasks(exec.as_ref(), &tasks, "rollout");
    let mut episodes = Vec::with_capacity(results.len());
    for (k, r) in results.into_iter().enumerate() {
        episodes.push(r.with_context(|| format!("episode {k}"))?);
    }
    let laps: Vec<f64> = episodes
        .iter()
        .flat_map(|e| e.agents[0].lap_times.iter().copied())
        .collect();
    let (mean, std) = paddock_rollout::benchmark::mean_std(&laps);
    let finished = episodes
        .iter()
        .filter(|e| e.agents[0].termination == paddock_rollout::Termination::Finished)
        .count();
    let info = driver_info(&policy)?;
    if args.json {
        let named: serde_json::Map<String, serde_json::Value> = info
            .params
            .iter()
            .zip(&params)
            .map(|(s, v)| (s.name.to_string(), serde_json::json!(v)))
            .collect();
        let doc = serde_json::json!({
            "map": episodes.first().map(|e| e.map.clone()),
            "policy": info.name,
            "params": named,
            "seed": args.seed,
            "episodes": episodes.iter().enumerate().map(|(k, e)| {
                let a = &e.agents[0];
                serde_json::json!({
                    "index": k,
                    "seed": e.seed,
                    "termination": a.termination,
                    "lap_times": a.lap_times,
                    "collided": a.collided,
                    "progress_m": a.progress,
                    "return": a.episode_return,
                    "time_s": e.time,
                    "steps": e.steps,
                    "trajectory": e.trajectory.as_ref().map(|t| serde_json::json!({
                        "decimation": t.decimation,
                        "t": t.t,
                        "x": t.agents[0].x,
                        "y": t.agents[0].y,
                        "theta": t.agents[0].theta,
                        "speed": t.agents[0].speed,
                        "steer": t.agents[0].steer,
                    })),
                })
            }).collect::<Vec<_>>(),
            "summary": {
                "finished": finished,
                "lap_time_mean": if mean.is_finite() { Some(mean) } else { None },
                "lap_time_std": if std.is_finite() { Some(std) } else { None },
            }
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    println!(
        "{} on {}: {} episodes, seed {}",
        info.name,
        episodes.first().map(|e| e.map.as_str()).unwrap_or("?"),
        episodes.len(),
        args.seed
    );
    println!("{:>5}  {:>20}  {:<10}  lap times [s]", "ep", "seed", "end");
    for (k, e) in episodes.iter().enumerate() {
        let a = &e.agents[0];
        let laps: Vec<String> = a.lap_times.iter().map(|t| format!("{t:.2}")).collect();
        println!(
            "{k:>5}  {:>20}  {:<10}  {}",
            e.seed,
            format!("{:?}", a.termination).to_lowercase(),
            laps.join(" ")
        );
    }
    if mean.is_finite() {
        println!(
            "finished {finished}/{}; lap time {mean:.3} ± {std:.3} s over {} laps",
            episodes.len(),
            laps.len()
        );
    } else {
        println!("finished {finished}/{}; no lap completed", episodes.len());
    }
    Ok(())
}

#[derive(Args)]
pub struct BenchmarkArgs {
    /// b1 (time trial), b2 (unknown obstacles) or b3 (head to head).
    task: Task,
    #[arg(long, default_value = "pure-pursuit")]
    policy: String,
    #[arg(long)]
    params: Option<String>,
    /// B3's opponent driver.
    #[arg(long)]
    opponent: Option<String>,
    #[arg(long)]
    opponent_params: Option<String>,
    #[arg(long)]
    map: Option<String>,
    #[arg(long, default_value_t = 20)]
    episodes: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, default_value_t = 2)]
    laps: u32,
    /// B2's obstacle count.
    #[arg(long, default_value_t = 8)]
    obstacles: usize,
    #[arg(long, default_value_t = 180.0)]
    time_limit: f64,
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Run the episodes through the broker at this client endpoint instead of locally.
    #[arg(long, value_name = "URL")]
    endpoint: Option<String>,
    #[arg(long)]
    json: bool,
    /// Print a markdown table.
    #[arg(long)]
    markdown: bool,
    /// Print only the markdown table's row (to assemble a table of many runs).
    #[arg(long)]
    markdown_row: bool,
}

pub fn benchmark(args: &BenchmarkArgs) -> Result<()> {
    let mut policy = AgentSpec::with_defaults(&args.policy)?;
    policy.params = parse_params(&args.policy, args.params.as_deref())?;
    let opponent = match (&args.opponent, args.task) {
        (Some(o), _) => {
            let mut a = AgentSpec::with_defaults(o)?;
            a.params = parse_params(o, args.opponent_params.as_deref())?;
            Some(a)
        }
        (None, Task::B3) => Some(AgentSpec::with_defaults("pure-pursuit")?),
        (None, _) => None,
    };
    let spec = BenchmarkSpec {
        task: args.task,
        map: args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into()),
        policy,
        opponent,
        episodes: args.episodes,
        seed: args.seed,
        laps: args.laps,
        obstacles: args.obstacles,
        time_limit: args.time_limit,
    };
    let tasks = spec.tasks()?;
    let exec = crate::remote::executor(args.endpoint.as_deref(), args.threads)?;
    let results = run_tasks(exec.as_ref(), &tasks, &format!("benchmark {}", args.task));
    if let Some(Err(e)) = results.iter().find(|r| r.is_err()) {
        bail!("an episode failed: {e}");
    }
    let report = paddock_rollout::benchmark::report(&spec, &results);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else if args.markdown {
        print!("{}", BenchmarkReport::markdown(&[report]));
    } else if args.markdown_row {
        print!(
            "{}",
            BenchmarkReport::markdown(&[report])
                .lines()
                .nth(2)
                .unwrap_or("")
        );
        println!();
    } else {
        print!("{}", BenchmarkReport::table(&[report]));
    }
    Ok(())
}
