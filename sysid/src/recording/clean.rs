//! Real logs' shape: time offsets (epoch seconds), duplicated or stray rows, gaps, and
//! logs that hold several runs. A log becomes a list of runs, each on its own time axis
//! from 0, with every skipped row reported, never a crash or an allocation sized by a
//! wrong timestamp.

use super::{Command, Recording, RunInfo, StateSample};

/// A gap longer than this between two state samples splits the log into runs [s].
pub const MAX_GAP_S: f64 = 1.0;
/// A piece of log between splits with fewer samples than this is stray (dropped).
pub const STRAY_SAMPLES: usize = 5;
/// Longest run accepted [s]: a guard against time in the wrong unit (ms, ns).
pub const MAX_RUN_S: f64 = 4.0 * 3600.0;
/// Gaps inside a run longer than this are reported [s].
const REPORTED_GAP_S: f64 = 0.25;

/// Indices of the samples of each run, in time order, and what was dropped.
///
/// `times` are in file order. A single sample out of order with both neighbours in order
/// is stray; a sample repeating the previous time is a duplicate; the rest is cut into
/// pieces at every backward step or gap over [`MAX_GAP_S`], pieces of fewer than
/// [`STRAY_SAMPLES`] are stray, and neighbouring pieces that follow on in time are joined.
pub fn split(times: &[f64], warnings: &mut Vec<String>) -> Vec<Vec<usize>> {
    let n = times.len();
    let mut keep: Vec<usize> = Vec::with_capacity(n);
    let mut duplicates = 0usize;
    let mut stray: Vec<f64> = Vec::new();
    for i in 0..n {
        let t = times[i];
        if let Some(&p) = keep.last() {
            let tp = times[p];
            if t == tp {
                duplicates += 1;
                continue;
            }
            if let Some(&tn) = times.get(i + 1) {
                let neighbours_in_order = tn > tp && tn - tp <= MAX_GAP_S;
                if neighbours_in_order && !(t > tp && t <= tn) {
                    stray.push(t);
                    continue;
                }
            }
        }
        keep.push(i);
    }
    // pieces at backward steps and long gaps
    let mut pieces: Vec<Vec<usize>> = Vec::new();
    for &i in &keep {
        let new_piece = match pieces.last().and_then(|p| p.last()) {
            Some(&p) => times[i] <= times[p] || times[i] - times[p] > MAX_GAP_S,
            None => true,
        };
        if new_piece {
            pieces.push(Vec::new());
        }
        if let Some(p) = pieces.last_mut() {
            p.push(i);
        }
    }
    // a log made only of small pieces keeps its biggest (the caller judges its length)
    let floor = STRAY_SAMPLES.min(pieces.iter().map(Vec::len).max().unwrap_or(0));
    let mut runs: Vec<Vec<usize>> = Vec::new();
    for piece in pieces {
        if piece.len() < floor {
            stray.extend(piece.iter().map(|&i| times[i]));
            continue;
        }
        if let Some(last) = runs.last_mut() {
            let (end, start) = (times[*last.last().unwrap_or(&0)], times[piece[0]]);
            if start > end && start - end <= MAX_GAP_S {
                last.extend(piece);
                continue;
            }
        }
        runs.push(piece);
    }
    if duplicates > 0 {
        warnings.push(format!(
            "{duplicates} samples repeating the previous timestamp skipped"
        ));
    }
    if !stray.is_empty() {
        let shown: Vec<String> = stray.iter().take(3).map(|t| format!("{t}")).collect();
        warnings.push(format!(
            "{} stray samples out of time order skipped (t = {}{})",
            stray.len(),
            shown.join(", "),
            if stray.len() > 3 { ", ..." } else { "" }
        ));
    }
    runs
}

/// Build the runs of a log from its samples in file order (absolute times). CSV logs pair
/// command `i` with sample `i` (`paired`); bags have their own command times, and each
/// run takes the commands from [`MAX_GAP_S`] before its first sample to its last (those
/// before it count from its start).
pub fn into_runs(
    commands: Vec<Command>,
    states: Vec<StateSample>,
    paired: bool,
    mut warnings: Vec<String>,
    name: &str,
) -> Result<Vec<Recording>, crate::SysidError> {
    let times: Vec<f64> = states.iter().map(|s| s.t).collect();
    let runs = split(&times, &mut warnings);
    let mut sorted_cmds = commands.clone();
    if !paired {
        sorted_cmds.sort_by(|a, b| a.t.total_cmp(&b.t));
    }
    let several = runs.len() > 1;
    let mut out = Vec::with_capacity(runs.len());
    for (k, idx) in runs.iter().enumerate() {
        let t0 = times[idx[0]];
        let t1 = times[idx[idx.len() - 1]];
        if t1 - t0 > MAX_RUN_S {
            return Err(crate::SysidError::Format {
                message: format!(
                    "a run of {:.0} s (t = {t0} to {t1}): longer than {MAX_RUN_S} s; is time in seconds?",
                    t1 - t0
                ),
            });
        }
        let mut rec = Recording::default();
        for &i in idx {
            let mut s = states[i];
            s.t -= t0;
            rec.states.push(s);
            if paired {
                let mut c = commands[i];
                c.t -= t0;
                rec.commands.push(c);
            }
        }
        if !paired {
            for c in &sorted_cmds {
                if c.t >= t0 - MAX_GAP_S && c.t <= t1 {
                    rec.commands.push(Command {
                        t: (c.t - t0).max(0.0),
                        ..*c
                    });
                }
            }
        }
        let mut gaps = 0usize;
        let mut longest: f64 = 0.0;
        for w in rec.states.windows(2) {
            let g = w[1].t - w[0].t;
            if g > REPORTED_GAP_S {
                gaps += 1;
                longest = longest.max(g);
            }
        }
        let run_name = if several {
            format!("{name}#{}", k + 1)
        } else {
            name.to_string()
        };
        if gaps > 0 {
            rec.warnings.push(format!(
                "{run_name}: {gaps} gaps over {REPORTED_GAP_S} s between samples (longest {longest:.2} s)"
            ));
        }
        rec.run_info = vec![RunInfo {
            name: run_name,
            start: 0.0,
            end: rec.duration(),
            first_state: 0,
            n_states: rec.states.len(),
            t_offset: t0,
        }];
        out.push(rec);
    }
    if several {
        warnings.push(format!(
            "{name}: split into {} runs at gaps over {MAX_GAP_S} s or where time goes back",
            runs.len()
        ));
    }
    if let Some(first) = out.first_mut() {
        let mut w = warnings;
        w.append(&mut first.warnings);
        first.warnings = w;
    } else {
        return Err(crate::SysidError::Format {
            message: format!(
                "{name}: no usable samples ({} rows read){}",
                states.len(),
                warnings
                    .first()
                    .map(|w| format!("; {w}"))
                    .unwrap_or_default()
            ),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(n: usize, dt: f64, t0: f64) -> Vec<f64> {
        (0..n).map(|i| t0 + i as f64 * dt).collect()
    }

    #[test]
    fn a_stray_row_far_in_the_future_is_dropped() {
        let mut times = t(100, 0.025, 0.0);
        times.insert(50, 100_000.0);
        let mut w = Vec::new();
        let runs = split(&times, &mut w);
        assert_eq!(runs.len(), 1);
        assert_eq!(runs[0].len(), 100);
        assert!(w[0].contains("stray") && w[0].contains("100000"), "{w:?}");
    }

    #[test]
    fn a_stray_block_and_a_restart_make_runs() {
        let mut times = t(100, 0.025, 1.7e9);
        times.extend([5e9, 5e9 + 0.01, 5e9 + 0.02]);
        times.extend(t(80, 0.025, 1.7e9 + 2.5));
        times.extend(t(60, 0.025, 0.0));
        let mut w = Vec::new();
        let runs = split(&times, &mut w);
        // the stray block goes; the piece after it continues the first run; then a restart
        assert_eq!(runs.len(), 2, "{w:?}");
        assert_eq!(runs[0].len(), 180);
        assert_eq!(runs[1].len(), 60);
        assert!(w.iter().any(|w| w.contains("3 stray")), "{w:?}");
    }

    #[test]
    fn duplicates_and_long_gaps() {
        let mut times = t(50, 0.025, 0.0);
        times.push(times[49]);
        times.extend(t(50, 0.025, 10.0));
        let mut w = Vec::new();
        let runs = split(&times, &mut w);
        assert_eq!(runs.len(), 2);
        assert!(w[0].contains("repeating"), "{w:?}");
    }
}
