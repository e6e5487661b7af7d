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

/// What the data leave open about an effect not kept: each scanned parameter's range
/// that these data cannot tell from "off".
#[derive(Debug, Clone, PartialEq)]
pub struct NotDetected {
    /// Index of a parameter in the effect's vector, and its range.
    pub ranges: Vec<(usize, [f64; 2])>,
    /// The effect "off" as the scans hold it: every parameter not being scanned stays at
    /// this value (for a multi-parameter effect the report names them).
    pub held: Vec<f64>,
}

/// C and E of the magic-formula tyre while its peak D is scanned: a typical lateral
/// shape (Pacejka's C about 1.3-1.6) without the curvature factor, which the fit too
/// frees only when it pays.
const SATURATION_SHAPE: [f64; 2] = [1.5, 0.0];

/// The effect switched off, and the parameters to scan from there, each towards one or
/// both ends of its bounds. One-parameter effects: their parameter, both ways (a gain
/// above and below 1, an offset either side). `drag`: each coefficient alone from 0,
/// the other held at 0. `tire_saturation`: its peak D down from its upper bound (a peak
/// so high that driving below it never bends the curve), C and E at
/// [`SATURATION_SHAPE`]. `friction_patch`: its mu both ways from the vehicle's, in the
/// box its best fit chose (`fitted`), where the residual pointed.
fn scans(kind: EffectKind, nominal_mu: f64, fitted: &[f64]) -> (Vec<f64>, Vec<usize>) {
    match kind {
        EffectKind::SteeringDelay
        | EffectKind::SteeringLag
        | EffectKind::SteeringOffset
        | EffectKind::SteeringBacklash
        | EffectKind::DriveLag
        | EffectKind::MeasurementDelay => (vec![0.0], vec![0]),
        EffectKind::SteeringGain | EffectKind::SpeedGain => (vec![1.0], vec![0]),
        EffectKind::Friction => (vec![nominal_mu], vec![0]),
        EffectKind::Drag => (vec![0.0, 0.0], vec![0, 1]),
        EffectKind::TireSaturation => {
            let d_off = kind.bounds()[0].1;
            (
                vec![d_off, SATURATION_SHAPE[0], SATURATION_SHAPE[1]],
                vec![0],
            )
        }
        EffectKind::FrictionPatch => {
            let mut v = vec![nominal_mu];
            v.extend_from_slice(fitted.get(1..5).unwrap_or(&[0.0; 4]));
            (v, vec![0])
        }
    }
}

/// For an effect not kept: how far from "off" each of its scanned parameters ([`scans`])
/// can go, on each side, before adding it to the final model costs more than `limit`
/// (the cost the margin allows). `fitted`: the effect's best fit (a patch's box).
pub fn could_be(
    ctx: &FitContext,
    chosen: &[Fitted],
    kind: EffectKind,
    fitted: &[f64],
    limit: f64,
) -> NotDetected {
    let (held, params) = scans(kind, ctx.nominal.mu, fitted);
    const STEPS: usize = 12;
    let side = |p: usize, end: f64| -> f64 {
        let off = held[p];
        if end == off {
            return off;
        }
        let mut last_ok = off;
        for i in 1..=STEPS {
            let v = off + (end - off) * i as f64 / STEPS as f64;
            let mut fx = chosen.to_vec();
            let mut values = held.clone();
            values[p] = v;
            fx.push(Fitted::new(kind, values));
            if ctx.cost(&fx, &|_| true) > limit {
                // between the last value passed and this one
                return 0.5 * (last_ok + v);
            }
            last_ok = v;
        }
        end
    };
    let bounds = kind.bounds();
    let ranges = params
        .into_iter()
        .map(|p| {
            let (lo, hi) = bounds[p];
            let off = held[p];
            (p, [side(p, lo.min(off)), side(p, hi.max(off))])
        })
        .collect();
    NotDetected { ranges, held }
}

/// Refit the kept effects jointly, none held at its first value. The steering delay acts
/// in whole steps, a step function the optimiser cannot follow: with an effect it trades
/// off against (a steering lag, a pose latency) it is profiled instead
/// (every 2 steps over its range, then the neighbours of the best), the others refitted
/// at each value; it stays held at the best value for the held-out refits.
pub fn joint_refit(ctx: &FitContext, chosen: &[Fitted]) -> Result<Vec<Fitted>, SysidError> {
    joint_refit_on(ctx, &[], chosen)
}

/// [`joint_refit`] of `chosen` with the effects `base` held.
pub fn joint_refit_on(
    ctx: &FitContext,
    base: &[Fitted],
    chosen: &[Fitted],
) -> Result<Vec<Fitted>, SysidError> {
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
        return Ok(ctx.fit(base, chosen, &|_| true, evals)?.0);
    };
    let at = |n: usize| -> Result<(Vec<Fitted>, f64), SysidError> {
        let mut fx = chosen.to_vec();
        fx[di].values[0] = n as f64 * crate::replay::DT;
        fx[di].pinned = vec![0];
        ctx.fit(base, &fx, &|_| true, evals / 2)
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

/// The delay-like effects: a candidate among them is fitted together with those already
/// kept ([`crate::fit::FitContext::evidence`]).
pub const DELAY_LIKE: &[EffectKind] = CONFUSABLE[0];

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
    use crate::fit::FitContext;
    use crate::recording::{Command, Recording, StateSample};
    use crate::replay::Replay;
    use paddock_sim::dynamics::Vehicle;
    use paddock_sim::geometry::Pose;
    use paddock_sim::params::VehicleParams;

    /// 12 s of the nominal car weaving at 2 and 5 m/s, logged at 50 Hz with noise.
    fn nominal_drive() -> Recording {
        let p = VehicleParams::default();
        let mut rng = paddock_sim::rng::Rng::new(3);
        let mut car = Vehicle::new(Pose::new(0.0, 0.0, 0.0));
        let mut rec = Recording::default();
        for k in 0..1200 {
            let t = k as f64 * crate::replay::DT;
            let speed = if ((t / 3.0) as usize).is_multiple_of(2) {
                2.0
            } else {
                5.0
            };
            let steer = 0.08 * libm::sin(std::f64::consts::TAU * t / 2.5);
            if k % 2 == 0 {
                let (vx, vy) = car.body_velocity();
                let s = car.state;
                let mut n = |sd: f64| sd * rng.normal();
                rec.states.push(StateSample {
                    t,
                    x: s.x + n(0.01),
                    y: s.y + n(0.01),
                    yaw: crate::recording::wrap_pi(s.yaw + n(0.005)),
                    vx: vx + n(0.03),
                    vy: vy + n(0.02),
                    yaw_rate: s.yaw_rate + n(0.02),
                });
                rec.commands.push(Command { t, steer, speed });
            }
            car.step(&p, steer, speed, crate::replay::DT);
        }
        rec
    }

    /// Every effect not kept gets a "could be up to" range, multi-parameter ones too
    /// (drag, tire_saturation and friction_patch got none): each scanned parameter's
    /// range starts at "off" and reaches some way out, the others held where documented.
    #[test]
    fn every_effect_not_kept_gets_a_could_be_range() {
        let rec = nominal_drive();
        let replay = Replay::new(&rec, 1.0);
        let nominal = VehicleParams::default();
        let n_w = replay.n_windows();
        let ctx = FitContext {
            replay: &replay,
            nominal: &nominal,
            fold_of_window: (0..n_w).map(|w| w * 3 / n_w).collect(),
            folds: 3,
            extent: [-30.0, -30.0, 30.0, 30.0],
            patch_seeds: Vec::new(),
            seed: 1,
            effort: 1.0,
        };
        let limit = ctx.cost(&[], &|_| true) * 1.03;
        let patch_box = [0.0, -3.0, 6.0, 3.0];
        for kind in crate::effects::ALL {
            let mut fitted = kind.start(&nominal);
            if kind == EffectKind::FrictionPatch {
                fitted = [&[0.5][..], &patch_box[..]].concat();
            }
            let nd = could_be(&ctx, &[], kind, &fitted, limit);
            assert!(!nd.ranges.is_empty(), "{}: {nd:?}", kind.name());
            for &(p, [lo, hi]) in &nd.ranges {
                let off = nd.held[p];
                let (blo, bhi) = kind.bounds()[p];
                assert!(
                    blo <= lo && lo <= off && off <= hi && hi <= bhi && hi - lo > 0.0,
                    "{} {}: [{lo}, {hi}] around {off}",
                    kind.name(),
                    kind.param_names()[p]
                );
            }
        }
        let nd = |k: EffectKind, f: &[f64]| could_be(&ctx, &[], k, f, limit);
        // drag: each coefficient alone from 0, the other at 0
        let drag = nd(EffectKind::Drag, &[0.1, 0.01]);
        assert_eq!(drag.held, vec![0.0, 0.0]);
        assert_eq!(drag.ranges.iter().map(|r| r.0).collect::<Vec<_>>(), [0, 1]);
        assert!(
            drag.ranges
                .iter()
                .all(|(_, [lo, hi])| *lo == 0.0 && *hi > 0.0)
        );
        // tire saturation: the peak D down from its bound, C 1.5 and E 0
        let tire = nd(EffectKind::TireSaturation, &[0.7, 2.0, 0.5]);
        assert_eq!(tire.held, vec![1.6, 1.5, 0.0]);
        let [(0, [lo, hi])] = tire.ranges[..] else {
            panic!("{tire:?}")
        };
        assert!(lo < 1.6 && hi == 1.6, "{tire:?}");
        // friction patch: mu both ways from the vehicle's, in the fitted box
        let patch = nd(EffectKind::FrictionPatch, &[0.5, 0.0, -3.0, 6.0, 3.0]);
        assert_eq!(patch.held[1..], patch_box);
        let [(0, [lo, hi])] = patch.ranges[..] else {
            panic!("{patch:?}")
        };
        assert!(lo < nominal.mu && nominal.mu < hi, "{patch:?}");
    }

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
