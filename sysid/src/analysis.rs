//! The pipeline: locate, test candidates, select greedily, refit, measure held out.

use std::collections::BTreeMap;
use std::time::Instant;

use paddock_sim::params::VehicleParams;
use rayon::prelude::*;
use tracing::info;

use crate::SysidError;
use crate::effects::{ALL, EffectKind};
use crate::fit::{Evidence, FitContext, Fitted, budget, build_params, measurement_delay};
use crate::locate::{Located, locate};
use crate::recording::Recording;
use crate::replay::{Replay, Residuals};
use crate::uncertainty::{NotDetected, ambiguities, could_be, interval, joint_refit, profile};

/// A held-out block's sums of squared residuals and measured samples per channel, and the
/// fit made without it.
type FoldResult = ([f64; 6], [usize; 6], Vec<Fitted>);

/// Knobs of the analysis.
#[derive(Debug, Clone)]
pub struct AnalysisOptions {
    /// Replay window [s].
    pub window_s: f64,
    /// Cross-validation folds (contiguous time blocks).
    pub folds: usize,
    /// Held-out improvement an effect must beat, per parameter (0.01 = 1 %).
    pub margin_per_param: f64,
    /// Most effects kept.
    pub max_effects: usize,
    pub candidates: Vec<EffectKind>,
    pub seed: u64,
    /// Scales the optimiser budgets (1 = default).
    pub effort: f64,
}

impl Default for AnalysisOptions {
    fn default() -> Self {
        Self {
            window_s: 1.0,
            folds: 3,
            margin_per_param: 0.03,
            max_effects: 4,
            // every effect of the vocabulary, the pose source's latency too: a localiser's
            // latency is seldom known, and it is told apart from the actuation delays
            // (docs/sysid.md)
            candidates: ALL.to_vec(),
            seed: 1,
            effort: 1.0,
        }
    }
}

impl AnalysisOptions {
    pub fn validate(&self) -> Result<(), SysidError> {
        let bad = |field: &str, value: String, req: &str| SysidError::Option {
            field: field.into(),
            value,
            requirement: req.into(),
        };
        if !(self.window_s.is_finite() && (0.2..=5.0).contains(&self.window_s)) {
            return Err(bad("window_s", self.window_s.to_string(), "in [0.2, 5] s"));
        }
        if !(2..=10).contains(&self.folds) {
            return Err(bad("folds", self.folds.to_string(), "in [2, 10]"));
        }
        if !(self.margin_per_param.is_finite() && self.margin_per_param >= 0.0) {
            return Err(bad(
                "margin_per_param",
                self.margin_per_param.to_string(),
                ">= 0",
            ));
        }
        if !(self.effort.is_finite() && self.effort > 0.0) {
            return Err(bad("effort", self.effort.to_string(), "> 0"));
        }
        Ok(())
    }
}

/// Progress of the analysis: `done` of `total` units, and what is running.
#[derive(Debug, Clone)]
pub struct Stage {
    pub done: usize,
    pub total: usize,
    pub message: String,
}

/// One candidate's outcome.
#[derive(Debug, Clone)]
pub struct CandidateResult {
    pub evidence: Evidence,
    /// Greedy round of the last test (1-based).
    pub round: usize,
    /// Kept in the model (significant when tested and added).
    pub selected: bool,
    /// Final parameters (after the joint refit) when selected.
    pub values: Vec<f64>,
    /// Selected: per parameter, the range of the refits with each block (or group of
    /// runs) held out, widened to two jackknife standard errors.
    pub interval: Option<Vec<[f64; 2]>>,
    /// Not selected: the range of each scanned parameter these data cannot tell from
    /// "off" (adding it to the final model changes the fit by less than the margin an
    /// effect must beat).
    pub could_be: Option<NotDetected>,
}

/// Everything an analysis produced.
#[derive(Debug, Clone)]
pub struct Analysis {
    pub nominal: VehicleParams,
    pub fitted: VehicleParams,
    pub effects: Vec<Fitted>,
    pub candidates: Vec<CandidateResult>,
    pub located: Located,
    /// The same grouping of the fitted model's residuals.
    pub located_fitted: Located,
    pub nominal_residuals: Residuals,
    pub fitted_residuals: Residuals,
    pub rmse_before: [f64; 6],
    pub rmse_after: [f64; 6],
    pub rmse_fitted_in_sample: [f64; 6],
    pub noise_floor: [f64; 6],
    pub folds: usize,
    pub window_s: f64,
    /// Whether whole runs were held out (several runs) or time blocks (one).
    pub heldout_runs: bool,
    /// Effects the data cannot tell apart, in words.
    pub ambiguities: Vec<String>,
    pub excitation: crate::explain::Excitation,
    /// Effects these data cannot identify, with what to drive.
    pub not_identifiable: Vec<(EffectKind, String)>,
    pub seconds: f64,
}

/// Run the analysis of `rec` against the nominal vehicle `nominal`.
pub fn analyze(
    rec: &Recording,
    nominal: &VehicleParams,
    opts: &AnalysisOptions,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Analysis, SysidError> {
    let start = Instant::now();
    opts.validate()?;
    rec.check()?;
    nominal.validate()?;
    let replay = Replay::new(rec, opts.window_s);
    // several runs: whole runs are held out; one: contiguous time blocks
    let n_runs = replay.n_runs();
    let folds = if n_runs >= 2 {
        opts.folds.min(n_runs)
    } else {
        opts.folds
    };
    if replay.n_windows() < 2 * folds {
        return Err(SysidError::TooShort {
            samples: rec.states.len(),
            duration_s: rec.total_duration(),
            runs: n_runs,
            min_samples: crate::recording::MIN_SAMPLES,
            min_duration_s: 2.0 * folds as f64 * opts.window_s,
            hint: crate::recording::SHORT_HINT.into(),
        });
    }
    let cands: Vec<EffectKind> = opts.candidates.clone();
    let rounds = opts.max_effects.min(cands.len());
    // locate, two steps per greedy round, the held-out measurement
    let total = 2 + 2 * rounds;
    let mut done = 0usize;
    let tick = |done: &mut usize, msg: String| {
        *done += 1;
        progress(Stage {
            done: *done,
            total,
            message: msg,
        });
    };

    let nominal_residuals = replay.residuals(nominal);
    let located = locate(rec, &replay, &nominal_residuals);
    info!(
        windows = replay.n_windows(),
        samples = replay.n_samples(),
        mismatches = located.mismatch.len(),
        "located the residual"
    );
    tick(&mut done, "located the residual".into());

    let n_w = replay.n_windows();
    let extent = {
        let mut e = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
        for s in &rec.states {
            e[0] = e[0].min(s.x - 1.0);
            e[1] = e[1].min(s.y - 1.0);
            e[2] = e[2].max(s.x + 1.0);
            e[3] = e[3].max(s.y + 1.0);
        }
        e
    };
    let ctx = FitContext {
        replay: &replay,
        nominal,
        fold_of_window: {
            let group = run_groups(n_runs, folds, opts.seed);
            (0..n_w)
                .map(|w| {
                    if n_runs >= 2 {
                        group[replay.window_run(w)]
                    } else {
                        w * folds / n_w
                    }
                })
                .collect()
        },
        folds,
        extent,
        patch_seeds: located.patch_seeds.clone(),
        seed: opts.seed,
        effort: opts.effort,
    };

    let mut chosen: Vec<Fitted> = Vec::new();
    let mut round_log: Vec<Vec<Evidence>> = Vec::new();
    let mut results: BTreeMap<EffectKind, CandidateResult> = BTreeMap::new();
    for round in 1..=rounds {
        let base_heldout = ctx.fold_costs(&chosen);
        let remaining: Vec<EffectKind> = cands
            .iter()
            .copied()
            .filter(|k| !chosen.iter().any(|c| c.kind == *k))
            .collect();
        if remaining.is_empty() {
            break;
        }
        let evid: Vec<Result<Evidence, SysidError>> = remaining
            .par_iter()
            .map(|k| ctx.evidence(&chosen, &base_heldout, *k, opts.margin_per_param))
            .collect();
        let mut best: Option<Evidence> = None;
        let mut round_evidence: Vec<Evidence> = Vec::new();
        for e in evid {
            let e = e?;
            round_evidence.push(e.clone());
            info!(
                round,
                effect = e.kind.name(),
                gain = e.gain,
                folds_improved = e.folds_improved,
                significant = e.significant,
                values = ?e.values,
                "candidate"
            );
            if e.significant && best.as_ref().is_none_or(|b| e.gain > b.gain) {
                best = Some(e.clone());
            }
            results.insert(
                e.kind,
                CandidateResult {
                    values: e.values.clone(),
                    evidence: e,
                    round,
                    selected: false,
                    interval: None,
                    could_be: None,
                },
            );
        }
        tick(
            &mut done,
            format!("round {round}: tested {} effects", remaining.len()),
        );
        round_log.push(round_evidence);
        let Some(best) = best else { break };
        info!(round, effect = best.kind.name(), "kept");
        let mut kept = best.fitted.clone();
        if kept.kind == EffectKind::SteeringDelay {
            // whole steps: found by exhaustive search, and profiled (not optimised) in
            // the joint refits, which a step function would only confuse
            kept.pinned = vec![0];
        }
        chosen.push(kept);
        if let Some(r) = results.get_mut(&best.kind) {
            r.selected = true;
        }
        if chosen.len() > 1 {
            chosen = joint_refit(&ctx, &chosen)?;
        }
        tick(
            &mut done,
            format!("round {round}: kept {}", best.kind.name()),
        );
    }
    for c in chosen.iter_mut() {
        if c.kind == EffectKind::FrictionPatch {
            tighten_patch(rec, &mut c.values);
        }
    }
    for c in &chosen {
        if let Some(r) = results.get_mut(&c.kind) {
            r.values = c.values.clone();
        }
    }

    // held-out residuals of the final model: each block predicted by a fit without it
    let rmse_before = nominal_residuals.rmse(|_| true);
    let mut fold_fits: Vec<Vec<Fitted>> = Vec::new();
    let rmse_after = if chosen.is_empty() {
        rmse_before
    } else {
        let evals: u64 = chosen.iter().map(|c| budget(c.kind)).sum::<u64>() / 2;
        let per_fold: Vec<Result<FoldResult, SysidError>> = (0..folds)
            .into_par_iter()
            .map(|f| {
                let fold_of = &ctx.fold_of_window;
                let (fit, _) = ctx.fit(&[], &chosen, &|w| fold_of[w] != f, evals)?;
                let res =
                    replay.residuals_at(&build_params(nominal, &fit), measurement_delay(&fit));
                let (sq, n) = res.sum_sq(|w| fold_of[w] == f);
                Ok((sq, n, fit))
            })
            .collect();
        // pooled per channel over the blocks that measure it: a channel only some
        // recordings have (vy from one bag among pose-only CSVs) is still scored
        let mut sq = [0.0; 6];
        let mut n_all = [0usize; 6];
        for r in per_fold {
            let (s, n, fit) = r?;
            fold_fits.push(fit);
            for c in 0..6 {
                sq[c] += s[c];
                n_all[c] += n[c];
            }
        }
        std::array::from_fn(|c| {
            if n_all[c] == 0 {
                f64::NAN
            } else {
                (sq[c] / n_all[c] as f64).sqrt()
            }
        })
    };
    tick(&mut done, "measured the held-out fit".into());
    let fitted = build_params(nominal, &chosen);
    fitted.validate()?;
    let fitted_residuals = replay.residuals_at(&fitted, measurement_delay(&chosen));
    let rmse_fitted_in_sample = fitted_residuals.rmse(|_| true);
    let located_fitted = locate(rec, &replay, &fitted_residuals);
    let final_cost = ctx.cost(&chosen, &|_| true);
    let n_measured: usize = replay.window_counts().iter().sum();
    // the cost's own noise: a sum of n squared normalised residuals wanders by about
    // sqrt(2 n), inflated by how far above the noise the fit stays
    let allowed =
        2.0 * (2.0 * n_measured as f64).sqrt() * (final_cost / n_measured.max(1) as f64).max(1.0);
    let intervals: Vec<(EffectKind, Vec<[f64; 2]>)> = (0..chosen.len())
        .into_par_iter()
        .map(|i| {
            let mut iv = interval(&chosen[i], &fold_fits);
            for (p, slot) in iv.iter_mut().enumerate() {
                if let Some([lo, hi]) = profile(&ctx, &chosen, i, p, final_cost + allowed) {
                    *slot = [slot[0].min(lo), slot[1].max(hi)];
                }
            }
            (chosen[i].kind, iv)
        })
        .collect();
    for (k, iv) in intervals {
        if let Some(r) = results.get_mut(&k) {
            r.interval = Some(iv);
        }
    }
    let limit = final_cost * (1.0 + opts.margin_per_param);
    let bounds: Vec<(EffectKind, NotDetected)> = results
        .values()
        .filter(|r| !r.selected)
        .map(|r| (r.evidence.kind, r.evidence.values.clone()))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(k, fitted)| (k, could_be(&ctx, &chosen, k, &fitted, limit)))
        .collect();
    for (k, b) in bounds {
        if let Some(r) = results.get_mut(&k) {
            r.could_be = Some(b);
        }
    }
    let ambiguities = ambiguities(&round_log, &chosen);
    let excitation = crate::explain::excitation(rec);
    let not_identifiable = crate::explain::not_identifiable(&excitation, nominal.mu);
    let mut candidates: Vec<CandidateResult> = results.into_values().collect();
    candidates.sort_by_key(|c| (!c.selected, c.evidence.kind));
    Ok(Analysis {
        nominal: nominal.clone(),
        fitted,
        effects: chosen,
        candidates,
        located,
        located_fitted,
        nominal_residuals,
        fitted_residuals,
        rmse_before,
        rmse_after,
        rmse_fitted_in_sample,
        noise_floor: replay.sigma,
        folds,
        window_s: replay.window_s,
        heldout_runs: n_runs >= 2,
        ambiguities,
        excitation,
        not_identifiable,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The held-out group of each run: runs in a seeded random order, dealt out in turn, so
/// the groups are as even as the runs allow and a test day driven in a fixed cycle of
/// manoeuvres does not put every run of one manoeuvre in one group (run `k` in group
/// `k mod 3` held out all the speed steps of a step, arc, speed-step day together, and a
/// steering gain fitted without them was vetoed by them).
fn run_groups(n_runs: usize, folds: usize, seed: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n_runs).collect();
    let mut rng = paddock_sim::rng::Rng::new(seed ^ 0x5eed_f01d);
    for i in (1..n_runs).rev() {
        let j = ((rng.uniform() * (i + 1) as f64) as usize).min(i);
        order.swap(i, j);
    }
    let mut group = vec![0; n_runs];
    for (pos, run) in order.into_iter().enumerate() {
        group[run] = pos % folds.max(1);
    }
    group
}

/// Shrink a friction patch to the recorded positions inside it (plus a small margin,
/// never past the fitted box): the fit cannot see beyond where the car drove, so the
/// smallest box with the same evidence is the honest answer.
fn tighten_patch(rec: &Recording, v: &mut [f64]) {
    const MARGIN_M: f64 = 0.3;
    let [xmin, ymin, xmax, ymax] = [v[1], v[2], v[3], v[4]];
    let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for s in &rec.states {
        if s.x >= xmin && s.x <= xmax && s.y >= ymin && s.y <= ymax {
            b = [b[0].min(s.x), b[1].min(s.y), b[2].max(s.x), b[3].max(s.y)];
        }
    }
    if b[0] > b[2] {
        return;
    }
    v[1] = (b[0] - MARGIN_M).max(xmin);
    v[2] = (b[1] - MARGIN_M).max(ymin);
    v[3] = (b[2] + MARGIN_M).min(xmax);
    v[4] = (b[3] + MARGIN_M).min(ymax);
}

#[cfg(test)]
mod tests {
    use super::run_groups;

    #[test]
    fn run_groups_are_even_and_do_not_follow_a_manoeuvre_cycle() {
        let g = run_groups(12, 3, 1);
        for f in 0..3 {
            assert_eq!(g.iter().filter(|x| **x == f).count(), 4, "{g:?}");
        }
        // a day driven as step, arc, speed-step, step, ...: some group mixes manoeuvres
        let cyclic = (0..12).any(|k| g[k] != g[k % 3]);
        assert!(cyclic, "{g:?}");
        assert_eq!(g, run_groups(12, 3, 1), "deterministic per seed");
        assert_eq!(run_groups(2, 3, 7).len(), 2);
    }
}
