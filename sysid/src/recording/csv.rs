//! The CSV form of a recording, read leniently: a byte-order mark, any column order,
//! extra columns, optional velocity channels (absent or empty: not measured), and rows
//! that cannot be used (a non-number, NaN, too few fields) skipped with a count.

use super::{CSV_COLUMNS, Command, StateSample};
use crate::SysidError;

/// Columns that must be present: time, the commands and the pose.
pub const REQUIRED: usize = 6;

/// Samples, commands and warnings read from CSV text (absolute times, file order).
pub struct Parsed {
    pub commands: Vec<Command>,
    pub states: Vec<StateSample>,
    pub warnings: Vec<String>,
}

/// Parse CSV text: the header names the columns ([`CSV_COLUMNS`]; `vx`, `vy` and
/// `yaw_rate` may be absent). A row whose time, command or pose is missing or not a finite
/// number is skipped; an empty or non-finite velocity cell means "not measured here".
pub fn parse(text: &str) -> Result<Parsed, SysidError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(SysidError::Format {
            message: "the CSV recording is empty (no header row)".into(),
        });
    };
    let names: Vec<&str> = header
        .split(',')
        .map(|s| s.trim().trim_matches('"'))
        .collect();
    let mut idx: [Option<usize>; 9] = [None; 9];
    for (k, col) in CSV_COLUMNS.iter().enumerate() {
        idx[k] = names.iter().position(|n| n == col);
        if k < REQUIRED && idx[k].is_none() {
            return Err(SysidError::MissingColumn {
                column: (*col).to_string(),
                header: header.trim().to_string(),
            });
        }
    }
    let mut out = Parsed {
        commands: Vec::new(),
        states: Vec::new(),
        warnings: Vec::new(),
    };
    let mut skipped = 0usize;
    let mut examples: Vec<String> = Vec::new();
    let mut rows = 0usize;
    for (line_no, line) in lines {
        rows += 1;
        let row = line_no + 1;
        let fields: Vec<&str> = line.split(',').map(|s| s.trim()).collect();
        let mut v = [f64::NAN; 9];
        let mut problem: Option<String> = None;
        if fields.len() < names.len() {
            problem = Some(format!(
                "row {row} has {} fields, the header has {}",
                fields.len(),
                names.len()
            ));
        } else {
            for (k, col) in CSV_COLUMNS.iter().enumerate() {
                let Some(i) = idx[k] else { continue };
                let s = fields[i];
                let x = if s.is_empty() {
                    f64::NAN
                } else {
                    match s.parse::<f64>() {
                        Ok(x) => x,
                        Err(_) => {
                            problem =
                                Some(format!("row {row}: column {col} = {s:?} is not a number"));
                            break;
                        }
                    }
                };
                if k < REQUIRED && !x.is_finite() {
                    problem = Some(format!(
                        "row {row}: column {col} = {s:?} is not a finite number"
                    ));
                    break;
                }
                v[k] = if x.is_finite() { x } else { f64::NAN };
            }
        }
        if let Some(p) = problem {
            skipped += 1;
            if examples.len() < 3 {
                examples.push(p);
            }
            continue;
        }
        out.commands.push(Command {
            t: v[0],
            steer: v[1],
            speed: v[2],
        });
        out.states.push(StateSample {
            t: v[0],
            x: v[3],
            y: v[4],
            yaw: super::wrap_pi(v[5]),
            vx: v[6],
            vy: v[7],
            yaw_rate: v[8],
        });
    }
    if skipped > 0 {
        let msg = format!(
            "{skipped} of {rows} rows skipped ({}{})",
            examples.join("; "),
            if skipped > examples.len() {
                "; ..."
            } else {
                ""
            }
        );
        if out.states.is_empty() {
            return Err(SysidError::Format {
                message: format!("no usable rows in the CSV recording: {msg}"),
            });
        }
        out.warnings.push(msg);
    }
    let absent: Vec<&str> = (REQUIRED..9)
        .filter(|&k| idx[k].is_none())
        .map(|k| CSV_COLUMNS[k])
        .collect();
    if !absent.is_empty() {
        out.warnings.push(format!(
            "not measured (no column): {}; the fit uses the channels present",
            absent.join(", ")
        ));
    }
    Ok(out)
}
