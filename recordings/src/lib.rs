//! # paddock-recordings: the car's messages and recordings
//!
//! The ROS 2 messages the car's stack speaks ([`msg`]: LaserScan, Odometry,
//! AckermannDriveStamped, ...) and their one CDR codec ([`cdr`]), and the recordings
//! made of them. A recording from the car comes in one of the forms ROS 2 writes:
//!
//! - an **MCAP file** (`paddock bridge record`, or `ros2 bag record -s mcap`, the default
//!   from Iron on). A file whose writer died before finalising it (a power cut, a kill)
//!   has no summary and ends mid-record: it is read up to its last complete chunk (of
//!   an uncompressed chunk cut short, up to its last whole message), and
//!   [`Bag::truncation`] says how much was recovered;
//! - a **rosbag2 bag folder** (`metadata.yaml` plus its storage files): SQLite3 (`.db3`,
//!   Humble's default storage) or MCAP, as `metadata.yaml` says;
//! - a bare **`.db3`** file of such a bag.
//!
//! rosbag2's compression (`ros2 bag record --compression-mode file|message
//! --compression-format zstd`) is read too: a folder whose storage files are each one zstd
//! stream (`*.mcap.zstd`, `*.db3.zstd`; a bare one of them as well), or whose messages are
//! each compressed, as `metadata.yaml` says.
//!
//! [`read_bag`] takes any of them and returns the messages of the topics asked for, in
//! log-time order, as their serialized bytes (CDR with its encapsulation header, the same
//! bytes in both storages), which [`cdr::from_cdr`] decodes into [`msg`] types.
//! [`write::McapBag`] writes an MCAP ROS 2 bag.
//!
//! Why a crate of its own: the bridge (on DDS, in `record` and `export-csv`) and the
//! reality-gap tool (`paddock sysid`) speak the same messages and read the same
//! recordings, and neither should depend on the other. It depends on no Paddock crate.

pub mod cdr;
pub mod msg;
pub mod track;
pub mod write;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Errors of reading a recording; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: String, message: String },
}

impl RecordingError {
    fn format(path: &Path, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.display().to_string(),
            message: message.into(),
        }
    }

    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

/// The storage a recording was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StorageFormat {
    Mcap,
    /// rosbag2's SQLite3 storage (`.db3`).
    Sqlite3,
}

/// One recorded message.
#[derive(Debug, Clone, PartialEq)]
pub struct BagMessage {
    pub topic: String,
    /// Nanoseconds since the epoch (rosbag2: the receive time; `paddock bridge record`:
    /// the header stamp by default).
    pub log_time: u64,
    /// The serialized message (`cdr`: with its 4-byte encapsulation header).
    pub data: Vec<u8>,
}

/// A topic of the recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// The ROS type (`nav_msgs/msg/Odometry`).
    pub type_name: String,
    /// The serialization (`cdr` for ROS 2).
    pub encoding: String,
    /// Messages read (all of them, also on topics not asked for).
    pub messages: u64,
    /// rosbag2's `offered_qos_profiles` (YAML) when the recording carries it.
    pub offered_qos_profiles: Option<String>,
}

/// What was recovered from an MCAP file that was never finalised.
#[derive(Debug, Clone, PartialEq)]
pub struct Truncation {
    /// Messages recovered (every topic).
    pub messages: u64,
    /// From the first to the last recovered message's log time, s.
    pub span_s: f64,
    /// The file's size, bytes.
    pub file_bytes: u64,
    /// Why reading stopped (the incomplete record at the end).
    pub error: String,
}

impl std::fmt::Display for Truncation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the recording was not finalised (power cut or kill?): recovered {} messages \
             over {:.2} s from the {} bytes written; the incomplete rest is lost ({})",
            self.messages, self.span_s, self.file_bytes, self.error
        )
    }
}

/// A recording read.
#[derive(Debug, Clone, PartialEq)]
pub struct Bag {
    pub format: StorageFormat,
    /// Messages of the topics asked for, by log time (stable for equal times).
    pub messages: Vec<BagMessage>,
    pub topics: BTreeMap<String, TopicInfo>,
    /// Set when an MCAP file ended before its summary (not finalised).
    pub truncation: Option<Truncation>,
}

impl Bag {
    /// "topic (n), topic (n)": what the recording holds, for error messages.
    pub fn topic_list(&self) -> String {
        self.topics
            .iter()
            .map(|(t, i)| format!("{t} ({} {})", i.messages, i.type_name))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Is `path` something [`read_bag`] reads as a ROS 2 recording (an `.mcap` or `.db3`
/// file, a file starting with the MCAP magic, or a folder with `metadata.yaml`)?
pub fn is_bag(path: &Path) -> bool {
    if path.is_dir() {
        return path.join("metadata.yaml").is_file();
    }
    let ext = |e: &str| path.extension().is_some_and(|x| x.eq_ignore_ascii_case(e));
    if ext("mcap") || ext("db3") || compressed_storage(path).is_some() {
        return true;
    }
    let mut magic = [0u8; 5];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
        .is_ok_and(|()| &magic == b"\x89MCAP")
}

/// Read the messages on `topics` from the recording at `path` (see the crate docs for
/// the forms it takes).
pub fn read_bag(path: &Path, topics: &[&str]) -> Result<Bag, RecordingError> {
    if path.is_dir() {
        return read_bag_folder(path, topics);
    }
    if let Some(storage) = compressed_storage(path) {
        return read_compressed_file(path, storage, topics);
    }
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("db3"))
    {
        return read_db3(path, topics);
    }
    let bytes = std::fs::read(path).map_err(|e| RecordingError::io(path, e))?;
    read_mcap(&bytes, path, topics)
}

/// `f`, or the message of its panic: for a third-party parser that may panic on damaged
/// input, so that a damaged recording is an error, not a crash.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
        p.downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic".to_string())
    })
}

/// Read an MCAP file's bytes; `path` names it in errors. A file that ends before its
/// summary is read up to its last complete chunk ([`Bag::truncation`] says how much).
pub fn read_mcap(bytes: &[u8], path: &Path, topics: &[&str]) -> Result<Bag, RecordingError> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(RecordingError::format(
            path,
            "not an MCAP file (no MCAP magic at the start)",
        ));
    }
    let finalised = guarded(|| mcap::read::footer(bytes).is_ok()).unwrap_or(false);
    let options = if finalised {
        Default::default()
    } else {
        mcap::read::Options::IgnoreEndMagic.into()
    };
    let mut stream = guarded(|| mcap::MessageStream::new_with_options(bytes, options))
        .map_err(|e| RecordingError::format(path, format!("not an MCAP file: {e}")))?
        .map_err(|e| RecordingError::format(path, format!("not an MCAP file: {e}")))?;
    let mut messages = Vec::new();
    let mut infos: BTreeMap<String, TopicInfo> = BTreeMap::new();
    let (mut read, mut first, mut last) = (0u64, u64::MAX, 0u64);
    let mut stopped = None;
    // the MCAP reader's arithmetic can overflow on a damaged record (a panic where
    // overflow is checked): that is a damaged file, read as far as it goes
    loop {
        let next = match guarded(|| stream.next()) {
            Ok(None) => break,
            Ok(Some(r)) => r.map_err(|e| e.to_string()),
            Err(panic) => Err(format!("a damaged record ({panic})")),
        };
        let m = match next {
            Ok(m) => m,
            Err(e) if !finalised => {
                stopped = Some(e);
                break;
            }
            Err(e) => {
                return Err(RecordingError::format(path, format!("reading MCAP: {e}")));
            }
        };
        read += 1;
        first = first.min(m.log_time);
        last = last.max(m.log_time);
        let topic = &m.channel.topic;
        let info = infos.entry(topic.clone()).or_insert_with(|| TopicInfo {
            type_name: m
                .channel
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default(),
            encoding: m.channel.message_encoding.clone(),
            messages: 0,
            offered_qos_profiles: m.channel.metadata.get("offered_qos_profiles").cloned(),
        });
        info.messages += 1;
        if topics.contains(&topic.as_str()) {
            messages.push(BagMessage {
                topic: topic.clone(),
                log_time: m.log_time,
                data: m.data.into_owned(),
            });
        }
    }
    let truncation = if finalised {
        None
    } else {
        let error = stopped.unwrap_or_else(|| "no summary or footer".to_string());
        if read == 0 {
            return Err(RecordingError::format(
                path,
                format!(
                    "an MCAP file that was not finalised and has no complete chunk to recover \
                     ({} bytes; {error})",
                    bytes.len()
                ),
            ));
        }
        let t = Truncation {
            messages: read,
            span_s: last.saturating_sub(first) as f64 * 1e-9,
            file_bytes: bytes.len() as u64,
            error,
        };
        Some(t)
    };
    messages.sort_by_key(|m| m.log_time);
    Ok(Bag {
        format: StorageFormat::Mcap,
        messages,
        topics: infos,
        truncation,
    })
}

/// Read one rosbag2 SQLite3 storage file (`.db3`).
pub fn read_db3(path: &Path, topics: &[&str]) -> Result<Bag, RecordingError> {
    use rusqlite::{Connection, OpenFlags};
    let sql = |e: rusqlite::Error| RecordingError::format(path, format!("rosbag2 SQLite3: {e}"));
    if !path.is_file() {
        return Err(RecordingError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let db = Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sql)?;
    // the columns every rosbag2 version has (Jazzy adds type_description_hash)
    let mut by_id: BTreeMap<i64, String> = BTreeMap::new();
    let mut infos: BTreeMap<String, TopicInfo> = BTreeMap::new();
    {
        let mut st = db
            .prepare(
                "SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics",
            )
            .map_err(|e| {
                RecordingError::format(
                    path,
                    format!("not a rosbag2 SQLite3 bag (no topics table?): {e}"),
                )
            })?;
        let rows = st
            .query_map([], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, String>(3)?,
                    r.get::<_, Option<String>>(4)?,
                ))
            })
            .map_err(sql)?;
        for row in rows {
            let (id, name, type_name, encoding, qos) = row.map_err(sql)?;
            by_id.insert(id, name.clone());
            infos.insert(
                name,
                TopicInfo {
                    type_name,
                    encoding,
                    messages: 0,
                    offered_qos_profiles: qos.filter(|q| !q.is_empty()),
                },
            );
        }
    }
    let mut messages = Vec::new();
    let mut st = db
        .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(sql)?;
    let rows = st
        .query_map([], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, i64>(1)?,
                r.get::<_, Vec<u8>>(2)?,
            ))
        })
        .map_err(sql)?;
    for row in rows {
        let (topic_id, timestamp, data) = row.map_err(sql)?;
        let Some(topic) = by_id.get(&topic_id) else {
            return Err(RecordingError::format(
                path,
                format!("a message on topic_id {topic_id}, which the topics table lacks"),
            ));
        };
        if let Some(info) = infos.get_mut(topic) {
            info.messages += 1;
        }
        if topics.contains(&topic.as_str()) {
            messages.push(BagMessage {
                topic: topic.clone(),
                log_time: u64::try_from(timestamp).map_err(|_| {
                    RecordingError::format(
                        path,
                        format!("negative timestamp {timestamp} on {topic}"),
                    )
                })?,
                data,
            });
        }
    }
    Ok(Bag {
        format: StorageFormat::Sqlite3,
        messages,
        topics: infos,
        truncation: None,
    })
}

/// The storage of a file that rosbag2 compressed whole: `sqlite3` for `*.db3.zstd`,
/// `mcap` for `*.mcap.zstd`.
fn compressed_storage(path: &Path) -> Option<&'static str> {
    let name = path.file_name()?.to_str()?.to_ascii_lowercase();
    if name.ends_with(".db3.zstd") {
        Some("sqlite3")
    } else if name.ends_with(".mcap.zstd") {
        Some("mcap")
    } else {
        None
    }
}

/// The bytes of a zstd-compressed file.
fn decompress_file(path: &Path) -> Result<Vec<u8>, RecordingError> {
    let file = std::fs::File::open(path).map_err(|e| RecordingError::io(path, e))?;
    zstd::stream::decode_all(std::io::BufReader::new(file)).map_err(|e| {
        RecordingError::format(
            path,
            format!("not a whole zstd stream (rosbag2 file compression): {e}"),
        )
    })
}

/// Read a storage file that rosbag2 compressed whole (`storage`: `sqlite3` or `mcap`).
/// SQLite reads files, so a `.db3` is decompressed into a temporary file first.
fn read_compressed_file(
    path: &Path,
    storage: &str,
    topics: &[&str],
) -> Result<Bag, RecordingError> {
    let bytes = decompress_file(path)?;
    if storage == "mcap" {
        return read_mcap(&bytes, path, topics);
    }
    let mut tmp = tempfile::Builder::new()
        .prefix("paddock-bag-")
        .suffix(".db3")
        .tempfile()
        .map_err(|e| RecordingError::io(path, e))?;
    std::io::Write::write_all(&mut tmp, &bytes).map_err(|e| RecordingError::io(path, e))?;
    drop(bytes);
    // errors name the user's file, not the temporary one
    read_db3(tmp.path(), topics).map_err(|e| match e {
        RecordingError::Format { message, .. } => RecordingError::format(path, message),
        RecordingError::Io { source, .. } => RecordingError::io(path, source),
    })
}

/// Read a rosbag2 bag folder: `metadata.yaml` names the storage, its files and their
/// compression.
pub fn read_bag_folder(dir: &Path, topics: &[&str]) -> Result<Bag, RecordingError> {
    let meta_path = dir.join("metadata.yaml");
    let text =
        std::fs::read_to_string(&meta_path).map_err(|e| RecordingError::io(&meta_path, e))?;
    let meta: serde_norway::Value = serde_norway::from_str(&text)
        .map_err(|e| RecordingError::format(&meta_path, format!("not YAML: {e}")))?;
    let info = &meta["rosbag2_bagfile_information"];
    let storage = info["storage_identifier"].as_str().ok_or_else(|| {
        RecordingError::format(
            &meta_path,
            "no rosbag2_bagfile_information.storage_identifier (not a rosbag2 bag?)",
        )
    })?;
    let files: Vec<PathBuf> = info["relative_file_paths"]
        .as_sequence()
        .map(|s| {
            s.iter()
                .filter_map(|f| f.as_str())
                .map(|f| dir.join(f))
                .collect()
        })
        .unwrap_or_default();
    if files.is_empty() {
        return Err(RecordingError::format(
            &meta_path,
            "rosbag2_bagfile_information.relative_file_paths lists no storage file",
        ));
    }
    if !matches!(storage, "sqlite3" | "mcap") {
        return Err(RecordingError::format(
            &meta_path,
            format!("storage_identifier = {storage:?}: only sqlite3 and mcap are read"),
        ));
    }
    let mode = info["compression_mode"]
        .as_str()
        .unwrap_or("")
        .to_ascii_lowercase();
    let format = info["compression_format"].as_str().unwrap_or("");
    let (whole_files, per_message) = match mode.as_str() {
        "" | "none" => (false, false),
        "file" | "message" if format.eq_ignore_ascii_case("zstd") => {
            (mode == "file", mode == "message")
        }
        "file" | "message" => {
            return Err(RecordingError::format(
                &meta_path,
                format!(
                    "compression_format = {format:?}: only zstd (rosbag2's compressor) is read"
                ),
            ));
        }
        other => {
            return Err(RecordingError::format(
                &meta_path,
                format!("compression_mode = {other:?}: file, message or none"),
            ));
        }
    };
    let mut out: Option<Bag> = None;
    for file in &files {
        let mut bag = match (whole_files, storage) {
            (true, _) => read_compressed_file(file, storage, topics)?,
            (false, "sqlite3") => read_db3(file, topics)?,
            _ => {
                let bytes = std::fs::read(file).map_err(|e| RecordingError::io(file, e))?;
                read_mcap(&bytes, file, topics)?
            }
        };
        if per_message {
            for (k, m) in bag.messages.iter_mut().enumerate() {
                m.data = zstd::stream::decode_all(&m.data[..]).map_err(|e| {
                    RecordingError::format(
                        file,
                        format!(
                            "message {k} on {}: not zstd as compression_mode = message says: {e}",
                            m.topic
                        ),
                    )
                })?;
            }
        }
        out = Some(match out {
            None => bag,
            Some(mut acc) => {
                acc.messages.extend(bag.messages);
                for (t, i) in bag.topics {
                    acc.topics
                        .entry(t)
                        .and_modify(|a| a.messages += i.messages)
                        .or_insert(i);
                }
                if acc.truncation.is_none() {
                    acc.truncation = bag.truncation;
                }
                acc
            }
        });
    }
    let mut bag = out.expect("at least one storage file");
    bag.messages.sort_by_key(|m| m.log_time);
    Ok(bag)
}

#[cfg(test)]
mod tests;
