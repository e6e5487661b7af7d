//! Maps by name: the maps the project ships, compiled into the library, and folders of
//! maps a program adds (the CLI adds those of `PADDOCK_MAPS`).
//!
//! Shipped maps are bytes inside the binary (`build.rs` embeds every file of every folder
//! in the project's `maps/`), so a binary finds them wherever it is installed or copied,
//! and never through the source tree it was compiled from. A shipped map is loaded from a
//! folder holding exactly its embedded files, written once per machine under the temporary
//! directory (`paddock-maps-<digest>/<name>/`) and checked byte for byte before every use
//! in a process: its circuit, its map's content hash and its bundle hash are those of the
//! project's `maps/<name>/` folder.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock, RwLock};

use crate::track::TrackError;

/// One shipped map: its folder name and its files (bare names and contents).
#[derive(Debug)]
pub struct ShippedMap {
    pub name: &'static str,
    pub files: &'static [(&'static str, &'static [u8])],
}

include!(concat!(env!("OUT_DIR"), "/shipped_maps.rs"));

/// Every shipped map, sorted by name.
pub fn shipped_maps() -> &'static [ShippedMap] {
    SHIPPED_MAPS
}

/// The shipped map called `name` (case-insensitive).
pub fn shipped_map(name: &str) -> Option<&'static ShippedMap> {
    SHIPPED_MAPS
        .iter()
        .find(|m| m.name.eq_ignore_ascii_case(name))
}

fn added_dirs() -> &'static RwLock<Vec<PathBuf>> {
    static DIRS: OnceLock<RwLock<Vec<PathBuf>>> = OnceLock::new();
    DIRS.get_or_init(|| RwLock::new(Vec::new()))
}

/// Adds folders of maps (one folder per map) that names are looked up in, before the
/// shipped maps, in the order given. Programs call this once at start-up (the CLI with
/// the folders of `PADDOCK_MAPS`); the library reads no environment variables itself.
pub fn add_map_dirs(dirs: impl IntoIterator<Item = PathBuf>) {
    let mut v = added_dirs().write().unwrap_or_else(|e| e.into_inner());
    for d in dirs {
        if !v.contains(&d) {
            v.push(d);
        }
    }
}

/// The folders added by [`add_map_dirs`], in lookup order.
pub fn map_dirs() -> Vec<PathBuf> {
    added_dirs()
        .read()
        .unwrap_or_else(|e| e.into_inner())
        .clone()
}

/// The folder holding exactly the files of shipped map `m` (see the module docs).
pub fn shipped_map_dir(m: &'static ShippedMap) -> Result<PathBuf, TrackError> {
    static WRITTEN: OnceLock<Mutex<HashMap<&'static str, PathBuf>>> = OnceLock::new();
    let written = WRITTEN.get_or_init(|| Mutex::new(HashMap::new()));
    let mut written = written.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(d) = written.get(m.name) {
        return Ok(d.clone());
    }
    let base = std::env::temp_dir().join(format!("paddock-maps-{SHIPPED_DIGEST}"));
    let dir = write_shipped(m, &base)?;
    written.insert(m.name, dir.clone());
    Ok(dir)
}

/// `base/<name>` when it holds exactly `m`'s files, else written there first (through a
/// staging folder renamed into place, so a reader never sees half a map).
fn write_shipped(m: &ShippedMap, base: &Path) -> Result<PathBuf, TrackError> {
    let dir = base.join(m.name);
    if holds_exactly(&dir, m) {
        return Ok(dir);
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| TrackError::Io { path, source }
    };
    if !base.is_dir() {
        std::fs::create_dir_all(base).map_err(io(base))?;
        // every user of the machine may add the maps of their binaries here; each reader
        // checks the files byte for byte, so nobody depends on another user's copy
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let _ = std::fs::set_permissions(base, std::fs::Permissions::from_mode(0o1777));
        }
    }
    static SEQ: AtomicU64 = AtomicU64::new(0);
    let staging = base.join(format!(
        ".tmp-{}-{}-{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed),
        m.name
    ));
    std::fs::create_dir(&staging).map_err(io(&staging))?;
    for (name, data) in m.files {
        let p = staging.join(name);
        std::fs::write(&p, data).map_err(io(&p))?;
    }
    for _ in 0..2 {
        if std::fs::rename(&staging, &dir).is_ok() || holds_exactly(&dir, m) {
            let _ = std::fs::remove_dir_all(&staging);
            return Ok(dir);
        }
        // a stale or foreign folder in the way: replace it once, else keep the staging copy
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(staging)
}

/// Whether `dir` holds exactly `m`'s files (names and bytes) and nothing else.
fn holds_exactly(dir: &Path, m: &ShippedMap) -> bool {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return false;
    };
    let mut names = Vec::new();
    for e in rd {
        let Ok(e) = e else { return false };
        names.push(e.file_name());
    }
    names.len() == m.files.len()
        && m.files
            .iter()
            .all(|(name, data)| std::fs::read(dir.join(name)).is_ok_and(|d| d.as_slice() == *data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tampered_copy_is_rewritten() {
        let m = shipped_map("lakeside").expect("lakeside ships");
        let base =
            std::env::temp_dir().join(format!("paddock-shipped-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let dir = write_shipped(m, &base).unwrap();
        assert_eq!(dir, base.join("lakeside"));
        assert!(holds_exactly(&dir, m));
        // a changed file and an extra file are both noticed and replaced
        std::fs::write(dir.join(m.files[0].0), b"garbage").unwrap();
        assert!(!holds_exactly(&dir, m));
        assert_eq!(write_shipped(m, &base).unwrap(), dir);
        assert!(holds_exactly(&dir, m));
        std::fs::write(dir.join("extra.txt"), b"x").unwrap();
        assert!(!holds_exactly(&dir, m));
        assert_eq!(write_shipped(m, &base).unwrap(), dir);
        assert!(holds_exactly(&dir, m));
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn names_are_case_insensitive() {
        assert!(shipped_maps().len() >= 3);
        assert_eq!(shipped_map("QUARRY").map(|m| m.name), Some("quarry"));
        assert!(shipped_map("no-such-map").is_none());
    }
}
