//! Loading ROS map_server maps (YAML + PNG/PGM), from files or from bytes in memory.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use serde_norway::Value;

use super::Map;
use crate::geometry::Pose;

/// How image pixel values become occupied / free cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum OccupancyRule {
    /// ROS map_server semantics: p = (255 - v) / 255 (v / 255 with `negate`); occupied
    /// if p > occupied_thresh; everything else free ("unknown" counts as free, as the
    /// reference simulator does). `mode: raw` reads v as the occupancy in percent.
    #[default]
    Ros,
    /// The f1tenth_gym reference: pixel value <= 128 is occupied; the YAML thresholds
    /// and `negate` are ignored.
    Reference,
}

/// Why a map could not be built. Every variant names the file (or grid) and the field.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not valid YAML: {message}")]
    Yaml { path: PathBuf, message: String },
    #[error("{path}: missing field `{field}`")]
    MissingField { path: PathBuf, field: &'static str },
    #[error("{path}: field `{field}` = {value}: {reason}")]
    InvalidField {
        path: PathBuf,
        field: &'static str,
        value: String,
        reason: String,
    },
    #[error("map image {path} (from {yaml}): {message}")]
    Image {
        path: PathBuf,
        yaml: PathBuf,
        message: String,
    },
    #[error("map grid `{name}`: {reason}")]
    InvalidGrid { name: String, reason: String },
}

/// The parsed YAML.
struct MapSpec {
    image: PathBuf,
    resolution: f64,
    origin: Pose,
    negate: bool,
    occupied_thresh: f64,
    mode: Mode,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Trinary,
    Scale,
    Raw,
}

impl Map {
    /// Load a ROS map_server map (YAML + image) with [`OccupancyRule::Ros`]. Every call
    /// reads and builds the map again: a program that uses a map many times keeps it (a
    /// [`crate::circuit::Circuits`] registry keeps each circuit's map).
    pub fn load(yaml: &Path) -> Result<Map, MapError> {
        Self::load_with(yaml, OccupancyRule::Ros)
    }

    /// [`Map::load`] with an explicit occupancy rule.
    pub fn load_with(yaml: &Path, rule: OccupancyRule) -> Result<Map, MapError> {
        let text = std::fs::read_to_string(yaml).map_err(|source| MapError::Io {
            path: yaml.to_path_buf(),
            source,
        })?;
        Self::from_yaml(yaml, &text, rule, |image| {
            std::fs::read(image).map(Cow::Owned)
        })
    }

    /// A map from the text of its YAML and a reader of the image file it names (the
    /// YAML's `image:`, relative to the folder of `yaml` unless absolute). `yaml` names
    /// the map (its file stem) and the errors; nothing is read but what `read_image`
    /// reads, so maps held in memory (the shipped maps) load without touching the disk.
    pub fn from_yaml<'a>(
        yaml: &Path,
        text: &str,
        rule: OccupancyRule,
        read_image: impl FnOnce(&Path) -> std::io::Result<Cow<'a, [u8]>>,
    ) -> Result<Map, MapError> {
        let spec = parse_yaml(yaml, text)?;
        let bytes = read_image(&spec.image).map_err(|e| MapError::Image {
            path: spec.image.clone(),
            yaml: yaml.to_path_buf(),
            message: e.to_string(),
        })?;
        let name = yaml
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        build(yaml, &name, &spec, &bytes, rule)
    }
}

fn build(
    yaml: &Path,
    name: &str,
    spec: &MapSpec,
    bytes: &[u8],
    rule: OccupancyRule,
) -> Result<Map, MapError> {
    let img_err = |message: String| MapError::Image {
        path: spec.image.clone(),
        yaml: yaml.to_path_buf(),
        message,
    };
    let grey = decode_image(bytes).map_err(img_err)?;
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    if w == 0 || h == 0 {
        return Err(img_err(format!("empty image {w} x {h}")));
    }
    let raw = grey.as_raw();
    let mut occupied = vec![false; w * h];
    // The rule depends on the pixel value only: decide once per value.
    let mut table = [false; 256];
    for (v, slot) in table.iter_mut().enumerate() {
        *slot = is_occupied(v as u8, spec, rule);
    }
    for r in 0..h {
        // Grid row 0 is the image's bottom row.
        let src = &raw[(h - 1 - r) * w..(h - r) * w];
        let dst = &mut occupied[r * w..(r + 1) * w];
        for c in 0..w {
            dst[c] = table[usize::from(src[c])];
        }
    }
    Map::from_grid(name, w, h, spec.resolution, spec.origin, occupied).map_err(|e| match e {
        MapError::InvalidGrid { reason, .. } => img_err(reason),
        other => other,
    })
}

/// Widest or tallest map image accepted, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Most pixels a map image may have (64 Mi: at 5 cm per pixel, 400 m x 400 m of track).
/// The grid and its distance field take 9 bytes per pixel, so this caps a map near 600 MB.
pub const MAX_IMAGE_PIXELS: u64 = 64 << 20;

/// Width and height of a PNG or PGM image from its header alone (nothing is decoded or
/// allocated for the pixels), refused above [`MAX_IMAGE_SIDE`] or [`MAX_IMAGE_PIXELS`].
pub fn image_dimensions(bytes: &[u8]) -> Result<(u32, u32), String> {
    let (w, h) = reader(bytes)?
        .into_dimensions()
        .map_err(|e| e.to_string())?;
    check_dimensions(w, h)?;
    Ok((w, h))
}

fn check_dimensions(w: u32, h: u32) -> Result<(), String> {
    let pixels = u64::from(w) * u64::from(h);
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || pixels > MAX_IMAGE_PIXELS {
        return Err(format!(
            "image of {w} x {h} pixels exceeds the limit of {MAX_IMAGE_SIDE} pixels a side \
             and {MAX_IMAGE_PIXELS} pixels in all"
        ));
    }
    if w == 0 || h == 0 {
        return Err(format!("empty image {w} x {h}"));
    }
    Ok(())
}

fn reader(bytes: &[u8]) -> Result<image::ImageReader<std::io::Cursor<&[u8]>>, String> {
    image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())
}

/// Decodes a map image to grey levels, checking its size from the header first and
/// bounding the decoder's allocations, so a small file that claims a huge image is
/// refused before any pixel memory is taken.
pub fn decode_image(bytes: &[u8]) -> Result<image::GrayImage, String> {
    let (w, h) = image_dimensions(bytes)?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    // the widest pixel format map_server images use (16-bit RGBA) for the claimed size
    limits.max_alloc = Some(u64::from(w) * u64::from(h) * 8 + (1 << 20));
    let mut r = reader(bytes)?;
    r.limits(limits);
    Ok(r.decode().map_err(|e| e.to_string())?.into_luma8())
}

/// The `image:` entry of a map YAML that travels inside a map bundle: it must name a
/// file of the bundle itself, so only a bare file name is accepted (no absolute path, no
/// `..`, no directory). Returns None when the text is not a map YAML (no `image` entry);
/// the error says what is wrong with the value without touching the file system.
pub fn bundle_image_name(yaml_text: &str) -> Result<Option<String>, String> {
    let Ok(doc) = serde_norway::from_str::<Value>(yaml_text) else {
        return Ok(None);
    };
    let Some(v) = doc.get("image") else {
        return Ok(None);
    };
    let Some(name) = v.as_str() else {
        return Err(format!("{} is not a file name", show(v)));
    };
    let p = Path::new(name);
    let bare = !name.is_empty()
        && !p.is_absolute()
        && !name.contains(['/', '\\', '\0'])
        && name != "."
        && name != "..";
    if !bare {
        return Err(format!(
            "{name:?} is not a bare file name: a map bundle's image must be one of its own files \
             (no absolute path, no directory, no `..`)"
        ));
    }
    Ok(Some(name.to_string()))
}

#[inline]
fn is_occupied(v: u8, spec: &MapSpec, rule: OccupancyRule) -> bool {
    match rule {
        OccupancyRule::Reference => v <= 128,
        OccupancyRule::Ros => match spec.mode {
            Mode::Raw => v <= 100 && f64::from(v) / 100.0 > spec.occupied_thresh,
            Mode::Trinary | Mode::Scale => {
                let p = if spec.negate {
                    f64::from(v) / 255.0
                } else {
                    f64::from(255 - v) / 255.0
                };
                p > spec.occupied_thresh
            }
        },
    }
}

fn parse_yaml(path: &Path, text: &str) -> Result<MapSpec, MapError> {
    let path_buf = || path.to_path_buf();
    let doc: Value = serde_norway::from_str(text).map_err(|e| MapError::Yaml {
        path: path_buf(),
        message: e.to_string(),
    })?;
    if !doc.is_mapping() {
        return Err(MapError::Yaml {
            path: path_buf(),
            message: "top level is not a mapping".into(),
        });
    }
    let invalid = |field: &'static str, value: &Value, reason: &str| MapError::InvalidField {
        path: path_buf(),
        field,
        value: show(value),
        reason: reason.to_string(),
    };
    let missing = |field| MapError::MissingField {
        path: path_buf(),
        field,
    };
    let number = |field: &'static str, v: &Value| -> Result<f64, MapError> {
        v.as_f64().ok_or_else(|| invalid(field, v, "not a number"))
    };

    let image_v = doc.get("image").ok_or_else(|| missing("image"))?;
    let image_s = image_v
        .as_str()
        .filter(|s| !s.trim().is_empty())
        .ok_or_else(|| invalid("image", image_v, "not a file name"))?;
    let image_p = Path::new(image_s);
    let image = if image_p.is_absolute() {
        image_p.to_path_buf()
    } else {
        path.parent().unwrap_or(Path::new("")).join(image_p)
    };

    let res_v = doc.get("resolution").ok_or_else(|| missing("resolution"))?;
    let resolution = number("resolution", res_v)?;
    if !(resolution.is_finite() && resolution > 0.0) {
        return Err(invalid(
            "resolution",
            res_v,
            "must be a positive finite number",
        ));
    }

    let origin_v = doc.get("origin").ok_or_else(|| missing("origin"))?;
    let seq = origin_v
        .as_sequence()
        .filter(|s| s.len() == 2 || s.len() == 3)
        .ok_or_else(|| invalid("origin", origin_v, "expected [x, y, yaw]"))?;
    let mut o = [0.0; 3];
    for (slot, v) in o.iter_mut().zip(seq) {
        *slot = number("origin", v)?;
        if !slot.is_finite() {
            return Err(invalid("origin", origin_v, "components must be finite"));
        }
    }

    let negate = match doc.get("negate") {
        None | Some(Value::Null) => false,
        Some(v) => match (v.as_bool(), v.as_i64()) {
            (Some(b), _) => b,
            (_, Some(0)) => false,
            (_, Some(1)) => true,
            _ => return Err(invalid("negate", v, "expected 0, 1, true or false")),
        },
    };
    let thresh = |field: &'static str, default: f64| -> Result<f64, MapError> {
        match doc.get(field) {
            None | Some(Value::Null) => Ok(default),
            Some(v) => {
                let t = number(field, v)?;
                if (0.0..=1.0).contains(&t) {
                    Ok(t)
                } else {
                    Err(invalid(field, v, "must be in [0, 1]"))
                }
            }
        }
    };
    let occupied_thresh = thresh("occupied_thresh", 0.65)?;
    let free_thresh = thresh("free_thresh", 0.196)?;
    if free_thresh > occupied_thresh {
        return Err(invalid(
            "free_thresh",
            doc.get("free_thresh").unwrap_or(&Value::Null),
            "must not exceed occupied_thresh",
        ));
    }
    let mode = match doc.get("mode") {
        None | Some(Value::Null) => Mode::Trinary,
        Some(v) => match v.as_str() {
            Some("trinary") => Mode::Trinary,
            Some("scale") => Mode::Scale,
            Some("raw") => Mode::Raw,
            _ => return Err(invalid("mode", v, "expected trinary, scale or raw")),
        },
    };
    Ok(MapSpec {
        image,
        resolution,
        origin: Pose::new(o[0], o[1], o[2]),
        negate,
        occupied_thresh,
        mode,
    })
}

fn show(v: &Value) -> String {
    match serde_norway::to_string(v) {
        Ok(s) => s.trim_end().to_string(),
        Err(_) => format!("{v:?}"),
    }
}
