//! Locating the reference data (`shared/`: f1tenth_gym vectors, real race tracks) that
//! CI clones beside the repository.

use std::path::{Path, PathBuf};

/// `shared/<sub>`: under `$PADDOCK_SHARED` if set, else under the first `shared/` beside
/// an ancestor of this crate that holds `sub`. A missing folder fails the test, unless
/// `PADDOCK_ALLOW_MISSING_SHARED=1`, which skips it (`None`).
pub fn shared(sub: &str) -> Option<PathBuf> {
    let found = match std::env::var_os("PADDOCK_SHARED") {
        Some(dir) => Some(PathBuf::from(dir).join(sub)).filter(|d| d.is_dir()),
        None => Path::new(env!("CARGO_MANIFEST_DIR"))
            .ancestors()
            .map(|a| a.join("shared").join(sub))
            .find(|d| d.is_dir()),
    };
    if found.is_none() {
        if std::env::var("PADDOCK_ALLOW_MISSING_SHARED").as_deref() == Ok("1") {
            eprintln!("shared/{sub} not found; skipped (PADDOCK_ALLOW_MISSING_SHARED=1)");
            return None;
        }
        panic!(
            "shared/{sub} not found: set PADDOCK_SHARED to the `shared` directory (or clone \
             it beside the repository), or set PADDOCK_ALLOW_MISSING_SHARED=1 to skip"
        );
    }
    found
}
