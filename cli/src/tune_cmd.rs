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

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use paddock_policy::driver_info;
use paddock_rollout::tune_job::{Evaluation, Generation, TuneJob, TuneResult, TuneSpec};
use paddock_rollout::{Executor, LocalExecutor, Scenario};
use paddock_sim::circuit::{Circuit, Circuits, DEFAULT_MAP};
use plotters::style::RGBColor;

use crate::args::{self, outln};
use crate::plots;

#[derive(Args)]
pub struct TuneArgs {
    /// Map name or directory (default: the default shipped map).
    #[arg(long)]
    pub map: Option<String>,
    /// Driver to tune (see `paddock drivers`).
    #[arg(long, alias = "policy", default_value = "pure-pursuit")]
    pub driver: String,
    /// Vehicle YAML (as `paddock sysid` writes it): tune for this car (default: the
    /// f1tenth_gym vehicle).
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,
    /// CMA-ES generations.
    #[arg(long, default_value_t = 60, value_parser = args::whole::<u32>(1, 10_000))]
    pub generations: u32,
    /// Candidates per generation.
    #[arg(long, default_value_t = 12, value_parser = args::whole::<usize>(2, 1_000))]
    pub popsize: usize,
    /// Seeded random starts each candidate is driven from.
    #[arg(long, default_value_t = 8, value_parser = args::whole::<usize>(1, 1_000))]
    pub seeds: usize,
    /// Held-out starts for the final comparison.
    #[arg(long, default_value_t = 20, value_parser = args::whole::<usize>(1, 10_000))]
    pub holdout: usize,
    /// Job seed: fixes the optimiser and every start.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    pub seed: u64,
    /// Added to a candidate's cost for an episode that does not finish its lap, seconds.
    #[arg(long, default_value_t = 100.0, value_parser = args::above(0.0, 1e6))]
    pub crash_penalty: f64,
    /// Output directory.
    #[arg(long, default_value = "tune-out")]
    pub out: PathBuf,
    /// Worker threads (0: one per core; at most 4 per core).
    #[arg(long, default_value_t = 0, value_parser = args::threads())]
    pub threads: usize,
    /// Print the result document as JSON.
    #[arg(long)]
    pub json: bool,
    /// Run the job on the broker at this client endpoint instead of locally.
    #[arg(long, value_name = "URL")]
    pub endpoint: Option<String>,
    /// With --endpoint: print the job id and return (follow it with `paddock jobs wait`).
    #[arg(long, requires = "endpoint")]
    pub detach: bool,
}

/// The job spec and base scenario of these arguments, with the loaded circuit.
pub fn setup(args: &TuneArgs, circuits: &Circuits) -> Result<(TuneSpec, Scenario, Arc<Circuit>)> {
    let map = args.map.clone().unwrap_or_else(|| DEFAULT_MAP.into());
    let circuit = circuits
        .get(&map)
        .with_context(|| format!("loading map {map:?}"))?;
    let info = driver_info(&args.driver)?;
    let spec = TuneSpec {
        driver: info.name.to_string(),
        generations: args.generations,
        popsize: args.popsize,
        seeds: args.seeds,
        holdout: args.holdout,
        seed: args.seed,
        crash_penalty: args.crash_penalty,
    };
    spec.validate()?;
    let mut base = Scenario::single(info.name)?;
    base.agents[0].vehicle = args::vehicle(args.vehicle.as_deref())?;
    // the same registry answers this name with the same circuit for the whole run
    base.map = map;
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * circuit.track.length();
    Ok((spec, base, circuit))
}

/// A local tuning run (`paddock tune` without `--endpoint`; with it, `main` hands the
/// job to the broker through [`crate::jobs_cmd::tune_remote`]).
pub fn run(args: &TuneArgs, circuits: &Circuits) -> Result<()> {
    let (spec, base, circuit) = setup(args, circuits)?;
    let mut job = TuneJob::new(spec, base, circuit.track.length())?;
    let exec = LocalExecutor::new(args.threads, circuits.clone())?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = ProgressBar::new(job.rounds_total() as u64);
    bar.set_style(
        ProgressStyle::with_template("tune {pos}/{len} [{bar:25}] {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let started = Instant::now();
    let mut tuning_s = 0.0;
    let mut tuning_episodes = 0u64;
    while let Some(tasks) = job.next_round()? {
        let in_generations = job.history().len() < job.rounds_total() as usize - 2;
        let t0 = Instant::now();
        let results = exec.run_batch(&tasks, &|_| {});
        let dt = t0.elapsed().as_secs_f64();
        let rate = tasks.len() as f64 / dt;
        let mut episodes = Vec::with_capacity(results.len());
        for r in results {
            episodes.push(r?);
        }
        job.tell(&episodes)?;
        if in_generations {
            tuning_s += dt;
            tuning_episodes += tasks.len() as u64;
        }
        bar.set_length(job.rounds_total() as u64);
        bar.set_position(job.rounds_done() as u64);
        if let Some(g) = job.history().last() {
            bar.set_message(format!(
                "best {:.3} s, mean lap {}, {:.0} rollouts/s",
                g.best_so_far,
                g.mean_lap_time
                    .map(|m| format!("{m:.2} s"))
                    .unwrap_or_else(|| "-".into()),
                rate
            ));
            tracing::info!(
                generation = g.generation,
                best = g.best_so_far,
                mean_lap = g.mean_lap_time,
                rollouts_per_s = rate,
                "round done"
            );
        }
    }
    bar.finish_and_clear();
    let r = job
        .result()
        .context("the tuning job ended without a result")?;
    report(
        args,
        &circuit,
        r,
        Timing {
            tuning_s,
            tuning_episodes,
            total_s: started.elapsed().as_secs_f64(),
        },
    )
}

/// The held-out comparison as printed: how many starts each side finished, their lap
/// times, and an improvement only where [`TuneResult::improvement_pct`] claims one (never
/// for a tuned driver that finishes fewer starts).
pub fn holdout_summary(r: &TuneResult) -> Vec<String> {
    let fmt = |e: &Evaluation| match (e.lap_time_mean, e.lap_time_std) {
        (Some(m), Some(s)) => format!(
            "finished {}/{} starts, lap time {m:.3} ± {s:.3} s",
            e.finished, e.episodes
        ),
        _ => format!("finished 0/{} starts, no lap time", e.episodes),
    };
    let mut lines = vec![
        format!("held-out comparison over {} starts:", r.holdout),
        format!("  default: {}", fmt(&r.default)),
        format!("  tuned:   {}", fmt(&r.tuned)),
    ];
    lines.push(match r.improvement_pct {
        Some(p) if p >= 0.0 => format!("  improvement: {p:.1}% faster laps, as many starts finished or more"),
        Some(p) => format!("  no improvement: tuned laps {:.1}% slower", -p),
        None if r.tuned.finished < r.default.finished => format!(
            "  no improvement: the tuned driver finished fewer held-out starts ({}/{} against {}/{})",
            r.tuned.finished, r.tuned.episodes, r.default.finished, r.default.episodes
        ),
        None => "  no improvement measurable: a side finished no held-out start".to_string(),
    });
    lines
}

/// Wall-clock figures of a run (not part of the deterministic result).
pub struct Timing {
    pub tuning_s: f64,
    pub tuning_episodes: u64,
    pub total_s: f64,
}

/// Writes result.json and the plots, and prints the result (or its JSON).
pub fn report(args: &TuneArgs, circuit: &Circuit, r: &TuneResult, timing: Timing) -> Result<()> {
    let info = driver_info(&r.driver)?;
    let lap_length = circuit.track.length();
    let rollouts_per_s = timing.tuning_episodes as f64 / timing.tuning_s.max(1e-9);
    let named = |v: &[f64]| -> serde_json::Map<String, serde_json::Value> {
        info.params
            .iter()
            .zip(v)
            .map(|(s, x)| (s.name.to_string(), serde_json::json!(x)))
            .collect()
    };
    let history: Vec<serde_json::Value> = r
        .history
        .iter()
        .map(|g| serde_json::to_value(g).unwrap_or_default())
        .collect();
    let result = serde_json::json!({
        "map": circuit.name,
        "driver": r.driver,
        "seed": r.seed,
        "generations": r.generations,
        "popsize": r.popsize,
        "seeds": r.seeds,
        "holdout": r.holdout,
        "evaluations": r.evaluations,
        "episodes_run": r.episodes_run,
        "tuning_s": timing.tuning_s,
        "total_s": timing.total_s,
        "rollouts_per_s": rollouts_per_s,
        "best_fitness": r.best_fitness,
        "chosen": r.chosen,
        "params": { "default": named(&r.default_params), "tuned": named(&r.tuned_params) },
        "default": r.default,
        "tuned": r.tuned,
        "improvement_pct": r.improvement_pct,
        "history": history,
    });
    let json_path = args.out.join("result.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&result)?)
        .with_context(|| format!("writing {}", json_path.display()))?;

    // Plots.
    let gens = |f: &dyn Fn(&Generation) -> Option<f64>| -> Vec<(f64, f64)> {
        r.history
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
    if let Some(example) = &r.tuned_example
        && let Some(tr) = &example.trajectory
    {
        let a = &tr.agents[0];
        plots::lap_on_map(
            &args.out.join("tuned_lap.png"),
            &format!(
                "{} tuned on {}: {}",
                info.name,
                circuit.name,
                example.agents[0]
                    .lap_times
                    .first()
                    .map(|t| format!("lap {t:.2} s"))
                    .unwrap_or_else(|| "no lap".into())
            ),
            circuit,
            &a.x,
            &a.y,
            &a.speed,
        )?;
    }

    if args.json {
        outln!("{}", serde_json::to_string_pretty(&result)?);
        return Ok(());
    }
    outln!(
        "tuned {} on {} ({:.1} m): {} generations x {} candidates x {} starts, {:.1} s, {:.0} rollouts/s",
        info.name,
        circuit.name,
        lap_length,
        r.history.len(),
        r.popsize,
        r.seeds,
        timing.tuning_s,
        rollouts_per_s
    );
    for line in holdout_summary(r) {
        outln!("{line}");
    }
    outln!("tuned parameters:");
    for (s, (d, t)) in info
        .params
        .iter()
        .zip(r.default_params.iter().zip(&r.tuned_params))
    {
        outln!("  {:<18} {:>9.4}  (default {})", s.name, t, d);
    }
    outln!(
        "wrote {}, convergence.png, tuned_lap.png",
        json_path.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(default: (usize, Option<f64>), tuned: (usize, Option<f64>)) -> TuneResult {
        let eval = |(finished, mean): (usize, Option<f64>)| Evaluation {
            episodes: 20,
            finished,
            lap_time_mean: mean,
            lap_time_std: mean.map(|_| 0.2),
        };
        let (d, t) = (eval(default), eval(tuned));
        TuneResult {
            driver: "pure-pursuit".into(),
            seed: 0,
            generations: 1,
            popsize: 4,
            seeds: 2,
            holdout: 20,
            evaluations: 4,
            episodes_run: 48,
            best_fitness: 9.0,
            chosen: "mean".into(),
            default_params: vec![],
            tuned_params: vec![],
            improvement_pct: paddock_rollout::tune_job::improvement_pct(&d, &t),
            default: d,
            tuned: t,
            history: vec![],
            tuned_example: None,
        }
    }

    #[test]
    fn summary_never_claims_an_improvement_for_fewer_finished_starts() {
        let text = holdout_summary(&result((20, Some(10.0)), (12, Some(8.0)))).join("\n");
        assert!(text.contains("default: finished 20/20 starts"), "{text}");
        assert!(text.contains("tuned:   finished 12/20 starts"), "{text}");
        assert!(!text.contains("  improvement:"), "{text}");
        assert!(
            text.contains("finished fewer held-out starts (12/20 against 20/20)"),
            "{text}"
        );

        let text = holdout_summary(&result((20, Some(10.0)), (20, Some(9.0)))).join("\n");
        assert!(text.contains("improvement: 10.0% faster"), "{text}");

        let text = holdout_summary(&result((15, Some(10.0)), (0, None))).join("\n");
        assert!(
            text.contains("tuned:   finished 0/20 starts, no lap time"),
            "{text}"
        );
        assert!(!text.contains("  improvement:"), "{text}");
    }
}
