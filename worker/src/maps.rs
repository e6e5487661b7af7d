//! Maps kept on disk by content hash.
//!
//! A map arrives as a [`MapBundle`] and is written to `<cache>/<hash>/<name>/`, so a
//! worker that restarts still holds it and a task names it by hash alone. The name is
//! only for people reading the directory: a circuit's name comes from its files, so the
//! same episode gives the same result (its `map` field included) on every worker.
//! Bundles are written to a temporary directory first and renamed into place, so a
//! worker killed mid-write never leaves a half map behind.

use std::path::{Path, PathBuf};

use paddock_proto::{Error, ErrorCode, MapBundle, error};

/// A directory of maps by content hash.
#[derive(Debug, Clone)]
pub struct MapCache {
    root: PathBuf,
}

/// Whether `hash` looks like a content hash (hex SHA-256): anything else is refused
/// before it comes near a path.
pub fn is_hash(hash: &str) -> bool {
    hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit())
}

fn dir_name(name: &str) -> String {
    let last = name
        .rsplit(['/', '\\'])
        .find(|s| !s.is_empty())
        .unwrap_or("");
    let clean: String = last
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if clean.is_empty() {
        "map".into()
    } else {
        clean
    }
}

impl MapCache {
    /// A cache under `root` (created if missing).
    pub fn open(root: impl Into<PathBuf>) -> std::io::Result<Self> {
        let root = root.into();
        std::fs::create_dir_all(&root)?;
        Ok(Self { root })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The directory holding the map with this hash, if the cache has it.
    pub fn get(&self, hash: &str) -> Option<PathBuf> {
        if !is_hash(hash) {
            return None;
        }
        let dir = self.root.join(hash.to_ascii_lowercase());
        std::fs::read_dir(&dir)
            .ok()?
            .filter_map(|e| e.ok())
            .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
            .map(|e| e.path())
            .find(|p| {
                !p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            })
    }

    /// Every hash the cache holds.
    pub fn hashes(&self) -> Vec<String> {
        let mut out: Vec<String> = std::fs::read_dir(&self.root)
            .map(|rd| {
                rd.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| is_hash(n))
                    .filter(|n| self.get(n).is_some())
                    .collect()
            })
            .unwrap_or_default();
        out.sort();
        out
    }

    /// Checks (form and what its files say: the image a bare name of the bundle, its
    /// size capped) and stores a bundle; returns its directory.
    pub fn store(&self, bundle: &MapBundle) -> Result<PathBuf, Error> {
        paddock_wire::check_map_bundle(bundle)?;
        if let Some(dir) = self.get(&bundle.hash) {
            return Ok(dir);
        }
        let hash_dir = self.root.join(bundle.hash.to_ascii_lowercase());
        let io = |e: std::io::Error| {
            error(
                ErrorCode::Internal,
                "map_bundle",
                format!(
                    "storing map {:?} under {}: {e}",
                    bundle.name,
                    hash_dir.display()
                ),
            )
        };
        std::fs::create_dir_all(&hash_dir).map_err(io)?;
        let name = dir_name(&bundle.name);
        let tmp = hash_dir.join(format!(".{name}.tmp-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        paddock_proto::write_map_dir(bundle, &tmp).map_err(io)?;
        let dest = hash_dir.join(&name);
        if let Err(e) = std::fs::rename(&tmp, &dest) {
            let _ = std::fs::remove_dir_all(&tmp);
            // another worker process sharing the cache may have won the race
            if self.get(&bundle.hash).is_none() {
                return Err(io(e));
            }
        }
        self.get(&bundle.hash).ok_or_else(|| {
            error(
                ErrorCode::Internal,
                "map_bundle",
                format!("map {:?} vanished from {}", bundle.name, hash_dir.display()),
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle() -> MapBundle {
        let circuits = paddock_sim::circuit::Circuits::new();
        let lakeside = circuits.get("lakeside").unwrap();
        paddock_wire::circuit_bundle(&lakeside, "../odd name/lakeside").unwrap()
    }

    #[test]
    fn stores_and_finds_by_hash() {
        let tmp = tempfile::tempdir().unwrap();
        let cache = MapCache::open(tmp.path().join("maps")).unwrap();
        let b = bundle();
        assert!(cache.get(&b.hash).is_none());
        assert!(cache.hashes().is_empty());
        let dir = cache.store(&b).unwrap();
        assert_eq!(dir.file_name().unwrap(), "lakeside");
        assert_eq!(cache.get(&b.hash).unwrap(), dir);
        assert_eq!(cache.hashes(), vec![b.hash.clone()]);
        // the stored files load as the same circuit name
        let c = paddock_sim::circuit::Circuit::load(&dir).unwrap();
        assert_eq!(c.name, "lakeside");
        // storing again is a no-op
        assert_eq!(cache.store(&b).unwrap(), dir);
        // a reopened cache still has it
        let again = MapCache::open(tmp.path().join("maps")).unwrap();
        assert_eq!(again.get(&b.hash).unwrap(), dir);
    }

    #[test]
    fn refuses_bad_bundles_and_hashes() {
        let tmp = tempfile::tempdir().unwrap();
        let cache = MapCache::open(tmp.path()).unwrap();
        let mut b = bundle();
        b.files[0].data.push(1);
        let e = cache.store(&b).unwrap_err();
        assert_eq!(e.field, "map_bundle.hash");
        assert!(cache.hashes().is_empty());
        assert!(cache.get("../../etc").is_none());
        assert!(!is_hash(&"g".repeat(64)));
        assert!(is_hash(&"a".repeat(64)));
        assert_eq!(dir_name("/x/y/"), "y");
        assert_eq!(dir_name(".."), "__");
        assert_eq!(dir_name(""), "map");
    }
}
