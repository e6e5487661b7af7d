//! Circuits: an occupancy map and its track, loaded from a map folder or from a map
//! shipped inside the library, and [`Circuits`], the registry a program creates to find
//! circuits by name and load each one once.
//!
//! A circuit is a value. Nothing in this crate keeps circuits or maps behind the
//! caller's back: the program decides how long they live by holding them, or the
//! registry that hands them out.
//!
//! The layout is that of the F1TENTH racetracks collection: `<name>_map.yaml` (ROS
//! map_server), the image it names, `<name>_centerline.csv` and an optional
//! `<name>_raceline.csv`.

mod registry;

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

pub use registry::Circuits;

use crate::map::{Map, OccupancyRule};
use crate::shipped::ShippedMap;
use crate::track::{RacelinePoint, Track, TrackError, parse_centerline_text, parse_raceline_text};

/// The map used whenever no map is named.
pub const DEFAULT_MAP: &str = "lakeside";

/// A raceline whose points keep at least this clearance (m) from every wall is driven as
/// it is; otherwise [`Circuit::driving_line`] computes one inside the map's free space.
pub const DRIVING_LINE_CLEARANCE: f64 = 0.25;
/// Wall margin (m) of a computed driving line: half the car's width plus room to track.
pub const DRIVING_LINE_MARGIN: f64 = 0.4;

/// Where a circuit's files came from.
#[derive(Debug, Clone)]
pub enum CircuitSource {
    /// A map folder on disk (canonical path).
    Dir(PathBuf),
    /// A map shipped inside the library, loaded from its embedded bytes.
    Shipped(&'static ShippedMap),
    /// Built by the program from a map and a track it made (no files).
    Memory,
}

/// A circuit: an occupancy map and its track.
#[derive(Debug)]
pub struct Circuit {
    pub name: String,
    pub source: CircuitSource,
    pub map: Arc<Map>,
    pub track: Arc<Track>,
    /// The line drivers follow, computed on first use (see [`Circuit::driving_line`]).
    driving_line: OnceLock<Vec<RacelinePoint>>,
}

impl Circuit {
    /// A circuit of a map and a track the program built ([`CircuitSource::Memory`]).
    pub fn new(name: &str, map: Arc<Map>, track: Arc<Track>) -> Self {
        Self::with_source(name, CircuitSource::Memory, map, track)
    }

    fn with_source(name: &str, source: CircuitSource, map: Arc<Map>, track: Arc<Track>) -> Self {
        Self {
            name: name.to_string(),
            source,
            map,
            track,
            driving_line: OnceLock::new(),
        }
    }

    /// The folder its files are in, when it was loaded from one.
    pub fn dir(&self) -> Option<&Path> {
        match &self.source {
            CircuitSource::Dir(d) => Some(d),
            CircuitSource::Shipped(_) | CircuitSource::Memory => None,
        }
    }

    /// The racing line drivers follow: the circuit's raceline if it keeps
    /// [`DRIVING_LINE_CLEARANCE`] from the walls everywhere, else (no raceline, or one
    /// that grazes walls, as the racelines of some real tracks do where the map's corridor
    /// is narrower than its centerline file claims) a minimum-curvature line computed
    /// inside the map's free space, [`DRIVING_LINE_MARGIN`] from the walls. Computed once
    /// per circuit, deterministically.
    pub fn driving_line(&self) -> &[RacelinePoint] {
        self.driving_line.get_or_init(|| {
            if let Some(r) = self.track.raceline()
                && r.iter()
                    .all(|p| self.map.clearance(p.x, p.y) >= DRIVING_LINE_CLEARANCE)
            {
                return r.to_vec();
            }
            crate::trackgen::raceline_in_map(
                &self.map,
                &self.track,
                DRIVING_LINE_MARGIN,
                &crate::trackgen::SpeedLimits::default(),
            )
        })
    }

    /// Load the circuit in folder `path`, or the circuit whose map YAML is `path`. Every
    /// call reads the files and builds the circuit again; [`Circuits`] loads each once.
    pub fn load(path: &Path) -> Result<Circuit, TrackError> {
        let (dir, yaml) = locate(path)?;
        let dir = dir.canonicalize().map_err(|source| TrackError::Io {
            path: dir.clone(),
            source,
        })?;
        let read = |name: &str| -> Result<Option<Cow<'static, [u8]>>, TrackError> {
            let p = dir.join(name);
            match std::fs::read(&p) {
                Ok(d) => Ok(Some(Cow::Owned(d))),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                Err(source) => Err(TrackError::Io { path: p, source }),
            }
        };
        let files = Files {
            label: dir.clone(),
            read: &read,
            // a folder's map YAML may name its image by any path (relative to the folder)
            read_image: &|p: &Path| std::fs::read(p).map(Cow::Owned),
        };
        files.circuit(&yaml, CircuitSource::Dir(dir.clone()))
    }

    /// The circuit of shipped map `m`, from the bytes compiled into the library (nothing
    /// is read from or written to the disk).
    pub fn shipped(m: &'static ShippedMap) -> Result<Circuit, TrackError> {
        let label = PathBuf::from(format!("(shipped)/{}", m.name));
        let yaml = m
            .files
            .iter()
            .map(|(n, _)| *n)
            .find(|n| n.ends_with("_map.yaml"))
            .ok_or_else(|| TrackError::Invalid {
                path: label.clone(),
                message: "no *_map.yaml file in this shipped map".into(),
            })?;
        let read = |name: &str| -> Result<Option<Cow<'static, [u8]>>, TrackError> {
            Ok(m.file(name).map(Cow::Borrowed))
        };
        // the image must be a file of the map itself, named by a bare name
        let image_dir = label.clone();
        let read_image = move |p: &Path| -> std::io::Result<Cow<'static, [u8]>> {
            p.strip_prefix(&image_dir)
                .ok()
                .and_then(|rest| rest.to_str())
                .and_then(|name| m.file(name))
                .map(Cow::Borrowed)
                .ok_or_else(|| {
                    std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        "not a file of the shipped map",
                    )
                })
        };
        let files = Files {
            label,
            read: &read,
            read_image: &read_image,
        };
        files.circuit(yaml, CircuitSource::Shipped(m))
    }
}

type ReadFile<'a> = dyn Fn(&str) -> Result<Option<Cow<'static, [u8]>>, TrackError> + 'a;
type ReadImage<'a> = dyn Fn(&Path) -> std::io::Result<Cow<'static, [u8]>> + 'a;

/// The files of one map folder, on disk or in memory: one loading path for both.
struct Files<'a> {
    /// The folder, as errors name it.
    label: PathBuf,
    /// A file of the folder by bare name; None when it is not there.
    read: &'a ReadFile<'a>,
    /// The image a map YAML names (its path as the YAML resolves it).
    read_image: &'a ReadImage<'a>,
}

impl Files<'_> {
    fn text(&self, name: &str) -> Result<Option<String>, TrackError> {
        let Some(bytes) = (self.read)(name)? else {
            return Ok(None);
        };
        String::from_utf8(bytes.into_owned())
            .map(Some)
            .map_err(|_| TrackError::Invalid {
                path: self.label.join(name),
                message: "not UTF-8 text".into(),
            })
    }

    /// The circuit whose map YAML is the file `yaml` of the folder.
    fn circuit(&self, yaml: &str, source: CircuitSource) -> Result<Circuit, TrackError> {
        let stem = yaml
            .strip_suffix("_map.yaml")
            .or_else(|| yaml.strip_suffix(".yaml"))
            .unwrap_or(yaml);
        let yaml_path = self.label.join(yaml);
        let yaml_text = self.text(yaml)?.ok_or_else(|| TrackError::Io {
            path: yaml_path.clone(),
            source: std::io::ErrorKind::NotFound.into(),
        })?;
        let centerline = format!("{stem}_centerline.csv");
        let Some(center_text) = self.text(&centerline)? else {
            return Err(TrackError::Invalid {
                path: self.label.join(centerline),
                message: "missing centerline file (a circuit needs <name>_centerline.csv next to its map YAML)".into(),
            });
        };
        let raceline = format!("{stem}_raceline.csv");
        let race = match self.text(&raceline)? {
            Some(t) => Some(parse_raceline_text(&self.label.join(&raceline), &t)?),
            None => None,
        };
        let center_path = self.label.join(&centerline);
        let points = parse_centerline_text(&center_path, &center_text)?;
        let track = Track::new(points, race).map_err(|message| TrackError::Invalid {
            path: center_path,
            message,
        })?;
        let map = Map::from_yaml(&yaml_path, &yaml_text, OccupancyRule::Ros, self.read_image)?;
        Ok(Circuit::with_source(
            stem,
            source,
            Arc::new(map),
            Arc::new(track),
        ))
    }
}

/// The folder of a circuit path (a folder, or a map YAML in one) and its map YAML's name.
fn locate(path: &Path) -> Result<(PathBuf, String), TrackError> {
    let (dir, yaml) = if path.is_file() {
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        (dir, path.to_path_buf())
    } else {
        (path.to_path_buf(), find_with_suffix(path, "_map.yaml")?)
    };
    let name = yaml
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| TrackError::Invalid {
            path: yaml.clone(),
            message: "not a UTF-8 file name".into(),
        })?
        .to_string();
    Ok((dir, name))
}

/// The circuit directories inside `dir` (those holding a `*_map.yaml`), sorted by name.
pub fn list_circuit_dirs(dir: &Path) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() && find_with_suffix(p, "_map.yaml").is_ok())
        .collect();
    out.sort();
    out
}

fn find_with_suffix(dir: &Path, suffix: &str) -> Result<PathBuf, TrackError> {
    let rd = std::fs::read_dir(dir).map_err(|source| TrackError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut found: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with(suffix))
        })
        .collect();
    found.sort();
    found.into_iter().next().ok_or_else(|| TrackError::Invalid {
        path: dir.to_path_buf(),
        message: format!("no *{suffix} file in this directory"),
    })
}
