//! `report.json`, `report.md` and `vehicle.yaml` of an analysis.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::{Value, json};

use crate::SysidError;
use crate::analysis::Analysis;
use crate::effects::EffectKind;
use crate::locate::Group;
use crate::recording::{CHANNELS, Recording};

fn channels(v: &[f64; 6]) -> Value {
    let m: serde_json::Map<String, Value> = CHANNELS
        .iter()
        .zip(v)
        .map(|(c, x)| ((*c).to_string(), json!((x * 1e6).round() / 1e6)))
        .collect();
    Value::Object(m)
}

/// The report as JSON (shape in the crate documentation).
pub fn to_json(a: &Analysis, rec: &Recording) -> Value {
    let effects: Vec<Value> = a
        .candidates
        .iter()
        .map(|c| {
            let e = &c.evidence;
            json!({
                "name": e.kind.name(),
                "params": e.kind.params_json(&c.values),
                "significant": c.selected,
                "evidence": {
                    "heldout_gain": (e.gain * 1e5).round() / 1e5,
                    "margin": e.margin,
                    "folds_improved": e.folds_improved,
                    "folds_worse": e.folds_worse,
                    "folds": e.heldout_base.len(),
                    "heldout_cost_base": e.heldout_base.iter().map(|v| v.round()).collect::<Vec<_>>(),
                    "heldout_cost_with": e.heldout_with.iter().map(|v| v.round()).collect::<Vec<_>>(),
                    "passed_test": e.significant,
                },
                "round": c.round,
                "in_vehicle": e.kind.in_vehicle(),
                "reading": c.selected.then(|| reading(a, c.evidence.kind, &c.values)),
                "interval": c.interval.as_ref().map(|iv| interval_json(e.kind, iv)),
                "not_detected_range": c.could_be.as_ref().map(|nd| {
                    let names = e.kind.param_names();
                    nd.ranges
                        .iter()
                        .map(|(p, b)| (names[*p].to_string(), json!([r5(b[0]), r5(b[1])])))
                        .collect::<serde_json::Map<_, _>>()
                }),
                // a multi-parameter effect: where the parameters not scanned were held
                "not_detected_with": c.could_be.as_ref()
                    .filter(|_| e.kind.n_params() > 1)
                    .map(|nd| e.kind.params_json(&nd.held)),
            })
        })
        .collect();
    json!({
        "effects": effects,
        "fit": {
            "rmse_before": channels(&a.rmse_before),
            "rmse_after": channels(&a.rmse_after),
            "rmse_fitted_in_sample": channels(&a.rmse_fitted_in_sample),
            "noise_floor": channels(&a.noise_floor),
            "heldout": format!("{}-fold cross-validation over {}; replay windows of {} s re-anchored to the recorded state", a.folds, if a.heldout_runs { "whole runs" } else { "contiguous time blocks" }, a.window_s),
        },
        "mismatch": a.located.mismatch.iter().map(|g| {
            let mut j = g.to_json();
            if g.kind == "time" {
                let (run, t) = rec.run_at(g.range[0]);
                j["run"] = json!(run);
                j["run_t0"] = json!((t * 1e3).round() / 1e3);
            }
            if let Some(k) = explained_by(a, g) {
                j["explained_by"] = json!(k);
            }
            j
        }).collect::<Vec<_>>(),
        "recording": {
            "duration_s": rec.total_duration(),
            "samples": rec.states.len(),
            "commands": rec.commands.len(),
            "warnings": rec.warnings,
            "runs": rec.runs().iter().map(|r| {
                let s = &rec.states[r.first_state];
                json!({
                    "name": r.name,
                    "duration_s": ((r.end - r.start) * 1e3).round() / 1e3,
                    "samples": r.n_states,
                    "t_offset": r.t_offset,
                    "start": if s.vx.abs() > 0.3 { "moving" } else { "rest" },
                })
            }).collect::<Vec<_>>(),
            "channels_missing": missing_names(rec),
        },
        "ambiguities": a.ambiguities,
        "not_identifiable": a.not_identifiable.iter().map(|(k, why)| json!({"effect": k.name(), "why": why})).collect::<Vec<_>>(),
        "above_noise_floor": above_noise(a),
        "analysis_seconds": (a.seconds * 100.0).round() / 100.0,
    })
}

fn reading(a: &Analysis, kind: EffectKind, v: &[f64]) -> String {
    crate::explain::reading(kind, v, a.nominal.mu)
}

fn r5(x: f64) -> f64 {
    (x * 1e5).round() / 1e5
}

/// `{param: [lo, hi]}` (a friction patch: its mu only).
fn interval_json(kind: EffectKind, iv: &[[f64; 2]]) -> Value {
    let m: serde_json::Map<String, Value> = kind
        .param_names()
        .iter()
        .zip(iv)
        .take(if kind == EffectKind::FrictionPatch {
            1
        } else {
            iv.len()
        })
        .map(|(n, b)| ((*n).to_string(), json!([r5(b[0]), r5(b[1])])))
        .collect();
    Value::Object(m)
}

fn missing_names(rec: &Recording) -> Vec<&'static str> {
    let m = rec.missing_channels();
    CHANNELS
        .iter()
        .zip(m)
        .filter(|(_, m)| *m)
        .map(|(c, _)| *c)
        .collect()
}

/// Channels where the fitted model's held-out error stays above 1.5 x the noise floor.
fn above_noise(a: &Analysis) -> Vec<&'static str> {
    CHANNELS
        .iter()
        .enumerate()
        .filter(|(c, _)| a.rmse_after[*c].is_finite() && a.rmse_after[*c] > 1.5 * a.noise_floor[*c])
        .map(|(_, n)| *n)
        .collect()
}

/// The kept effect that explains a mismatch location: the first kept effect of the kinds
/// that act there, when the fitted model's residual there fell by 30 % or more.
fn explained_by(a: &Analysis, g: &Group) -> Option<String> {
    let fitted = a
        .located_fitted
        .time
        .iter()
        .chain(&a.located_fitted.regimes)
        .chain(&a.located_fitted.cells)
        .find(|f| f.kind == g.kind && f.label == g.label && f.range == g.range)?;
    if fitted.score > 0.7 * g.score {
        return None;
    }
    use EffectKind::*;
    let acting: &[EffectKind] = match (g.kind, g.label.as_str()) {
        ("region", _) => &[FrictionPatch, Friction, TireSaturation],
        (_, "lateral_accel_mps2") => &[TireSaturation, Friction, FrictionPatch, SteeringGain],
        (_, "steering_rate_radps") => &[
            SteeringDelay,
            SteeringLag,
            SteeringBacklash,
            MeasurementDelay,
            SteeringGain,
        ],
        (_, "speed_mps") => &[Drag, SpeedGain, DriveLag, Friction, SteeringGain],
        (_, "braking") => &[DriveLag, SpeedGain, Drag],
        _ => &[],
    };
    let kept: Vec<EffectKind> = a
        .candidates
        .iter()
        .filter(|c| c.selected)
        .map(|c| c.evidence.kind)
        .collect();
    acting
        .iter()
        .find(|k| kept.contains(k))
        .map(|k| k.name().to_string())
        .or_else(|| {
            (!kept.is_empty()).then(|| {
                let names: Vec<&str> = kept.iter().map(|k| k.name()).collect();
                format!("the fitted model as a whole ({})", names.join(" + "))
            })
        })
}

fn fmt_range(kind: EffectKind, iv: &[[f64; 2]]) -> String {
    kind.param_names()
        .iter()
        .zip(iv)
        .take(if kind == EffectKind::FrictionPatch {
            1
        } else {
            iv.len()
        })
        .map(|(n, b)| format!("{n} {:.4} to {:.4}", b[0], b[1]))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The report in plain words: what was found, how sure, what to change on the car, what
/// to drive next, where the model and the car part.
pub fn to_markdown(a: &Analysis, rec: &Recording) -> String {
    to_markdown_with(a, rec, None)
}

/// [`to_markdown`] with the VESC corrections (`report.json`'s `vesc`) when known.
pub fn to_markdown_with(a: &Analysis, rec: &Recording, vesc: Option<&Value>) -> String {
    let mut s = String::new();
    let kept: Vec<&crate::analysis::CandidateResult> =
        a.candidates.iter().filter(|c| c.selected).collect();
    let _ = writeln!(s, "# Reality-gap report\n");
    let _ = writeln!(s, "## In short\n");
    if kept.is_empty() {
        let _ = writeln!(
            s,
            "Nothing significant. No candidate effect improved the held-out data by more than \
             its parameters buy, so the nominal model explains this recording as well as any \
             candidate does; what remains looks like measurement noise and random disturbance.\n"
        );
    } else {
        let _ = writeln!(
            s,
            "The simulator misses {} effect{} (each lowered the error on held-out data by more \
             than its parameters buy, in separate {}, and made none worse beyond noise):\n",
            kept.len(),
            if kept.len() == 1 { "" } else { "s" },
            if a.heldout_runs {
                "groups of runs"
            } else {
                "time blocks"
            }
        );
        for c in &kept {
            let k = c.evidence.kind;
            let _ = writeln!(
                s,
                "- **{}**: {}. Fitted {}{}; held-out error {:.1} % lower.",
                k.name(),
                reading(a, k, &c.values),
                k.params_json(&c.values),
                c.interval
                    .as_ref()
                    .map(|iv| format!(" (likely range: {})", fmt_range(k, iv)))
                    .unwrap_or_default(),
                100.0 * c.evidence.gain
            );
        }
        let _ = writeln!(s);
    }
    for amb in &a.ambiguities {
        let _ = writeln!(s, "Ambiguous: {amb}.\n");
    }
    let above = above_noise(a);
    if !above.is_empty() {
        let _ = writeln!(
            s,
            "Note: the fitted model stays above the estimated noise floor in {} (more than 1.5 \
             times the noise): something the candidates do not cover remains, or the car was \
             pushed about by disturbances.\n",
            above.join(", ")
        );
    }

    let _ = writeln!(s, "## The data\n");
    let runs = rec.runs();
    let moving = runs
        .iter()
        .filter(|r| rec.states[r.first_state].vx.abs() > 0.3)
        .count();
    let _ = writeln!(
        s,
        "{} run{}, {:.1} s in all ({} starting in motion), {} state samples, {} commands. The \
         recorded commands were replayed through the simulator in {} s windows, each started \
         from the recorded state.",
        runs.len(),
        if runs.len() == 1 { "" } else { "s" },
        rec.total_duration(),
        moving,
        rec.states.len(),
        rec.commands.len(),
        a.window_s
    );
    let missing = missing_names(rec);
    if !missing.is_empty() {
        let _ = writeln!(
            s,
            "Not measured: {}; the fit uses the channels present, and the replay carries \
             the unmeasured velocities on from the model (derived from the pose where a run starts).",
            missing.join(", ")
        );
    }
    let _ = writeln!(s);
    for w in &rec.warnings {
        let _ = writeln!(s, "Warning: {w}\n");
    }

    let _ = writeln!(s, "## What to change on the car\n");
    if kept.is_empty() {
        let _ = writeln!(s, "Nothing: the nominal vehicle stands.\n");
    } else {
        let _ = writeln!(
            s,
            "`vehicle.yaml` is the nominal vehicle with the effects above; the simulator loads \
             it as it is."
        );
        for c in &kept {
            match c.evidence.kind {
                EffectKind::MeasurementDelay => {
                    let _ = writeln!(
                        s,
                        "- The pose arrives {:.0} ms late: give the localiser's latency to the policy (or compensate it); it is not in `vehicle.yaml`.",
                        1e3 * c.values[0]
                    );
                }
                EffectKind::SteeringBacklash => {
                    let _ = writeln!(
                        s,
                        "- The steering linkage has play: tighten it, or keep `steering_backlash` in the simulator."
                    );
                }
                _ => {}
            }
        }
        match vesc {
            Some(v) if v.as_object().is_some_and(|m| !m.is_empty()) => {
                let _ = writeln!(
                    s,
                    "\nIn the VESC driver's `vesc.yaml`:\n\n| key | now | set to |\n|---|---|---|"
                );
                if let Some(m) = v.as_object() {
                    for (k, x) in m {
                        let _ = writeln!(s, "| {k} | {} | {} |", x["old"], x["new"]);
                    }
                }
            }
            Some(_) => {
                let _ = writeln!(
                    s,
                    "\nThe VESC calibration (`vesc.yaml`) needs no change for these effects."
                );
            }
            None => {}
        }
        let _ = writeln!(s);
    }

    let _ = writeln!(s, "## How sure\n");
    let _ = writeln!(
        s,
        "Error on held-out data ({}-fold over {}, each predicted by a model fitted without it), \
         nominal vs fitted, and the measurement noise estimated from the recording itself:\n",
        a.folds,
        if a.heldout_runs {
            "whole runs"
        } else {
            "contiguous time blocks"
        }
    );
    let _ = writeln!(s, "| channel | nominal | fitted | noise |");
    let _ = writeln!(s, "|---|---|---|---|");
    for (c, name) in CHANNELS.iter().enumerate() {
        if a.rmse_before[c].is_finite() {
            let _ = writeln!(
                s,
                "| {} | {:.4} | {:.4} | {:.4} |",
                name, a.rmse_before[c], a.rmse_after[c], a.noise_floor[c]
            );
        } else {
            let _ = writeln!(s, "| {name} | not measured | | |");
        }
    }
    let _ = writeln!(s, "\nTested and not kept:\n");
    for c in a.candidates.iter().filter(|c| !c.selected) {
        let e = &c.evidence;
        let range = c
            .could_be
            .as_ref()
            .map(|nd| {
                format!(
                    "not detected; {}. ",
                    not_detected_words(e.kind, nd, a.nominal.mu)
                )
            })
            .unwrap_or_else(|| "not detected. ".into());
        let _ = writeln!(
            s,
            "- {}: {}Best fit {} changed the held-out error by {:+.1} % (needs below -{:.1} %, better in 2 of {} {} and worse beyond noise in none; this one: better in {}, worse in {}).",
            e.kind.name(),
            range,
            e.kind.params_json(&c.evidence.values),
            -100.0 * e.gain,
            100.0 * e.margin,
            e.heldout_base.len(),
            if a.heldout_runs { "groups" } else { "blocks" },
            e.folds_improved,
            e.folds_worse
        );
    }

    let _ = writeln!(s, "\n## What to drive next\n");
    if a.not_identifiable.is_empty() {
        let _ = writeln!(s, "These data exercise every candidate effect.");
    } else {
        let _ = writeln!(
            s,
            "These data cannot identify some effects (a \"not detected\" above means little for them):\n"
        );
        for (k, why) in &a.not_identifiable {
            let _ = writeln!(s, "- {}: {why}.", k.name());
        }
    }

    let _ = writeln!(s, "\n## Where the nominal model and the recording part\n");
    if a.located.mismatch.is_empty() {
        let _ = writeln!(
            s,
            "The residual is spread evenly: no time segment, regime or place stands out.\n"
        );
    } else {
        let _ = writeln!(
            s,
            "Ratio = mean residual there over the mean residual of the whole recording.\n"
        );
        for g in &a.located.mismatch {
            let what = match g.kind {
                "time" => {
                    let (run, t) = rec.run_at(g.range[0]);
                    if runs.len() > 1 {
                        format!("in {run} from {:.1} s", t)
                    } else {
                        format!("from {:.1} s to {:.1} s", g.range[0], g.range[1])
                    }
                }
                "regime" => format!("{} in [{}, {})", g.label, g.range[0], g.range[1]),
                _ => format!(
                    "the box x [{:.1}, {:.1}] m, y [{:.1}, {:.1}] m",
                    g.range[0], g.range[2], g.range[1], g.range[3]
                ),
            };
            let why = match explained_by(a, g) {
                Some(k) => format!("; explained by {k}"),
                None if kept.is_empty() => String::new(),
                None => "; not explained by the fitted model".into(),
            };
            let _ = writeln!(
                s,
                "- {} {}: ratio {:.2}, {:.0} % of the total residual ({} samples){why}",
                g.kind,
                what,
                g.ratio,
                100.0 * g.share,
                g.samples
            );
        }
    }
    let _ = writeln!(s, "\nAnalysis took {:.1} s.", a.seconds);
    s
}

/// Write `report.json`, `report.md` and `vehicle.yaml` into `dir`.
pub fn write(dir: &Path, a: &Analysis, rec: &Recording) -> Result<(), SysidError> {
    write_with(dir, a, rec, None)
}

/// [`write`], with the VESC driver's parameters (`vesc.yaml`) to correct.
pub fn write_with(
    dir: &Path,
    a: &Analysis,
    rec: &Recording,
    vesc_params: Option<&[(String, f64)]>,
) -> Result<(), SysidError> {
    let io = |p: &Path, e: std::io::Error| SysidError::Io {
        path: p.display().to_string(),
        source: e,
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let json_path = dir.join("report.json");
    let vesc = vesc_params.map(|p| {
        let get = |k: EffectKind| {
            a.candidates
                .iter()
                .find(|c| c.selected && c.evidence.kind == k)
                .map(|c| c.values[0])
        };
        crate::explain::vesc_corrections(
            p,
            get(EffectKind::SteeringGain),
            get(EffectKind::SteeringOffset),
            get(EffectKind::SpeedGain),
        )
    });
    let mut report = to_json(a, rec);
    if let Some(v) = &vesc {
        report["vesc"] = v.clone();
    }
    let text = serde_json::to_string_pretty(&report).unwrap_or_default();
    std::fs::write(&json_path, text).map_err(|e| io(&json_path, e))?;
    let md = dir.join("report.md");
    std::fs::write(&md, to_markdown_with(a, rec, vesc.as_ref())).map_err(|e| io(&md, e))?;
    let y = dir.join("vehicle.yaml");
    let yaml = format!(
        "# Fitted by `paddock sysid`: the nominal vehicle plus the effects the recording supports.\n{}",
        a.fitted.to_yaml_string()
    );
    std::fs::write(&y, yaml).map_err(|e| io(&y, e))?;
    Ok(())
}

/// "c_lin could be anywhere in [0, 0.2] (c_quad 0 held); ... without these data
/// telling" for an effect not kept.
fn not_detected_words(
    kind: EffectKind,
    nd: &crate::uncertainty::NotDetected,
    nominal_mu: f64,
) -> String {
    let names = kind.param_names();
    let parts: Vec<String> = nd
        .ranges
        .iter()
        .map(|(p, [lo, hi])| {
            let with = match kind {
                EffectKind::Drag | EffectKind::TireSaturation => {
                    let others: Vec<String> = (0..names.len())
                        .filter(|q| q != p)
                        .map(|q| format!("{} {}", names[q], nd.held[q]))
                        .collect();
                    format!(" ({} held)", others.join(", "))
                }
                EffectKind::FrictionPatch => format!(
                    " inside x [{:.1}, {:.1}] m, y [{:.1}, {:.1}] m (where the residual pointed)",
                    nd.held[1], nd.held[3], nd.held[2], nd.held[4]
                ),
                _ => String::new(),
            };
            format!(
                "{} could be anywhere in [{lo:.4}, {hi:.4}]{with}",
                names[*p]
            )
        })
        .collect();
    let mut out = parts.join("; ");
    out.push_str(", without these data telling");
    if let (EffectKind::TireSaturation, Some((_, [lo, _]))) = (kind, nd.ranges.first()) {
        let _ = write!(
            out,
            " (the tyres' grip could peak as low as {:.1} m/s^2 of lateral acceleration)",
            lo * nominal_mu * 9.81
        );
    }
    out
}
