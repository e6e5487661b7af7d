//! The F1TENTH racetracks CSV formats: centerline and raceline files.

use std::path::Path;

use super::{CenterPoint, RacelinePoint, TrackError};

fn read(path: &Path) -> Result<String, TrackError> {
    std::fs::read_to_string(path).map_err(|source| TrackError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Parse an F1TENTH centerline CSV file (see [`parse_centerline_text`]).
pub fn parse_centerline(path: &Path) -> Result<Vec<CenterPoint>, TrackError> {
    parse_centerline_text(path, &read(path)?)
}

/// Parse the text of an F1TENTH centerline CSV: `x, y, w_right, w_left` per line, `#`
/// comments. `path` names the file in errors.
pub fn parse_centerline_text(path: &Path, text: &str) -> Result<Vec<CenterPoint>, TrackError> {
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v = parse_fields(path, ln + 1, line, ',', 4)?;
        out.push(CenterPoint {
            x: v[0],
            y: v[1],
            w_right: v[2],
            w_left: v[3],
        });
    }
    Ok(out)
}

/// Parse a raceline CSV file (see [`parse_raceline_text`]).
pub fn parse_raceline(path: &Path) -> Result<Vec<RacelinePoint>, TrackError> {
    parse_raceline_text(path, &read(path)?)
}

/// Parse the text of a raceline CSV in the TUM format: `s; x; y; psi; kappa; vx; ax` per
/// line, `#` comments. `path` names the file in errors.
pub fn parse_raceline_text(path: &Path, text: &str) -> Result<Vec<RacelinePoint>, TrackError> {
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v = parse_fields(path, ln + 1, line, ';', 7)?;
        out.push(RacelinePoint {
            s: v[0],
            x: v[1],
            y: v[2],
            psi: v[3],
            kappa: v[4],
            vx: v[5],
            ax: v[6],
        });
    }
    Ok(out)
}

fn parse_fields(
    path: &Path,
    line: usize,
    text: &str,
    sep: char,
    n: usize,
) -> Result<Vec<f64>, TrackError> {
    let fields: Vec<&str> = text.split(sep).map(str::trim).collect();
    if fields.len() < n {
        return Err(TrackError::Parse {
            path: path.to_path_buf(),
            line,
            message: format!(
                "expected {n} fields separated by {sep:?}, found {}: {text:?}",
                fields.len()
            ),
        });
    }
    fields[..n]
        .iter()
        .enumerate()
        .map(|(col, f)| match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(TrackError::Parse {
                path: path.to_path_buf(),
                line,
                message: format!("column {} is not a finite number: {f:?}", col + 1),
            }),
        })
        .collect()
}
