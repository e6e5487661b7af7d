//! How sure the analysis is: the joint refit that lets trading-off parameters move
//! together, intervals of kept parameters, the range a rejected effect could still have,
//! and the effects the data cannot tell apart.

use rayon::prelude::*;

use crate::SysidError;
use crate::effects::EffectKind;
use crate::fit::{Evidence, FitContext, Fitted, budget};

/// Per parameter of `c`: its range over the held-out refits, widened to two jackknife
/// standard errors around the final value (a delay: at least half a step).
pub fn interval(c: &Fitted, fold_fits: &[Vec<Fitted>]) -> Vec<[f64; 2]> {
    let bounds = c.kind.bounds();
    (0..c.values.len())
        .map(|i| {
            let v = c.values[i];
            let xs: Vec<f64> = fold_fits
                .iter()
                .filter_map(|f| f.iter().find(|e| e.kind == c.kind).map(|e| e.values[i]))
                .collect();
            let n = xs.len() as f64;
            let mut half = 0.0;
            if n >= 2.0 {
                let mean = xs.iter().sum::<f64>() / n;
                let jack =
                    ((n - 1.0) / n * xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>()).sqrt();
                half = 2.0 * jack;
            }
            if c.kind == EffectKind::SteeringDelay {
                half = half.max(0.5 * crate::replay::DT);
            }
            let lo = xs.iter().copied().fold(v - half, f64::min);
            let hi = xs.iter().copied().fold(v + half, f64::max);
            match bounds.get(i) {
                Some(&(blo, bhi)) => [lo.max(blo), hi.min(bhi)],
                None => [lo, hi],
            }
        })
        .collect()
}

/// The parameter value that switches a one-parameter effect off.
fn off_value(kind: EffectKind, nominal_mu: f64) -> Option<f64> {
    Some(match kind {
        EffectKind::SteeringDelay
        | EffectKind::SteeringLag
        | EffectKind::SteeringOffset
        | EffectKind::SteeringBacklash
        | EffectKind::DriveLag
        | EffectKind::MeasurementDelay => 0.0,
        EffectKind::SteeringGain | EffectKind::SpeedGain => 1.0,
        EffectKind::Friction => nominal_mu,
        _ => return None,
    })
}

/// For an effect not kept: how far from "off" its parameter can go, on each side, before
/// adding it to the final model costs more than `limit` (the cost the margin allows).
pub fn could_be(
    ctx: &FitContext,
    chosen: &[Fitted],
    kind: EffectKind,
    limit: f64,
) -> Option<[f64; 2]> {
    let off = off_value(kind, ctx.nominal.mu)?;
    let (lo, hi) = kind.bounds()[0];
    const STEPS: usize = 12;
    let side = |end: f64| -> f64 {
        let mut last_ok = off;
        for i in 1..=STEPS {
            let v = off + (end - off) * i as f64 / STEPS as f64;
            let mut fx = chosen.to_vec();
            fx.push(Fitted::new(kind, vec![v]));
            if ctx.cost(&fx, &|_| true) > limit {
                // between the last value passed and this one
                return 0.5 * (last_ok + v);
            }
            last_ok = v;
        }
        end
    };
    Some([side(lo.min(off)), side(hi.max(off))])
}

/// Refit the kept effects jointly, none held at its first value. The steering delay acts
/// in whole steps, a step function the optimiser cannot follow: with an effect it trades
/// off against (a steering lag, a pose latency) it is profiled instead
/// (every 2 steps over its range, then the neighbours of the best), the others refitted
/// at each value; it stays held at the best value for the held-out refits.
pub fn joint_refit(ctx: &FitContext, chosen: &[Fitted]) -> Result<Vec<Fitted>, SysidError> {
    let evals: u64 = chosen.iter().map(|c| budget(c.kind)).sum();
    let trades_off = chosen.iter().any(|c| {
        matches!(
            c.kind,
            EffectKind::SteeringLag | EffectKind::MeasurementDelay
        )
    });
    let di = chosen
        .iter()
        .position(|c| c.kind == EffectKind::SteeringDelay);
    let Some(di) = di.filter(|_| trades_off) else {
        return Ok(ctx.fit(&[], chosen, &|_| true, evals)?.0);
    };
    let at = |n: usize| -> Result<(Vec<Fitted>, f64), SysidError> {
        let mut fx = chosen.to_vec();
        fx[di].values[0] = n as f64 * crate::replay::DT;
        fx[di].pinned = vec![0];
        ctx.fit(&[], &fx, &|_| true, evals / 2)
    };
    let max_n = (EffectKind::SteeringDelay.bounds()[0].1 / crate::replay::DT).round() as usize;
    let coarse: Vec<usize> = (0..=max_n).step_by(2).collect();
    let mut tried: Vec<(usize, Vec<Fitted>, f64)> = Vec::new();
    let results: Vec<Result<(Vec<Fitted>, f64), SysidError>> =
        coarse.par_iter().map(|&n| at(n)).collect();
    for (n, r) in coarse.iter().zip(results) {
        let (f, c) = r?;
        tried.push((*n, f, c));
    }
    let best_n = tried
        .iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map_or(0, |t| t.0);
    let fine: Vec<usize> = [best_n.wrapping_sub(1), best_n + 1]
        .into_iter()
        .filter(|n| *n <= max_n)
        .collect();
    let results: Vec<Result<(Vec<Fitted>, f64), SysidError>> =
        fine.par_iter().map(|&n| at(n)).collect();
    for (n, r) in fine.iter().zip(results) {
        let (f, c) = r?;
        tried.push((*n, f, c));
    }
    let (_, best, _) = tried
        .into_iter()
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .expect("at least one delay tried");
    Ok(best)
}

/// Groups of effects that can stand in for each other.
const CONFUSABLE: [&[EffectKind]; 4] = [
    &[
        EffectKind::SteeringDelay,
        EffectKind::SteeringLag,
        EffectKind::MeasurementDelay,
    ],
    &[
        EffectKind::Friction,
        EffectKind::TireSaturation,
        EffectKind::SteeringGain,
    ],
    &[
        EffectKind::DriveLag,
        EffectKind::SpeedGain,
        EffectKind::Drag,
    ],
    &[EffectKind::SteeringOffset, EffectKind::SteeringBacklash],
];

/// What would separate each group.
const SEPARATING: [&str; 4] = [
    "steering steps at two speeds with speed steps in between (a pose latency shifts the speed response too; a lag rounds a step, a delay shifts it)",
    "arcs at rising speed up to the grip limit (a gain acts at every speed, friction and saturation only near the limit)",
    "speed steps up and down at low and at high speed (a lag shapes the step, a gain its level, drag grows with speed)",
    "steering steps in both directions (an offset shifts both the same way, play opposes the reversal)",
];

/// In the round an effect was kept, a confusable candidate that explained the data
/// nearly as well (within 20 % of its held-out gain, and significant itself) is reported
/// with it, with the manoeuvre that would separate them; delay-like effects also get
/// their effective dead time.
pub fn ambiguities(rounds: &[Vec<Evidence>], chosen: &[Fitted]) -> Vec<String> {
    let mut out = Vec::new();
    for round in rounds {
        let Some(best) = round
            .iter()
            .filter(|e| e.significant)
            .max_by(|a, b| a.gain.total_cmp(&b.gain))
        else {
            continue;
        };
        let Some(g) = CONFUSABLE.iter().position(|g| g.contains(&best.kind)) else {
            continue;
        };
        let rivals: Vec<&Evidence> = round
            .iter()
            .filter(|e| {
                e.kind != best.kind
                    && CONFUSABLE[g].contains(&e.kind)
                    && e.significant
                    && e.gain >= 0.8 * best.gain
            })
            .collect();
        if rivals.is_empty() {
            continue;
        }
        let names: Vec<&str> = rivals.iter().map(|e| e.kind.name()).collect();
        // every kept effect of the family, in the order kept: a later round may have
        // added another one (a pose latency taking up part of a delay and a lag)
        let kept: Vec<&str> = chosen
            .iter()
            .filter(|c| CONFUSABLE[g].contains(&c.kind))
            .map(|c| c.kind.name())
            .collect();
        // every rival kept too (a later round added it, fitted jointly): they trade off,
        // but the data did separate them
        let all_kept = rivals
            .iter()
            .all(|e| chosen.iter().any(|c| c.kind == e.kind));
        let mut line = format!(
            "{} and {} {} (held-out gain {:.0} % vs {}); kept {}",
            best.kind.name(),
            names.join(", "),
            if all_kept {
                "trade off here, and were told apart only by fitting them jointly"
            } else {
                "are not separable here"
            },
            100.0 * best.gain,
            rivals
                .iter()
                .map(|e| format!("{:.0} %", 100.0 * e.gain))
                .collect::<Vec<_>>()
                .join(", "),
            if kept.is_empty() {
                best.kind.name().to_string()
            } else {
                kept.join(" + ")
            }
        );
        if g == 0 {
            let dead: f64 = chosen
                .iter()
                .filter(|c| CONFUSABLE[0].contains(&c.kind))
                .map(|c| c.values[0])
                .sum();
            line.push_str(&format!(
                "; together the delay-like effects act as an effective delay of {dead:.3} s"
            ));
        }
        line.push_str(&format!("; to separate them drive {}", SEPARATING[g]));
        out.push(line);
    }
    out
}

/// The range of parameter `p` of kept effect `i` over which the final model's cost stays
/// below `limit`, the others held (steps doubling outward, the crossing interpolated).
/// `None` for a friction patch's box.
pub fn profile(
    ctx: &FitContext,
    chosen: &[Fitted],
    i: usize,
    p: usize,
    limit: f64,
) -> Option<[f64; 2]> {
    let kind = chosen[i].kind;
    if kind == EffectKind::FrictionPatch && p > 0 {
        return None;
    }
    let (lo, hi) = kind.bounds()[p];
    let v0 = chosen[i].values[p];
    let first = if kind == EffectKind::SteeringDelay {
        crate::replay::DT
    } else {
        (hi - lo) / 400.0
    };
    let cost_at = |v: f64| {
        let mut fx = chosen.to_vec();
        fx[i].values[p] = v;
        ctx.cost(&fx, &|_| true)
    };
    let side = |dir: f64| -> f64 {
        let mut last = v0;
        let mut h = first;
        for _ in 0..12 {
            let v = (v0 + dir * h).clamp(lo, hi);
            if cost_at(v) > limit {
                return if kind == EffectKind::SteeringDelay {
                    last
                } else {
                    0.5 * (last + v)
                };
            }
            last = v;
            if v == lo || v == hi {
                break;
            }
            h *= 2.0;
        }
        last
    };
    Some([side(-1.0), side(1.0)])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evidence(kind: EffectKind, gain: f64) -> Evidence {
        Evidence {
            kind,
            values: vec![0.05],
            fitted: Fitted::new(kind, vec![0.05]),
            heldout_base: vec![100.0; 3],
            heldout_with: vec![100.0 * (1.0 - gain); 3],
            gain,
            folds_improved: 3,
            folds_worse: 0,
            margin: 0.03,
            significant: true,
        }
    }

    /// A lag kept in round 1 with a delay close behind, then a pose latency kept in round
    /// 2: the ambiguity names both kept effects of the family and their total dead time
    /// (it named only the lag, while the dead time counted the latency too).
    #[test]
    fn an_ambiguity_names_every_kept_effect_of_its_family() {
        let rounds = vec![
            vec![
                evidence(EffectKind::SteeringLag, 0.77),
                evidence(EffectKind::SteeringDelay, 0.75),
                evidence(EffectKind::SteeringGain, 0.1),
            ],
            vec![evidence(EffectKind::MeasurementDelay, 0.05)],
        ];
        let chosen = vec![
            Fitted::new(EffectKind::SteeringLag, vec![0.107]),
            Fitted::new(EffectKind::MeasurementDelay, vec![0.032]),
        ];
        let lines = ambiguities(&rounds, &chosen);
        assert_eq!(lines.len(), 1, "{lines:?}");
        let l = &lines[0];
        assert!(
            l.starts_with("steering_lag and steering_delay are not separable"),
            "{l}"
        );
        assert!(l.contains("kept steering_lag + measurement_delay"), "{l}");
        assert!(l.contains("effective delay of 0.139 s"), "{l}");
        // both kept: they trade off, but were separated
        let both = vec![
            Fitted::new(EffectKind::SteeringLag, vec![0.078]),
            Fitted::new(EffectKind::SteeringDelay, vec![0.06]),
        ];
        let lines = ambiguities(&rounds[..1], &both);
        assert!(
            lines[0].contains("trade off here, and were told apart")
                && lines[0].contains("kept steering_lag + steering_delay"),
            "{lines:?}"
        );
        // a clear winner: no ambiguity
        let clear = vec![vec![
            evidence(EffectKind::SteeringLag, 0.77),
            evidence(EffectKind::SteeringDelay, 0.3),
        ]];
        assert!(ambiguities(&clear, &chosen[..1]).is_empty());
    }
}
