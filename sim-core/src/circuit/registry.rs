//! [`Circuits`]: the maps a program can name, each loaded once.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::{Circuit, DEFAULT_MAP, list_circuit_dirs, locate};
use crate::shipped::{ShippedMap, shipped_map, shipped_maps};
use crate::track::TrackError;

/// The circuits a program can name: folders of maps it was given, then the maps shipped
/// inside the library. Each circuit is loaded once, on first use, and kept (with its
/// distance field and driving line, built once too) as long as the registry lives, so
/// every episode on a map shares one copy.
///
/// A registry is a value the program creates (the CLI from `PADDOCK_MAPS`) and passes to
/// whatever runs episodes; clones share the loaded circuits. Nothing in the library
/// keeps a registry of its own, reads an environment variable or writes a file.
///
/// A name or path answers the same circuit for the life of the registry: the files are
/// read once, later changes on disk are not seen.
#[derive(Debug, Clone, Default)]
pub struct Circuits {
    inner: Arc<Inner>,
}

#[derive(Debug, Default)]
struct Inner {
    /// Folders of map folders, searched by name in this order before the shipped maps.
    dirs: Vec<PathBuf>,
    /// One slot per circuit loaded or being loaded: the first caller fills it while
    /// later callers for the same circuit wait on its lock (other circuits load in
    /// parallel).
    slots: Mutex<HashMap<Key, Arc<Slot>>>,
    /// What each name or path given to [`Circuits::get`] resolved to.
    names: Mutex<HashMap<String, Arc<Circuit>>>,
}

/// One circuit: empty until its first load succeeds.
type Slot = Mutex<Option<Arc<Circuit>>>;

/// What a circuit was loaded from.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Key {
    Shipped(&'static str),
    /// The canonical path of the map YAML.
    File(PathBuf),
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // a panic while a lock was held leaves plain data behind: keep using it
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Circuits {
    /// The shipped maps only.
    pub fn new() -> Self {
        Self::default()
    }

    /// The maps in `dirs` (each a folder of map folders, searched in order), then the
    /// shipped maps.
    pub fn with_dirs(dirs: impl IntoIterator<Item = PathBuf>) -> Self {
        let mut v: Vec<PathBuf> = Vec::new();
        for d in dirs {
            if !v.contains(&d) {
                v.push(d);
            }
        }
        Self {
            inner: Arc::new(Inner {
                dirs: v,
                ..Inner::default()
            }),
        }
    }

    /// The folders searched by name, in order.
    pub fn dirs(&self) -> &[PathBuf] {
        &self.inner.dirs
    }

    /// How many circuits are loaded.
    pub fn loaded(&self) -> usize {
        lock(&self.inner.slots)
            .values()
            .filter(|s| lock(s).is_some())
            .count()
    }

    /// The circuit a map name or path names: an existing folder or map YAML path is
    /// loaded as is; otherwise `map` is a name, see [`Circuits::by_name`].
    pub fn get(&self, map: &str) -> Result<Arc<Circuit>, TrackError> {
        if let Some(c) = lock(&self.inner.names).get(map) {
            return Ok(c.clone());
        }
        let p = Path::new(map);
        let c = if p.exists() {
            self.load(p)?
        } else {
            self.by_name(map)?
        };
        lock(&self.inner.names).insert(map.to_string(), c.clone());
        Ok(c)
    }

    /// The circuit called `name` (case-insensitive): the first map folder of that name
    /// in the registry's folders, else the shipped map. Never opens `name` as a path, so
    /// a name from a client cannot reach other files of the host.
    pub fn by_name(&self, name: &str) -> Result<Arc<Circuit>, TrackError> {
        for d in &self.inner.dirs {
            for entry in list_circuit_dirs(d) {
                if entry
                    .file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.eq_ignore_ascii_case(name))
                {
                    return self.load(&entry);
                }
            }
        }
        if let Some(m) = shipped_map(name) {
            return self.shipped(m);
        }
        let shipped: Vec<&str> = shipped_maps().iter().map(|m| m.name).collect();
        let mut searched: Vec<String> = self
            .inner
            .dirs
            .iter()
            .map(|d| d.display().to_string())
            .collect();
        searched.push(format!("the shipped maps ({})", shipped.join(", ")));
        Err(TrackError::UnknownMap {
            name: name.to_string(),
            searched: searched.join(", "),
        })
    }

    /// The circuit in folder `path` or whose map YAML is `path`.
    pub fn load(&self, path: &Path) -> Result<Arc<Circuit>, TrackError> {
        let (dir, yaml) = locate(path)?;
        let canon = dir.canonicalize().map_err(|source| TrackError::Io {
            path: dir.clone(),
            source,
        })?;
        let yaml = canon.join(yaml);
        self.once(Key::File(yaml.clone()), || Circuit::load(&yaml))
    }

    /// The circuit of shipped map `m`.
    pub fn shipped(&self, m: &'static ShippedMap) -> Result<Arc<Circuit>, TrackError> {
        self.once(Key::Shipped(m.name), || Circuit::shipped(m))
    }

    /// The default circuit ([`DEFAULT_MAP`], as [`Circuits::by_name`] finds it).
    pub fn default_circuit(&self) -> Result<Arc<Circuit>, TrackError> {
        self.by_name(DEFAULT_MAP)
    }

    /// The circuit under `key`, loaded by `load` if no caller loaded it before. A failed
    /// load is not kept: the next call tries again.
    fn once(
        &self,
        key: Key,
        load: impl FnOnce() -> Result<Circuit, TrackError>,
    ) -> Result<Arc<Circuit>, TrackError> {
        let slot = lock(&self.inner.slots).entry(key).or_default().clone();
        let mut slot = lock(&slot);
        if let Some(c) = &*slot {
            return Ok(c.clone());
        }
        let c = Arc::new(load()?);
        *slot = Some(c.clone());
        Ok(c)
    }
}
