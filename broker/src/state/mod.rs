//! The broker's durable state under `--state DIR`: an embedded SQLite database
//! (`DIR/paddock.db`) holding every job (spec, serialised progress, result), and the
//! maps clients stored, by content hash, under `DIR/maps/<hash>/`.
//!
//! A job row is rewritten after every round, in one transaction, so a broker killed at
//! any moment restarts from the last finished round; finished jobs stay listable with
//! their results.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use rusqlite::{Connection, OptionalExtension, params};

/// Errors of the store; each names the file or the job.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("state directory {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("job database {path}: {source}")]
    Db {
        path: PathBuf,
        source: rusqlite::Error,
    },
    #[error("map bundle: {0}")]
    Bundle(String),
}

/// One job as stored.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct JobRecord {
    pub id: String,
    pub name: String,
    /// "tune", "rollouts" or "benchmark".
    pub kind: String,
    /// A `paddock_proto::JobState` value.
    pub state: i32,
    /// The submitted spec (encoded `JobSubmit`).
    pub spec: Vec<u8>,
    /// The job's serialised progress (for tune jobs the `TuneJob` JSON).
    pub job_state: String,
    /// The result document, once finished.
    pub result_json: String,
    /// Binary result (encoded `RolloutResult` for rollout jobs).
    pub result_bin: Vec<u8>,
    pub error: String,
    pub rounds_done: u32,
    pub rounds_total: u32,
    pub episodes_done: u64,
    pub progress_json: String,
    pub created_at: f64,
    pub updated_at: f64,
    /// Who submitted it (a broker principal: `key:...`, `token:...` or `peer:...`);
    /// empty for jobs stored before jobs had owners.
    pub owner: String,
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// The store; see the module documentation.
pub struct Store {
    dir: PathBuf,
    db_path: PathBuf,
    db: Connection,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    name TEXT NOT NULL,
    kind TEXT NOT NULL,
    state INTEGER NOT NULL,
    spec BLOB NOT NULL,
    job_state TEXT NOT NULL,
    result_json TEXT NOT NULL,
    result_bin BLOB NOT NULL,
    error TEXT NOT NULL,
    rounds_done INTEGER NOT NULL,
    rounds_total INTEGER NOT NULL,
    episodes_done INTEGER NOT NULL,
    progress_json TEXT NOT NULL,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS maps (
    hash TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    bytes INTEGER NOT NULL,
    stored_at REAL NOT NULL
);
";

const JOB_COLUMNS: &str = "id, name, kind, state, spec, job_state, result_json, result_bin, \
     error, rounds_done, rounds_total, episodes_done, progress_json, created_at, updated_at, owner";

/// A fresh job id: `job-` and 128 random bits in hex, so a job cannot be found by
/// counting (the id is what a client without a CURVE key or client token holds).
fn draw_job_id() -> Result<String, std::io::Error> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b).map_err(std::io::Error::other)?;
    Ok(format!("job-{}", crate::core::hex(&b)))
}

impl Store {
    /// Opens (creating if needed) the store in `dir`.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        let io = |source| StoreError::Io {
            path: dir.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(dir.join("maps")).map_err(io)?;
        let db_path = dir.join("paddock.db");
        let db_err = |source| StoreError::Db {
            path: db_path.clone(),
            source,
        };
        let db = Connection::open(&db_path).map_err(db_err)?;
        db.execute_batch("PRAGMA journal_mode = WAL; PRAGMA synchronous = NORMAL;")
            .map_err(db_err)?;
        db.execute_batch(SCHEMA).map_err(db_err)?;
        // a store written before jobs had owners: its jobs get an empty owner
        let has_owner: bool = db
            .prepare("SELECT 1 FROM pragma_table_info('jobs') WHERE name = 'owner'")
            .and_then(|mut st| st.exists([]))
            .map_err(db_err)?;
        if !has_owner {
            db.execute_batch("ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT ''")
                .map_err(db_err)?;
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            db_path,
            db,
        })
    }

    fn db_err(&self, source: rusqlite::Error) -> StoreError {
        StoreError::Db {
            path: self.db_path.clone(),
            source,
        }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Creates a job row; its id is drawn here (see [`draw_job_id`]).
    pub fn insert_job(&self, job: &mut JobRecord) -> Result<(), StoreError> {
        job.id = draw_job_id().map_err(|source| StoreError::Io {
            path: self.dir.clone(),
            source,
        })?;
        self.db
            .execute(
                &format!("INSERT INTO jobs ({JOB_COLUMNS}) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16)"),
                params![
                    job.id,
                    job.name,
                    job.kind,
                    job.state,
                    job.spec,
                    job.job_state,
                    job.result_json,
                    job.result_bin,
                    job.error,
                    job.rounds_done,
                    job.rounds_total,
                    job.episodes_done as i64,
                    job.progress_json,
                    job.created_at,
                    job.updated_at,
                    job.owner
                ],
            )
            .map_err(|e| self.db_err(e))?;
        Ok(())
    }

    /// Deletes a job row; false when there was none.
    pub fn delete_job(&self, id: &str) -> Result<bool, StoreError> {
        let n = self
            .db
            .execute("DELETE FROM jobs WHERE id = ?1", [id])
            .map_err(|e| self.db_err(e))?;
        Ok(n > 0)
    }

    /// Jobs `owner` has stored (`None`: everyone's).
    pub fn count_jobs(&self, owner: Option<&str>) -> Result<usize, StoreError> {
        let n: i64 = match owner {
            Some(o) => self
                .db
                .query_row("SELECT COUNT(*) FROM jobs WHERE owner = ?1", [o], |r| {
                    r.get(0)
                }),
            None => self
                .db
                .query_row("SELECT COUNT(*) FROM jobs", [], |r| r.get(0)),
        }
        .map_err(|e| self.db_err(e))?;
        Ok(n as usize)
    }

    /// The newest `limit` jobs `owner` may see (its own and those stored before jobs had
    /// owners; `None`: every job), oldest first.
    pub fn jobs_of(&self, owner: Option<&str>, limit: usize) -> Result<Vec<JobRecord>, StoreError> {
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let sql = format!(
            "SELECT * FROM (SELECT seq, {JOB_COLUMNS} FROM jobs WHERE ?1 IS NULL OR owner = ?1 OR owner = '' \
             ORDER BY seq DESC LIMIT ?2) ORDER BY seq"
        );
        let mut st = self.db.prepare(&sql).map_err(|e| self.db_err(e))?;
        let rows = st
            .query_map(params![owner, limit], |r| Self::row_at(r, 1))
            .map_err(|e| self.db_err(e))?
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| self.db_err(e))?;
        Ok(rows)
    }

    /// Rewrites a job row (after a round, or when it ends).
    pub fn update_job(&self, job: &JobRecord) -> Result<(), StoreError> {
        let n = self
            .db
            .execute(
                "UPDATE jobs SET state = ?2, job_state = ?3, result_json = ?4, result_bin = ?5, \
                 error = ?6, rounds_done = ?7, rounds_total = ?8, episodes_done = ?9, \
                 progress_json = ?10, updated_at = ?11 WHERE id = ?1",
                params![
                    job.id,
                    job.state,
                    job.job_state,
                    job.result_json,
                    job.result_bin,
                    job.error,
                    job.rounds_done,
                    job.rounds_total,
                    job.episodes_done as i64,
                    job.progress_json,
                    job.updated_at
                ],
            )
            .map_err(|e| self.db_err(e))?;
        if n == 0 {
            return Err(self.db_err(rusqlite::Error::QueryReturnedNoRows));
        }
        Ok(())
    }

    fn row(r: &rusqlite::Row<'_>) -> rusqlite::Result<JobRecord> {
        Self::row_at(r, 0)
    }

    /// A job from the row's columns `at..` (in [`JOB_COLUMNS`] order).
    fn row_at(r: &rusqlite::Row<'_>, at: usize) -> rusqlite::Result<JobRecord> {
        Ok(JobRecord {
            id: r.get(at)?,
            name: r.get(at + 1)?,
            kind: r.get(at + 2)?,
            state: r.get(at + 3)?,
            spec: r.get(at + 4)?,
            job_state: r.get(at + 5)?,
            result_json: r.get(at + 6)?,
            result_bin: r.get(at + 7)?,
            error: r.get(at + 8)?,
            rounds_done: r.get(at + 9)?,
            rounds_total: r.get(at + 10)?,
            episodes_done: r.get::<_, i64>(at + 11)? as u64,
            progress_json: r.get(at + 12)?,
            created_at: r.get(at + 13)?,
            updated_at: r.get(at + 14)?,
            owner: r.get(at + 15)?,
        })
    }

    pub fn job(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        self.db
            .query_row(
                &format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"),
                [id],
                Self::row,
            )
            .optional()
            .map_err(|e| self.db_err(e))
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Result<Vec<JobRecord>, StoreError> {
        let mut st = self
            .db
            .prepare(&format!("SELECT {JOB_COLUMNS} FROM jobs ORDER BY seq"))
            .map_err(|e| self.db_err(e))?;
        let rows = st
            .query_map([], Self::row)
            .map_err(|e| self.db_err(e))?
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| self.db_err(e))?;
        Ok(rows)
    }

    /// The directory of a stored map.
    pub fn map_dir(&self, hash: &str) -> PathBuf {
        self.dir.join("maps").join(hash)
    }

    /// Whether a map with this hash is stored.
    pub fn has_map(&self, hash: &str) -> Result<bool, StoreError> {
        if !is_hex_hash(hash) {
            return Ok(false);
        }
        let n: i64 = self
            .db
            .query_row("SELECT COUNT(*) FROM maps WHERE hash = ?1", [hash], |r| {
                r.get(0)
            })
            .map_err(|e| self.db_err(e))?;
        Ok(n > 0 && self.map_dir(hash).is_dir())
    }

    /// Stores a checked bundle under its hash (idempotent).
    pub fn put_map(&self, bundle: &paddock_proto::MapBundle) -> Result<(), StoreError> {
        paddock_proto::check_bundle(bundle).map_err(|e| StoreError::Bundle(e.message))?;
        if self.has_map(&bundle.hash)? {
            return Ok(());
        }
        let final_dir = self.map_dir(&bundle.hash);
        let tmp = self.dir.join("maps").join(format!(".tmp-{}", bundle.hash));
        let io = |source| StoreError::Io {
            path: final_dir.clone(),
            source,
        };
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(io)?;
        }
        paddock_proto::write_map_dir(bundle, &tmp).map_err(io)?;
        if final_dir.exists() {
            std::fs::remove_dir_all(&final_dir).map_err(io)?;
        }
        std::fs::rename(&tmp, &final_dir).map_err(io)?;
        let bytes: usize = bundle.files.iter().map(|f| f.data.len()).sum();
        self.db
            .execute(
                "INSERT OR REPLACE INTO maps (hash, name, bytes, stored_at) VALUES (?1, ?2, ?3, ?4)",
                params![bundle.hash, bundle.name, bytes as i64, unix_now()],
            )
            .map_err(|e| self.db_err(e))?;
        Ok(())
    }

    /// Reads a stored map back as a bundle (for workers that ask for it).
    pub fn map_bundle(&self, hash: &str) -> Result<Option<paddock_proto::MapBundle>, StoreError> {
        if !self.has_map(hash)? {
            return Ok(None);
        }
        let name: String = self
            .db
            .query_row("SELECT name FROM maps WHERE hash = ?1", [hash], |r| {
                r.get(0)
            })
            .map_err(|e| self.db_err(e))?;
        let dir = self.map_dir(hash);
        let mut bundle =
            paddock_proto::read_map_dir(&dir, &name).map_err(|source| StoreError::Io {
                path: dir.clone(),
                source,
            })?;
        if bundle.hash != hash {
            return Err(StoreError::Bundle(format!(
                "stored map {} no longer matches its hash (files hash to {})",
                dir.display(),
                bundle.hash
            )));
        }
        bundle.hash = hash.to_string();
        Ok(Some(bundle))
    }
}

impl Store {
    /// The file of a stored blob.
    fn blob_path(&self, hash: &str) -> PathBuf {
        self.dir.join("blobs").join(hash)
    }

    /// Bytes of the maps and blobs stored on disk.
    pub fn stored_bytes(&self) -> u64 {
        fn walk(dir: &Path) -> u64 {
            let Ok(entries) = std::fs::read_dir(dir) else {
                return 0;
            };
            entries
                .flatten()
                .map(|e| match e.file_type() {
                    Ok(t) if t.is_dir() => walk(&e.path()),
                    Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
                    _ => 0,
                })
                .sum()
        }
        walk(&self.dir.join("maps")) + walk(&self.dir.join("blobs"))
    }

    /// Whether a blob with this hash is stored.
    pub fn has_blob(&self, hash: &str) -> bool {
        self.blob_path(hash).is_file()
    }

    /// Stores bytes under their hash (idempotent); returns the hash.
    pub fn put_blob(&self, data: &[u8]) -> Result<String, StoreError> {
        let hash = paddock_proto::blob_hash(data);
        let path = self.blob_path(&hash);
        if path.is_file() {
            return Ok(hash);
        }
        let io = |source| StoreError::Io {
            path: path.clone(),
            source,
        };
        let dir = self.dir.join("blobs");
        std::fs::create_dir_all(&dir).map_err(io)?;
        let tmp = dir.join(format!(".tmp-{hash}"));
        std::fs::write(&tmp, data).map_err(io)?;
        std::fs::rename(&tmp, &path).map_err(io)?;
        Ok(hash)
    }

    /// A stored blob's bytes, checked against its hash; None when it is not stored.
    pub fn blob(&self, hash: &str) -> Result<Option<Vec<u8>>, StoreError> {
        if !is_hex_hash(hash) {
            return Ok(None);
        }
        let path = self.blob_path(hash);
        let data = match std::fs::read(&path) {
            Ok(d) => d,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(StoreError::Io { path, source }),
        };
        if paddock_proto::blob_hash(&data) != hash {
            return Err(StoreError::Bundle(format!(
                "stored blob {} no longer matches its hash",
                path.display()
            )));
        }
        Ok(Some(data))
    }
}

/// A map hash as [`paddock_proto::bundle_hash`] writes it: 64 lowercase hex digits
/// (also keeps hashes from naming paths outside the map store).
pub fn is_hex_hash(hash: &str) -> bool {
    hash.len() == 64
        && hash
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle() -> paddock_proto::MapBundle {
        let png = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../maps/lakeside/lakeside_map.png"
        );
        // sorted by name, as the store reads them back; a bundle's image must be one of
        // its files (check_bundle)
        let files = vec![
            paddock_proto::MapFile {
                name: "x.png".into(),
                data: std::fs::read(png).unwrap(),
            },
            paddock_proto::MapFile {
                name: "x_map.yaml".into(),
                data: b"image: x.png\n".to_vec(),
            },
        ];
        paddock_proto::MapBundle {
            hash: paddock_proto::bundle_hash(&files),
            name: "x".into(),
            files,
        }
    }

    #[test]
    fn jobs_survive_reopening_and_keep_their_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = JobRecord {
            name: "first".into(),
            kind: "tune".into(),
            state: 2,
            job_state: "{}".into(),
            ..Default::default()
        };
        let mut b = JobRecord {
            name: "second".into(),
            kind: "rollouts".into(),
            ..Default::default()
        };
        {
            let s = Store::open(dir.path()).unwrap();
            s.insert_job(&mut a).unwrap();
            s.insert_job(&mut b).unwrap();
            a.rounds_done = 3;
            a.job_state = "{\"round\":3}".into();
            s.update_job(&a).unwrap();
        }
        let s = Store::open(dir.path()).unwrap();
        let jobs = s.jobs().unwrap();
        assert_eq!(jobs.len(), 2);
        assert_eq!(jobs[0], a);
        assert_eq!(jobs[1].id, b.id);
        assert_ne!(a.id, b.id);
        let mut c = JobRecord {
            owner: "key:A".into(),
            ..Default::default()
        };
        s.insert_job(&mut c).unwrap();
        // ids are 128 random bits, not a count
        assert!(c.id.starts_with("job-") && c.id.len() == 36, "{}", c.id);
        assert!(![&a.id, &b.id].contains(&&c.id));
        assert!(s.job("job-99").unwrap().is_none());
        // owners: key:A sees its job and the unowned ones; key:B only the unowned
        assert_eq!(s.jobs_of(Some("key:A"), 10).unwrap().len(), 3);
        assert_eq!(s.jobs_of(Some("key:B"), 10).unwrap().len(), 2);
        assert_eq!(s.jobs_of(None, 2).unwrap().len(), 2, "the newest two");
        assert_eq!(s.jobs_of(None, 2).unwrap()[1].id, c.id);
        assert_eq!(s.count_jobs(Some("key:A")).unwrap(), 1);
        assert!(s.delete_job(&c.id).unwrap());
        assert!(!s.delete_job(&c.id).unwrap());
        assert_eq!(s.count_jobs(None).unwrap(), 2);
        let ghost = JobRecord {
            id: "job-99".into(),
            ..Default::default()
        };
        assert!(s.update_job(&ghost).is_err());
    }

    #[test]
    fn maps_are_stored_by_hash_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        let b = bundle();
        assert!(!s.has_map(&b.hash).unwrap());
        s.put_map(&b).unwrap();
        s.put_map(&b).unwrap();
        assert!(s.has_map(&b.hash).unwrap());
        assert_eq!(s.map_bundle(&b.hash).unwrap().unwrap(), b);
        assert!(s.map_dir(&b.hash).join("x_map.yaml").is_file());
        // a bundle whose files do not match its hash is refused
        let mut bad = b.clone();
        bad.files[1].data.push(b'!');
        assert!(matches!(s.put_map(&bad), Err(StoreError::Bundle(_))));
        // hashes that could name other paths are never looked up
        assert!(!s.has_map("../../etc").unwrap());
        assert!(s.map_bundle("..").unwrap().is_none());
    }
}
