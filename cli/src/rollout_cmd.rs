//! `paddock rollout` and `paddock benchmark`: batches of episodes run locally on all
//! cores, or through a broker with `--endpoint`.

use std::path::PathBuf;
use std::sync::Arc;

use crate::args::{self, out, outln};
use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use paddock_policy::{ParamSpec, driver_info, params_from_overrides};
use paddock_rollout::benchmark::{BenchmarkReport, BenchmarkSpec, Task};
use paddock_rollout::{
    AgentSpec, EpisodeResult, EpisodeTask, Executor, RolloutError, Scenario, task_seed,
};
use paddock_sim::circuit::{Circuits, DEFAULT_MAP};

use crate::video::VideoOptions;

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
    /// Driver: a name (see `paddock drivers`) or an ONNX model file (`model.onnx`;
    /// docs/onnx.md).
    #[arg(long, alias = "policy", default_value = "pure-pursuit")]
    driver: String,
    /// Driver parameters: `name=value,...` or a full comma-separated vector.
    #[arg(long)]
    params: Option<String>,
    /// Vehicle YAML (f1tenth_gym keys and `effects:`, as `paddock sysid` writes it;
    /// default: the f1tenth_gym vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Episodes to run.
    #[arg(long, default_value_t = 10, value_parser = args::whole::<usize>(1, 1_000_000))]
    episodes: usize,
    /// Batch seed: episode k starts from a seed derived from (seed, k).
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Laps to drive.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<u32>(1, 100))]
    laps: u32,
    /// Simulated seconds before an episode is cut off.
    #[arg(long, default_value_t = 120.0, value_parser = args::above(0.0, 36_000.0))]
    time_limit: f64,
    /// Seeded random static obstacles on the track.
    #[arg(long, default_value_t = 0, value_parser = args::whole::<usize>(0, 1_000))]
    obstacles: usize,
    /// Start every episode on the starting grid at this arc length along the centerline
    /// (m), as `paddock bridge sil --start-s` does, instead of at a seeded random place
    /// (the LIDAR noise still follows each episode's seed).
    #[arg(long, value_name = "M", value_parser = args::number(0.0, 1e5))]
    start_s: Option<f64>,
    /// Worker threads (0: one per core; at most 4 per core).
    #[arg(long, default_value_t = 0, value_parser = args::threads())]
    threads: usize,
    /// Run the episodes through the broker at this client endpoint instead of locally.
    #[arg(long, value_name = "URL")]
    endpoint: Option<String>,
    /// With --json: include each episode's trajectory, sampled every N steps.
    #[arg(long, value_name = "N", value_parser = args::whole::<u32>(1, 1_000_000))]
    trajectory: Option<u32>,
    /// Print JSON: every episode and the summary.
    #[arg(long)]
    json: bool,
    /// Write a top-down video of one episode (--video-episode) to this file: .gif, or
    /// .mp4 / .webm / .mkv / .mov with ffmpeg on PATH.
    #[arg(long, value_name = "FILE")]
    video: Option<PathBuf>,
    /// The episode --video shows (0-based).
    #[arg(long, default_value_t = 0, value_name = "K", value_parser = args::whole::<usize>(0, 999_999))]
    video_episode: usize,
    #[command(flatten)]
    video_opts: VideoOptions,
}

/// A driver name or a `.onnx` model path given on the command line (`flag` names it in
/// errors), as the driver name a scenario carries: a model is read, checked and
/// optimised once for this process and registered (`onnx:<sha256>`). With a broker
/// (`endpoint`), the model is also stored in it, from where each worker fetches it once.
pub fn resolve_driver(
    flag: &str,
    name: &str,
    endpoint: Option<&str>,
    circuits: &Circuits,
) -> Result<String> {
    let spec = paddock_policy::DriverSpec::parse(name).with_context(|| format!("{flag} {name}"))?;
    let registered = spec.register().with_context(|| format!("{flag} {name}"))?;
    if let (Some(endpoint), paddock_policy::DriverSpec::Onnx(model)) = (endpoint, &spec) {
        crate::remote::Remote::connect(endpoint, circuits)?
            .put_model(model)
            .with_context(|| format!("{flag} {name}"))?;
    }
    Ok(registered)
}

/// The start of a one-car scenario on the starting grid at arc length `s` (m): the
/// pose `paddock bridge sil --start-s` starts its car at.
fn grid_start(
    scenario: &Scenario,
    s: f64,
    circuits: &Circuits,
) -> Result<paddock_rollout::StartSpec> {
    use paddock_sim::world::{Starts, World, WorldConfig};
    let circuit = circuits
        .get(&scenario.map)
        .with_context(|| format!("loading map {:?}", scenario.map))?;
    let world = World::new(circuit, WorldConfig::default())?;
    let poses = world
        .start_poses_for(0, &Starts::Grid { s })
        .with_context(|| format!("--start-s {s}"))?;
    Ok(paddock_rollout::StartSpec::Poses(poses))
}

pub fn rollout(args: &RolloutArgs, circuits: &Circuits) -> Result<()> {
    let driver = resolve_driver("--driver", &args.driver, args.endpoint.as_deref(), circuits)?;
    let params = parse_params(&driver, args.params.as_deref())?;
    let mut scenario = Scenario::single(&driver)?;
    scenario.map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    scenario.agents[0].params = params.clone();
    scenario.agents[0].vehicle = args::vehicle(args.vehicle.as_deref())?;
    scenario.laps = args.laps;
    scenario.time_limit = args.time_limit;
    scenario.obstacles.count = args.obstacles;
    if let Some(s) = args.start_s {
        scenario.starts = grid_start(&scenario, s, circuits)?;
    }
    scenario.validate()?;
    let scenario = Arc::new(scenario);
    let mut tasks: Vec<EpisodeTask> = (0..args.episodes)
        .map(|k| EpisodeTask {
            scenario: scenario.clone(),
            seed: task_seed(args.seed, k as u64),
            record: args.trajectory,
        })
        .collect();
    if let Some(path) = &args.video {
        if args.video_episode >= args.episodes {
            bail!(
                "--video-episode {} is out of range: must be a whole number in [0, {}] (there are {} episodes)",
                args.video_episode,
                args.episodes - 1,
                args.episodes
            );
        }
        crate::video::check_encoder(path)?;
        tasks[args.video_episode].record = Some(args.video_opts.decimation()?);
    }
    let exec = crate::remote::executor(args.endpoint.as_deref(), args.threads, circuits)?;
    let results = run_tasks(exec.as_ref(), &tasks, "rollout");
    let mut episodes = Vec::with_capacity(results.len());
    for (k, r) in results.into_iter().enumerate() {
        episodes.push(r.with_context(|| format!("episode {k}"))?);
    }
    if let Some(path) = &args.video {
        let jobs = [(path.clone(), &*scenario, &episodes[args.video_episode])];
        crate::video::write_episodes(circuits, &jobs, &args.video_opts)?;
        eprintln!("wrote {}", path.display());
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
    let info = driver_info(&driver)?;
    if args.json {
        let named: serde_json::Map<String, serde_json::Value> = info
            .params
            .iter()
            .zip(&params)
            .map(|(s, v)| (s.name.to_string(), serde_json::json!(v)))
            .collect();
        let doc = serde_json::json!({
            "map": episodes.first().map(|e| e.map.clone()),
            "driver": info.name,
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
        outln!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    outln!(
        "{} on {}: {} episodes, seed {}",
        info.name,
        episodes.first().map(|e| e.map.as_str()).unwrap_or("?"),
        episodes.len(),
        args.seed
    );
    outln!("{:>5}  {:>20}  {:<10}  lap times [s]", "ep", "seed", "end");
    for (k, e) in episodes.iter().enumerate() {
        let a = &e.agents[0];
        let laps: Vec<String> = a.lap_times.iter().map(|t| format!("{t:.2}")).collect();
        outln!(
            "{k:>5}  {:>20}  {:<10}  {}",
            e.seed,
            format!("{:?}", a.termination).to_lowercase(),
            laps.join(" ")
        );
    }
    if mean.is_finite() {
        outln!(
            "finished {finished}/{}; lap time {mean:.3} ± {std:.3} s over {} laps",
            episodes.len(),
            laps.len()
        );
    } else {
        outln!("finished {finished}/{}; no lap completed", episodes.len());
    }
    Ok(())
}

#[derive(Args)]
pub struct BenchmarkArgs {
    /// b1 (time trial), b2 (unknown obstacles) or b3 (head to head).
    task: Task,
    /// The driver under test: a name (see `paddock drivers`) or an ONNX model file
    /// (`model.onnx`; docs/onnx.md).
    #[arg(long, alias = "policy", default_value = "pure-pursuit")]
    driver: String,
    /// The driver's parameters: `name=value,...` or a full comma-separated vector.
    #[arg(long)]
    params: Option<String>,
    /// Vehicle YAML of every car (as `paddock sysid` writes it; default: the f1tenth_gym
    /// vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// B3's opponent driver: a name or an ONNX model file (default: pure-pursuit).
    #[arg(long)]
    opponent: Option<String>,
    /// The opponent's parameters: `name=value,...` or a full vector.
    #[arg(long)]
    opponent_params: Option<String>,
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Episodes to run.
    #[arg(long, default_value_t = 20, value_parser = args::whole::<usize>(1, 1_000_000))]
    episodes: usize,
    /// Benchmark seed: fixes every start and obstacle.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
    /// Laps per episode.
    #[arg(long, default_value_t = 2, value_parser = args::whole::<u32>(1, 100))]
    laps: u32,
    /// B2's obstacle count.
    #[arg(long, default_value_t = 8, value_parser = args::whole::<usize>(0, 1_000))]
    obstacles: usize,
    /// Simulated seconds before an episode is cut off.
    #[arg(long, default_value_t = 180.0, value_parser = args::above(0.0, 36_000.0))]
    time_limit: f64,
    /// Worker threads (0: one per core; at most 4 per core).
    #[arg(long, default_value_t = 0, value_parser = args::threads())]
    threads: usize,
    /// Run the episodes through the broker at this client endpoint instead of locally.
    #[arg(long, value_name = "URL")]
    endpoint: Option<String>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Print a markdown table.
    #[arg(long)]
    markdown: bool,
    /// Print only the markdown table's row (to assemble a table of many runs).
    #[arg(long)]
    markdown_row: bool,
    /// Write a top-down video of every episode into this directory
    /// (`<task>-<episode>.<format>`; B3: the head-to-head races).
    #[arg(long, value_name = "DIR")]
    video: Option<PathBuf>,
    /// The videos' format: gif, or mp4 / webm / mkv / mov with ffmpeg on PATH.
    #[arg(long, default_value = "gif", value_name = "EXT")]
    video_format: String,
    #[command(flatten)]
    video_opts: VideoOptions,
}

pub fn benchmark(args: &BenchmarkArgs, circuits: &Circuits) -> Result<()> {
    let vehicle = args::vehicle(args.vehicle.as_deref())?;
    let endpoint = args.endpoint.as_deref();
    let name = resolve_driver("--driver", &args.driver, endpoint, circuits)?;
    let mut driver = AgentSpec::with_defaults(&name)?;
    driver.params = parse_params(&name, args.params.as_deref())?;
    driver.vehicle = vehicle.clone();
    let opponent = match (&args.opponent, args.task) {
        (Some(o), _) => {
            let name = resolve_driver("--opponent", o, endpoint, circuits)?;
            let mut a = AgentSpec::with_defaults(&name)?;
            a.params = parse_params(&name, args.opponent_params.as_deref())
                .context("--opponent-params")?;
            Some(a)
        }
        (None, Task::B3) => Some(AgentSpec::with_defaults("pure-pursuit")?),
        (None, _) => None,
    }
    .map(|mut a| {
        a.vehicle = vehicle.clone();
        a
    });
    let spec = BenchmarkSpec {
        task: args.task,
        map: args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into()),
        driver,
        opponent,
        episodes: args.episodes,
        seed: args.seed,
        laps: args.laps,
        obstacles: args.obstacles,
        time_limit: args.time_limit,
    };
    let mut tasks = spec.tasks()?;
    let task_name = args.task.to_string().to_lowercase();
    let video_name = |k: usize| format!("{task_name}-{k:03}.{}", args.video_format);
    if let Some(dir) = &args.video {
        if !["gif", "mp4", "webm", "mkv", "mov"].contains(&args.video_format.as_str()) {
            bail!(
                "--video-format {}: must be gif, or mp4, webm, mkv or mov (encoded by ffmpeg)",
                args.video_format
            );
        }
        crate::video::check_encoder(&dir.join(video_name(0)))?;
        let decimation = args.video_opts.decimation()?;
        for t in &mut tasks {
            t.record = Some(decimation);
        }
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let exec = crate::remote::executor(args.endpoint.as_deref(), args.threads, circuits)?;
    let results = run_tasks(exec.as_ref(), &tasks, &format!("benchmark {}", args.task));
    if let Some(Err(e)) = results.iter().find(|r| r.is_err()) {
        bail!("an episode failed: {e}");
    }
    if let Some(dir) = &args.video {
        let jobs: Vec<_> = tasks
            .iter()
            .zip(&results)
            .enumerate()
            .filter_map(|(k, (t, r))| {
                r.as_ref()
                    .ok()
                    .map(|e| (dir.join(video_name(k)), &*t.scenario, e))
            })
            .collect();
        crate::video::write_episodes(circuits, &jobs, &args.video_opts)?;
        eprintln!("wrote {} videos into {}", jobs.len(), dir.display());
    }
    let report = paddock_rollout::benchmark::report(&spec, &results);
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&report)?);
    } else if args.markdown {
        out!("{}", BenchmarkReport::markdown(&[report]));
    } else if args.markdown_row {
        out!(
            "{}",
            BenchmarkReport::markdown(&[report])
                .lines()
                .nth(2)
                .unwrap_or("")
        );
        outln!();
    } else {
        out!("{}", BenchmarkReport::table(&[report]));
    }
    Ok(())
}
