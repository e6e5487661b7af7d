//! `PADDOCK_SCAN_PATH`: the LIDAR code path of the env sessions' worlds in a process (the
//! `paddock` command's workers and `paddock perf`, the in-process library of a learner).
//!
//! Every path gives the same bits; a narrower one is slower. The setting serves to
//! measure on one CPU what CPUs without AVX-512 (or without AVX) run (`avx` on an
//! AVX-512 machine times what an AVX2-only cloud host gets), and to keep a process off a
//! path. Unset or empty: the widest path this CPU supports. The simulator itself reads
//! no environment: the programs read this one and set it on their worlds.

use paddock_sim::lidar::{ScanPath, ScanPathError, cpu_features};

/// The variable's name.
pub const SCAN_PATH_VAR: &str = "PADDOCK_SCAN_PATH";

/// [`SCAN_PATH_VAR`] names no path, or one this CPU cannot run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ScanPathVarError {
    #[error("{SCAN_PATH_VAR}={value:?} is not one of portable, avx, avx512")]
    Unknown { value: String },
    #[error("{SCAN_PATH_VAR}={}: {unsupported}", unsupported.path)]
    Unsupported { unsupported: ScanPathError },
}

/// The path [`SCAN_PATH_VAR`] names in this process's environment: `None` where it is
/// unset or empty.
pub fn scan_path_from_env() -> Result<Option<ScanPath>, ScanPathVarError> {
    match std::env::var_os(SCAN_PATH_VAR) {
        None => Ok(None),
        Some(v) => scan_path_from_var(&v.to_string_lossy()),
    }
}

/// [`scan_path_from_env`] for the value `value` (blanks around the name are ignored).
pub fn scan_path_from_var(value: &str) -> Result<Option<ScanPath>, ScanPathVarError> {
    let name = value.trim();
    if name.is_empty() {
        return Ok(None);
    }
    let Some(path) = ScanPath::from_name(name) else {
        return Err(ScanPathVarError::Unknown {
            value: value.to_string(),
        });
    };
    if !path.supported() {
        return Err(ScanPathVarError::Unsupported {
            unsupported: ScanPathError {
                path,
                features: cpu_features(),
            },
        });
    }
    Ok(Some(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_this_cpu_runs_is_taken_and_anything_else_refused_naming_the_variable() {
        for blank in ["", "  "] {
            assert_eq!(scan_path_from_var(blank), Ok(None));
        }
        for path in ScanPath::ALL {
            let got = scan_path_from_var(&format!(" {} ", path.name()));
            if path.supported() {
                assert_eq!(got, Ok(Some(path)));
            } else {
                let text = got.expect_err(path.name()).to_string();
                assert!(
                    text.starts_with(&format!("PADDOCK_SCAN_PATH={path}: ")),
                    "{text}"
                );
                assert!(text.contains(&cpu_features()), "{text}");
            }
        }
        assert_eq!(scan_path_from_var("portable"), Ok(Some(ScanPath::Portable)));
        for bad in ["AVX", "sse2", "avx-512", "widest"] {
            let e = scan_path_from_var(bad).expect_err(bad);
            assert_eq!(
                e.to_string(),
                format!("PADDOCK_SCAN_PATH=\"{bad}\" is not one of portable, avx, avx512")
            );
        }
    }
}
