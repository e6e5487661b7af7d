//! `paddock tune`: CMA-ES tuning of a driver's parameters for lap time (the main job).
//!
//! Each generation, CMA-ES proposes `popsize` parameter vectors (ask); each is driven
//! from K seeded random starts for one lap; its fitness is the mean lap time plus a
//! crash penalty (tell). The tuned and the default parameters are then compared on
//! held-out seeds the optimiser never saw. Results go to `--out`: `result.json`,
//! `convergence.png` (best and mean lap time per generation) and `tuned_lap.png` (a
//! tuned lap drawn on the map, coloured by speed).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use paddock_policy::driver_info;
use paddock_rollout::benchmark::mean_std;
use paddock_rollout::{
    EpisodeResult, EpisodeTask, Executor, LocalExecutor, Scenario, Termination, task_seed,
};
use paddock_sim::track::{Circuit, DEFAULT_MAP};
use paddock_tune::{Optimizer, Options, Sigma0};
use plotters::style::RGBColor;
use serde::Serialize;

use crate::plots;

#[derive(Args)]
pub struct TuneArgs {
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    map: Option<String>,
    /// Driver to tune (see `paddock drivers`).
    #[arg(long, default_value = "pure-pursuit")]
    policy: String,
    #[arg(long, default_value_t = 60)]
    generations: u32,
    /// Candidates per generation.
    #[arg(long, default_value_t = 12)]
    popsize: usize,
    /// Seeded random starts each candidate is driven from.
    #[arg(long, default_value_t = 8)]
    seeds: usize,
    /// Held-out starts for the final comparison.
    #[arg(long, default_value_t = 20)]
    holdout: usize,
    /// Job seed: fixes the optimiser and every start.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Added to a candidate's cost for an episode that does not finish its lap, seconds.
    #[arg(long, default_value_t = 100.0)]
    crash_penalty: f64,
    /// Output directory.
    #[arg(long, default_value = "tune-out")]
    out: PathBuf,
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct Generation {
    generation: u32,
    evaluations: u64,
    /// Best candidate of this generation: its fitness and mean lap time.
    best_fitness: f64,
    best_lap_time: Option<f64>,
    /// Mean lap time over this generation's finished episodes.
    mean_lap_time: Option<f64>,
    finished_fraction: f64,
    best_so_far: f64,
    sigma: f64,
    rollouts_per_s: f64,
}

#[derive(Serialize)]
struct Evaluation {
    episodes: usize,
    finished: usize,
    lap_time_mean: Option<f64>,
    lap_time_std: Option<f64>,
}

fn evaluate(results: &[EpisodeResult]) -> Evaluation {
    let laps: Vec<f64> = results
        .iter()
        .filter(|e| e.agents[0].termination == Termination::Finished)
        .flat_map(|e| e.agents[0].lap_times.iter().copied())
        .collect();
    let (m, s) = mean_std(&laps);
    Evaluation {
        episodes: results.len(),
        finished: results
            .iter()
            .filter(|e| e.agents[0].termination == Termination::Finished)
            .count(),
        lap_time_mean: m.is_finite().then_some(m),
        lap_time_std: s.is_finite().then_some(s),
    }
}

/// One episode's cost: its lap time, or the penalty plus the unfinished fraction of the
/// lap times the penalty (so a candidate that gets further is better).
fn cost(e: &EpisodeResult, lap_length: f64, penalty: f64) -> f64 {
    let a = &e.agents[0];
    if a.termination == Termination::Finished {
        a.lap_times.iter().sum()
    } else {
        let done = (a.progress / lap_length).clamp(0.0, 1.0);
        penalty * (2.0 - done)
    }
}

pub fn run(args: &TuneArgs) -> Result<()> {
    if args.generations == 0 || args.popsize < 2 || args.seeds == 0 || args.holdout == 0 {
        bail!(
            "--generations, --seeds and --holdout must be at least 1 and --popsize at least 2 \
             (got {}, {}, {}, {})",
            args.generations,
            args.seeds,
            args.holdout,
            args.popsize
        );
    }
    if !(args.crash_penalty.is_finite() && args.crash_penalty > 0.0) {
        bail!(
            "--crash-penalty must be a positive number, got {}",
            args.crash_penalty
        );
    }
    let map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    let circuit = Circuit::resolve(&map, &[]).with_context(|| format!("loading map {map:?}"))?;
    let info = driver_info(&args.policy)?;
    let lap_length = circuit.track.length();
    let mut base = Scenario::single(info.name)?;
    base.map = circuit.dir.display().to_string();
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * lap_length;
    let defaults: Vec<f64> = info.params.iter().map(|p| p.default).collect();
    let bounds: Vec<(f64, f64)> = info.params.iter().map(|p| (p.lo, p.hi)).collect();
    let options = Options::new(defaults.clone(), Sigma0::FractionOfWidth(0.15))
        .with_bounds(bounds)
        .with_popsize(args.popsize)
        .with_seed(args.seed)
        .with_max_restarts(3);
    let mut opt = Optimizer::new(options)?;
    let exec = LocalExecutor::new(args.threads)?;
    let train: Vec<u64> = (0..args.seeds as u64)
        .map(|k| task_seed(args.seed, k))
        .collect();
    // every parameter vector driven from every seed, vector-major
    let tasks_for = |params: &[Vec<f64>], seeds: &[u64]| -> Vec<EpisodeTask> {
        params
            .iter()
            .flat_map(|p| {
                let mut sc = base.clone();
                sc.agents[0].params = p.clone();
                let sc = Arc::new(sc);
                seeds.iter().map(move |&seed| EpisodeTask {
                    scenario: sc.clone(),
                    seed,
                    record: None,
                })
            })
            .collect()
    };

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = ProgressBar::new(args.generations as u64);
    bar.set_style(
        ProgressStyle::with_template("tune {pos}/{len} [{bar:25}] {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let started = Instant::now();
    let mut history = Vec::new();
    let mut episodes_run = 0u64;
    for g in 0..args.generations {
        if opt.is_done().is_some() {
            break;
        }
        let candidates = opt.ask()?;
        let tasks = tasks_for(&candidates, &train);
        let t0 = Instant::now();
        let results = exec.run_batch(&tasks, &|_| {});
        let rate = tasks.len() as f64 / t0.elapsed().as_secs_f64();
        episodes_run += tasks.len() as u64;
        let mut episodes = Vec::with_capacity(results.len());
        for r in results {
            episodes.push(r?);
        }
        let k = train.len();
        let fitness: Vec<f64> = episodes
            .chunks(k)
            .map(|c| {
                c.iter()
                    .map(|e| cost(e, lap_length, args.crash_penalty))
                    .sum::<f64>()
                    / k as f64
            })
            .collect();
        opt.tell(&candidates, &fitness)?;
        let best_i = (0..fitness.len())
            .min_by(|&a, &b| fitness[a].total_cmp(&fitness[b]))
            .unwrap_or(0);
        let best_eval = evaluate(&episodes[best_i * k..(best_i + 1) * k]);
        let all = evaluate(&episodes);
        let status = opt.status();
        let rec = Generation {
            generation: g + 1,
            evaluations: status.evaluations,
            best_fitness: fitness[best_i],
            best_lap_time: (best_eval.finished == k)
                .then_some(best_eval.lap_time_mean)
                .flatten(),
            mean_lap_time: all.lap_time_mean,
            finished_fraction: all.finished as f64 / all.episodes as f64,
            best_so_far: status.best_fitness,
            sigma: status.sigma,
            rollouts_per_s: rate,
        };
        bar.set_message(format!(
            "best {:.3} s, mean lap {}, {:.0} rollouts/s",
            rec.best_so_far,
            rec.mean_lap_time
                .map(|m| format!("{m:.2} s"))
                .unwrap_or_else(|| "-".into()),
            rate
        ));
        bar.inc(1);
        tracing::info!(
            generation = g + 1,
            best = rec.best_so_far,
            mean_lap = rec.mean_lap_time,
            rollouts_per_s = rate,
            "generation done"
        );
        history.push(rec);
    }
    bar.finish_and_clear();
    let tuning_s = started.elapsed().as_secs_f64();
    let (best_x, best_fitness) = opt
        .best()
        .map(|(x, f)| (x.to_vec(), f))
        .context("the optimiser told no finite fitness")?;
    // The best single sample was chosen on few noisy starts; the distribution's mean is
    // often the more robust driver. Validate both on fresh starts and keep the better.
    let validation: Vec<u64> = (0..(2 * args.seeds) as u64)
        .map(|k| task_seed(args.seed ^ 0x5641_4c49_4441_5445, k))
        .collect();
    let contenders = [best_x.clone(), opt.mean()];
    let val_tasks = tasks_for(&contenders, &validation);
    let mut val_costs = [0.0f64; 2];
    for (i, r) in exec.run_batch(&val_tasks, &|_| {}).into_iter().enumerate() {
        val_costs[i / validation.len()] += cost(&r?, lap_length, args.crash_penalty);
    }
    let chosen = if val_costs[1] < val_costs[0] {
        "mean"
    } else {
        "best sample"
    };
    let tuned = if val_costs[1] < val_costs[0] {
        contenders[1].clone()
    } else {
        best_x
    };
    tracing::info!(
        chosen,
        best = val_costs[0],
        mean = val_costs[1],
        "validation"
    );

    // Held-out comparison: seeds the optimiser never saw.
    let holdout: Vec<u64> = (0..args.holdout as u64)
        .map(|k| task_seed(args.seed ^ 0x4845_4c44_4f55_5421, k))
        .collect();
    let mut eval_tasks = tasks_for(&[defaults.clone(), tuned.clone()], &holdout);
    // the tuned lap on the first held-out start is drawn on the map
    eval_tasks[holdout.len()].record = Some(2);
    let results = exec.run_batch(&eval_tasks, &|_| {});
    let mut episodes = Vec::with_capacity(results.len());
    for r in results {
        episodes.push(r?);
    }
    let (default_eps, tuned_eps) = episodes.split_at(holdout.len());
    let default_eval = evaluate(default_eps);
    let tuned_eval = evaluate(tuned_eps);
    let improvement = match (default_eval.lap_time_mean, tuned_eval.lap_time_mean) {
        (Some(d), Some(t)) => Some(100.0 * (d - t) / d),
        _ => None,
    };
    let named = |v: &[f64]| -> serde_json::Map<String, serde_json::Value> {
        info.params
            .iter()
            .zip(v)
            .map(|(s, x)| (s.name.to_string(), serde_json::json!(x)))
            .collect()
    };
    let total_s = started.elapsed().as_secs_f64();
    let result = serde_json::json!({
        "map": circuit.name,
        "policy": info.name,
        "seed": args.seed,
        "generations": history.len(),
        "popsize": args.popsize,
        "seeds": args.seeds,
        "holdout": args.holdout,
        "evaluations": opt.status().evaluations,
        "episodes_run": episodes_run,
        "tuning_s": tuning_s,
        "total_s": total_s,
        "rollouts_per_s": episodes_run as f64 / tuning_s,
        "best_fitness": best_fitness,
        "chosen": chosen,
        "params": { "default": named(&defaults), "tuned": named(&tuned) },
        "default": default_eval,
        "tuned": tuned_eval,
        "improvement_pct": improvement,
        "history": history,
    });
    let json_path = args.out.join("result.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&result)?)
        .with_context(|| format!("writing {}", json_path.display()))?;

    // Plots.
    let gens = |f: &dyn Fn(&Generation) -> Option<f64>| -> Vec<(f64, f64)> {
        history
            .iter()
            .filter_map(|h| f(h).map(|y| (h.generation as f64, y)))
            .collect()
    };
    plots::line_plot(
        &args.out.join("convergence.png"),
        &format!("CMA-ES tuning of {} on {}", info.name, circuit.name),
        "generation",
        "lap time [s]",
        &[
            plots::Series {
                name: "best candidate (mean over starts)".into(),
                points: gens(&|h| h.best_lap_time),
                color: RGBColor(200, 40, 40),
            },
            plots::Series {
                name: "generation mean (finished laps)".into(),
                points: gens(&|h| h.mean_lap_time),
                color: RGBColor(40, 90, 200),
            },
        ],
    )?;
    if let Some(tr) = tuned_eps.first().and_then(|e| e.trajectory.as_ref()) {
        let a = &tr.agents[0];
        plots::lap_on_map(
            &args.out.join("tuned_lap.png"),
            &format!(
                "{} tuned on {}: {}",
                info.name,
                circuit.name,
                tuned_eps[0].agents[0]
                    .lap_times
                    .first()
                    .map(|t| format!("lap {t:.2} s"))
                    .unwrap_or_else(|| "no lap".into())
            ),
            &circuit,
            &a.x,
            &a.y,
            &a.speed,
        )?;
    }

    if args.json {
        println!("{}", serde_json::to_string_pretty(&result)?);
        return Ok(());
    }
    let fmt = |e: &Evaluation| match (e.lap_time_mean, e.lap_time_std) {
        (Some(m), Some(s)) => format!("{m:.3} ± {s:.3} s ({}/{} finished)", e.finished, e.episodes),
        _ => format!("no lap finished (0/{})", e.episodes),
    };
    println!(
        "tuned {} on {} ({:.1} m): {} generations x {} candidates x {} starts, {:.1} s, {:.0} rollouts/s",
        info.name,
        circuit.name,
        lap_length,
        history.len(),
        args.popsize,
        args.seeds,
        tuning_s,
        episodes_run as f64 / tuning_s
    );
    println!("held-out lap time over {} starts:", args.holdout);
    println!("  default: {}", fmt(&default_eval));
    println!("  tuned:   {}", fmt(&tuned_eval));
    if let Some(p) = improvement {
        println!("  improvement: {p:.1}%");
    }
    println!("tuned parameters:");
    for (s, (d, t)) in info.params.iter().zip(defaults.iter().zip(&tuned)) {
        println!("  {:<18} {:>9.4}  (default {})", s.name, t, d);
    }
    println!(
        "wrote {}, convergence.png, tuned_lap.png",
        json_path.display()
    );
    Ok(())
}
