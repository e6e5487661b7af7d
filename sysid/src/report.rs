//! `report.json`, `report.md` and `vehicle.yaml` of an analysis.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::{Value, json};

use crate::SysidError;
use crate::analysis::Analysis;
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
            "heldout": format!("{}-fold cross-validation over contiguous time blocks; replay windows of {} s re-anchored to the recorded state", a.folds, a.window_s),
        },
        "mismatch": a.located.mismatch.iter().map(|g| g.to_json()).collect::<Vec<_>>(),
        "recording": {
            "duration_s": rec.duration(),
            "samples": rec.states.len(),
            "commands": rec.commands.len(),
            "warnings": rec.warnings,
        },
        "analysis_seconds": (a.seconds * 100.0).round() / 100.0,
    })
}

/// The report in plain words.
pub fn to_markdown(a: &Analysis, rec: &Recording) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Reality-gap report\n");
    let _ = writeln!(
        s,
        "Recording: {:.1} s, {} state samples, {} commands. The recorded commands were replayed \
         through the simulator in {} s windows, each started from the recorded state, and the \
         simulated states compared with the recorded ones.\n",
        rec.duration(),
        rec.states.len(),
        rec.commands.len(),
        a.window_s
    );
    for w in &rec.warnings {
        let _ = writeln!(s, "Warning: {w}\n");
    }
    let _ = writeln!(s, "## What is missing from the simulator\n");
    if a.effects.is_empty() {
        let _ = writeln!(
            s,
            "Nothing significant. No candidate effect improved the held-out data by more than \
             its parameters buy, so the nominal model explains this recording as well as any \
             candidate does; what remains looks like measurement noise and random disturbance.\n"
        );
    } else {
        let _ = writeln!(
            s,
            "The data support these effects (each improved the held-out residual by more than \
             its parameters buy, in separate time blocks, and made no block worse):\n"
        );
        for c in a.candidates.iter().filter(|c| c.selected) {
            let _ = writeln!(
                s,
                "- **{}** {}: held-out residual {:.1} % lower when it was added.",
                c.evidence.kind.name(),
                c.evidence.kind.params_json(&c.values),
                100.0 * c.evidence.gain
            );
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "Candidates that were tested and not kept:\n");
    for c in a.candidates.iter().filter(|c| !c.selected) {
        let e = &c.evidence;
        let _ = writeln!(
            s,
            "- {}: best fit {} changed the held-out residual by {:+.1} % (a kept effect must lower it by more than {:.1} %, in at least 2 of {} blocks and raise it in none; this one lowered it in {}, raised it in {}).",
            e.kind.name(),
            e.kind.params_json(&c.values),
            -100.0 * e.gain,
            100.0 * e.margin,
            e.heldout_base.len(),
            e.folds_improved,
            e.folds_worse
        );
    }
    let _ = writeln!(s, "\n## How much better the fitted model is\n");
    let _ = writeln!(
        s,
        "Root-mean-square error on held-out data ({}-fold over time blocks), nominal model vs fitted model, \
         with the measurement noise estimated from the recording:\n",
        a.folds
    );
    let _ = writeln!(s, "| channel | nominal | fitted | noise |");
    let _ = writeln!(s, "|---|---|---|---|");
    for (c, name) in CHANNELS.iter().enumerate() {
        let _ = writeln!(
            s,
            "| {} | {:.4} | {:.4} | {:.4} |",
            name, a.rmse_before[c], a.rmse_after[c], a.noise_floor[c]
        );
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
                "time" => format!("from {:.1} s to {:.1} s", g.range[0], g.range[1]),
                "regime" => format!("{} in [{}, {})", g.label, g.range[0], g.range[1]),
                _ => format!(
                    "the box x [{:.1}, {:.1}] m, y [{:.1}, {:.1}] m",
                    g.range[0], g.range[2], g.range[1], g.range[3]
                ),
            };
            let _ = writeln!(
                s,
                "- {} {}: ratio {:.2}, {:.0} % of the total residual ({} samples)",
                g.kind,
                what,
                g.ratio,
                100.0 * g.share,
                g.samples
            );
        }
    }
    let _ = writeln!(
        s,
        "\n`vehicle.yaml` holds the fitted model; the simulator loads it as it is.\n\nAnalysis took {:.1} s.",
        a.seconds
    );
    s
}

/// Write `report.json`, `report.md` and `vehicle.yaml` into `dir`.
pub fn write(dir: &Path, a: &Analysis, rec: &Recording) -> Result<(), SysidError> {
    let io = |p: &Path, e: std::io::Error| SysidError::Io {
        path: p.display().to_string(),
        source: e,
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let json_path = dir.join("report.json");
    let text = serde_json::to_string_pretty(&to_json(a, rec)).unwrap_or_default();
    std::fs::write(&json_path, text).map_err(|e| io(&json_path, e))?;
    let md = dir.join("report.md");
    std::fs::write(&md, to_markdown(a, rec)).map_err(|e| io(&md, e))?;
    let y = dir.join("vehicle.yaml");
    let yaml = format!(
        "# Fitted by `paddock sysid`: the nominal vehicle plus the effects the recording supports.\n{}",
        a.fitted.to_yaml_string()
    );
    std::fs::write(&y, yaml).map_err(|e| io(&y, e))?;
    Ok(())
}
