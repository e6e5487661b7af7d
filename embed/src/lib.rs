//! Env sessions inside the learner's own process.
//!
//! A learner on one machine reaches the simulator through a local `paddock serve`: its
//! requests cross a socket to the broker, then another to the worker thread, and every
//! observation comes back the same way. For a vector env on one core those hops, the
//! socket threads and the three processes' turns on the CPU cost a fifth to a third of
//! what the simulation itself does (docs/performance-vecenv.md). Here the worker's own
//! [`Sessions`] run in the caller's process instead, behind a small C ABI that the Python
//! package loads with `ctypes`: requests and replies are the very protobuf messages and
//! payload frames a client and a worker exchange, so the checks, the error replies, the
//! observations and their bits are the worker's, and the client decodes them with the
//! code it uses for a server.
//!
//! A handle ([`Embedded`]) serves these requests (`kind` of [`paddock_embed_call`]):
//! - [`ENV`]: an env request (`EnvRequest.op` and its payload) on session `session`; 0
//!   opens one (the handle gives the ids, as the broker does). Frames: the encoded
//!   `EnvReply`, then its payload frames. A step or reset given a buffer of exactly its
//!   scans' size (`scans`, `scans_len`) writes the scans there and answers an empty
//!   scans frame: the learner's array is where the simulator writes them, with no frame
//!   to zero and no copy. Nothing here rebuilds a session elsewhere, so replies carry no
//!   fingerprint (`EnvReply.fingerprint` is 0).
//! - [`PUT_MAP`]: a `MapBundle`, checked and kept in the handle's map cache (a temporary
//!   directory made on the first map put and removed with the handle; a handle that only
//!   opens shipped maps writes nothing). Frames: the encoded `MapRef`.
//! - [`PUT_BLOB`]: an ONNX model's bytes, checked and registered with this process
//!   (`paddock_policy::onnx::register`). Frames: its `onnx:<sha256>` driver name.
//! - [`SHIPPED`]: the maps compiled into the library. Frames: a `BrokerStatus` with only
//!   its `maps` set.
//!
//! A refused request answers -1 and one frame, the encoded `Error` (code, field,
//! message), as a server would reply. A panic (a bug) becomes an `INTERNAL` error, never
//! an unwind into the caller. One handle serves one caller at a time (the Python side
//! holds a lock around each call); handles are independent of each other.
//!
//! A vector env's copies step on the library's own thread pool ([`process_pool`]), shared
//! by the process's handles, not on rayon's global pool: a process that forks (Python's
//! `multiprocessing` and gymnasium's `AsyncVectorEnv` by default on Linux) leaves the
//! pool's threads behind, and rayon's global pool cannot be made again, so a child that
//! stepped on it would wait for good. The library's pool ends with the process's last
//! handle and is made again by the next, in a forked child by the child's first handle.
//! A handle made before the fork stays the parent's: in the child its calls are refused
//! and freeing it leaves the parent's map cache alone.

use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, Once, PoisonError, Weak};

use paddock_proto::{BrokerStatus, EnvOp, Error, ErrorCode, MapBundle, error};
use paddock_sim::circuit::Circuits;
use paddock_worker::maps::MapCache;
use paddock_worker::sessions::Sessions;
use prost::Message;

/// The version of the C ABI below; the Python side refuses a library of another.
pub const ABI_VERSION: u32 = 2;

/// Request kinds of [`paddock_embed_call`].
pub const ENV: u32 = 1;
pub const PUT_MAP: u32 = 2;
pub const PUT_BLOB: u32 = 3;
pub const SHIPPED: u32 = 4;

/// This process's id without a system call per request (a handle's calls check it): read
/// once, and again in a forked child by a fork handler.
fn current_pid() -> u32 {
    static PID: AtomicU32 = AtomicU32::new(0);
    static HANDLER: Once = Once::new();
    extern "C" fn in_child() {
        // getpid and an atomic store: all a fork handler may do
        PID.store(std::process::id(), Ordering::Relaxed);
    }
    HANDLER.call_once(|| {
        PID.store(std::process::id(), Ordering::Relaxed);
        // SAFETY: registers a handler that only stores this process's new id.
        let rc = unsafe { libc::pthread_atfork(None, None, Some(in_child)) };
        assert_eq!(rc, 0, "registering the in-process simulator's fork handler");
    });
    PID.load(Ordering::Relaxed)
}

/// The thread pool of this process's handles, with rayon's default count
/// (`RAYON_NUM_THREADS`, else the cores this process may run on). The handles hold it: it
/// ends with the last of them (its threads with it, so a process that closed its envs
/// forks without them) and is made again by the next handle, in a forked child too
/// (whose parent's pool has no threads there).
pub fn process_pool() -> Arc<rayon::ThreadPool> {
    static POOL: Mutex<Option<(u32, Weak<rayon::ThreadPool>)>> = Mutex::new(None);
    let pid = current_pid();
    let mut slot = POOL.lock().unwrap_or_else(PoisonError::into_inner);
    match slot.take() {
        Some((owner, weak)) if owner == pid => {
            if let Some(pool) = weak.upgrade() {
                *slot = Some((owner, weak));
                return pool;
            }
        }
        // a forked child: the parent's pool is left as it is (its threads are not in
        // this process; ending it would only signal them)
        Some((_, parents)) => std::mem::forget(parents),
        None => {}
    }
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .thread_name(|i| format!("paddock-embed-{i}"))
            .build()
            .expect("the in-process simulator could not start its threads"),
    );
    *slot = Some((pid, Arc::downgrade(&pool)));
    pool
}

/// Env sessions, their map cache, and the frames of the last reply.
pub struct Embedded {
    sessions: Sessions,
    /// Made on the first map put; its directory is removed with the handle.
    cache: Option<(MapCache, tempfile::TempDir)>,
    next_session: u64,
    out: Vec<Vec<u8>>,
    /// The process that made the handle (a forked child's copy is not its to use).
    pid: u32,
}

impl Default for Embedded {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for Embedded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Embedded")
            .field("sessions", &self.sessions.count())
            .field("cache", &self.cache.as_ref().map(|(c, _)| c.root()))
            .finish()
    }
}

impl Embedded {
    /// A handle with no sessions (the shipped maps at hand, no map cache yet).
    pub fn new() -> Self {
        let mut sessions = Sessions::new();
        sessions.set_circuits(Circuits::new());
        sessions.set_fingerprints(false);
        // the learner's process's `PADDOCK_SCAN_PATH`: a bad value refuses every env open,
        // naming it
        sessions.set_scan_path(paddock_worker::scan_path::scan_path_from_env());
        sessions.set_pool(process_pool());
        Self {
            sessions,
            cache: None,
            next_session: 1,
            out: Vec::new(),
            pid: current_pid(),
        }
    }

    /// Whether this process is a fork of the one that made the handle.
    pub fn forked(&self) -> bool {
        current_pid() != self.pid
    }

    /// The map cache, made in a new temporary directory on first use.
    fn cache(&mut self) -> Result<&MapCache, Error> {
        if self.cache.is_none() {
            let io = |e: std::io::Error| {
                error(
                    ErrorCode::Internal,
                    "put_map",
                    format!("making the in-process map cache in the temporary directory: {e}"),
                )
            };
            let dir = tempfile::Builder::new()
                .prefix("paddock-embed-maps-")
                .tempdir()
                .map_err(io)?;
            let cache = MapCache::open(dir.path()).map_err(io)?;
            self.sessions.set_map_cache(cache.clone());
            self.cache = Some((cache, dir));
        }
        Ok(&self.cache.as_ref().expect("made above").0)
    }

    /// The reply frames to request `kind` (see the module docs), or the error; the
    /// scans of an env step or reset go into `scans` when it has their size.
    pub fn call(
        &mut self,
        kind: u32,
        session: u64,
        op: i32,
        payload: &[u8],
        scans: Option<&mut [u8]>,
    ) -> Result<Vec<Vec<u8>>, Error> {
        if self.forked() {
            return Err(error(
                ErrorCode::InvalidArgument,
                "handle",
                format!(
                    "this in-process simulator was made by process {} before it forked this \
                     one ({}); its threads are not here: make the env in this process",
                    self.pid,
                    current_pid()
                ),
            ));
        }
        match kind {
            ENV => Ok(self.env(session, op, payload, scans)),
            PUT_MAP => {
                let bundle = MapBundle::decode(payload).map_err(|e| {
                    error(
                        ErrorCode::BadMessage,
                        "put_map.bundle",
                        format!("put_map.bundle: {} bytes do not decode: {e}", payload.len()),
                    )
                })?;
                self.cache()?.store(&bundle)?;
                Ok(vec![paddock_wire::map_ref(&bundle).encode_to_vec()])
            }
            // The model's own checks (its size limit, the observation contract) refuse
            // it; registering gives its `onnx:<sha256>` name.
            PUT_BLOB => paddock_policy::onnx::register(payload, "put_blob.data")
                .map(|name| vec![name.as_bytes().to_vec()])
                .map_err(|e| error(ErrorCode::InvalidArgument, "put_blob.data", e.to_string())),
            SHIPPED => {
                let status = BrokerStatus {
                    maps: paddock_wire::shipped_bundles()
                        .iter()
                        .map(paddock_wire::map_ref)
                        .collect(),
                    ..Default::default()
                };
                Ok(vec![status.encode_to_vec()])
            }
            _ => Err(error(
                ErrorCode::InvalidArgument,
                "kind",
                format!("kind = {kind} is not a request this library serves (1-4)"),
            )),
        }
    }

    /// An env request's reply: its header, then its payload frames.
    fn env(
        &mut self,
        session: u64,
        op: i32,
        payload: &[u8],
        scans: Option<&mut [u8]>,
    ) -> Vec<Vec<u8>> {
        let mut id = session;
        if session == 0 && op == EnvOp::EnvOpen as i32 {
            id = self.next_session;
            self.next_session += 1;
        }
        let reply = self.sessions.handle_into(id, op, payload, scans);
        let mut frames = Vec::with_capacity(1 + reply.frames.len());
        frames.push(reply.header.encode_to_vec());
        frames.extend(reply.frames);
        frames
    }

    /// [`Embedded::call`] with a panic turned into an `INTERNAL` error; the reply (or the
    /// encoded error) is kept as the handle's frames. Returns the number of frames, or
    /// -1 for an error.
    pub fn serve(
        &mut self,
        kind: u32,
        session: u64,
        op: i32,
        payload: &[u8],
        scans: Option<&mut [u8]>,
    ) -> i64 {
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            self.call(kind, session, op, payload, scans)
        }))
        .unwrap_or_else(|panic| {
            let what = paddock_worker::panic_message(panic.as_ref());
            Err(error(
                ErrorCode::Internal,
                "",
                format!("the in-process simulator failed: {what}"),
            ))
        });
        match result {
            Ok(frames) => {
                self.out = frames;
                self.out.len() as i64
            }
            Err(e) => {
                self.out = vec![e.encode_to_vec()];
                -1
            }
        }
    }

    /// The frames of the last reply.
    pub fn frames(&self) -> &[Vec<u8>] {
        &self.out
    }
}

/// The C ABI's version ([`ABI_VERSION`]).
#[unsafe(no_mangle)]
pub extern "C" fn paddock_embed_abi_version() -> u32 {
    ABI_VERSION
}

/// A new handle (null only if making it panicked). Free it with [`paddock_embed_free`].
#[unsafe(no_mangle)]
pub extern "C" fn paddock_embed_new() -> *mut Embedded {
    match std::panic::catch_unwind(Embedded::new) {
        Ok(h) => Box::into_raw(Box::new(h)),
        Err(_) => std::ptr::null_mut(),
    }
}

/// Frees a handle from [`paddock_embed_new`] (its sessions and its map cache).
///
/// # Safety
/// `h` must come from [`paddock_embed_new`] and not have been freed; null is ignored.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn paddock_embed_free(h: *mut Embedded) {
    if !h.is_null() {
        // SAFETY: the caller passes a live handle from `paddock_embed_new`.
        let handle = unsafe { Box::from_raw(h) };
        if handle.forked() {
            // a forked child's copy of its parent's handle: dropping it would remove the
            // parent's map cache from the disk
            std::mem::forget(handle);
            return;
        }
        let _ = std::panic::catch_unwind(AssertUnwindSafe(move || drop(handle)));
    }
}

/// Serves request `kind` (see the module docs) with `len` bytes of payload at
/// `payload`: the number of reply frames, or -1 and one frame holding the encoded
/// `Error`; -2 for a null handle. The frames stay valid until the handle's next call.
/// An env step or reset whose scans take exactly `scans_len` bytes writes them at
/// `scans` and answers an empty scans frame; with another length (or null) they come
/// as a frame.
///
/// # Safety
/// `h` must be a live handle used by one thread at a time; `payload` must point to `len`
/// readable bytes (it may be null when `len` is 0); `scans` to `scans_len` writable
/// bytes that nothing else reads or writes during the call (null when `scans_len` is
/// 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn paddock_embed_call(
    h: *mut Embedded,
    kind: u32,
    session: u64,
    op: i32,
    payload: *const u8,
    len: usize,
    scans: *mut u8,
    scans_len: usize,
) -> i64 {
    // SAFETY: the caller passes a live handle, used by this thread alone.
    let Some(h) = (unsafe { h.as_mut() }) else {
        return -2;
    };
    let payload = if len == 0 || payload.is_null() {
        &[][..]
    } else {
        // SAFETY: the caller guarantees `len` readable bytes at `payload`.
        unsafe { std::slice::from_raw_parts(payload, len) }
    };
    let scans = if scans_len == 0 || scans.is_null() {
        None
    } else {
        // SAFETY: the caller guarantees `scans_len` writable bytes at `scans`, not
        // aliased during the call.
        Some(unsafe { std::slice::from_raw_parts_mut(scans, scans_len) })
    };
    h.serve(kind, session, op, payload, scans)
}

/// Frame `i` of the last reply: its length, its address written to `data` (null and 0
/// past the last frame).
///
/// # Safety
/// `h` must be a live handle; `data` must be writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn paddock_embed_frame(
    h: *const Embedded,
    i: usize,
    data: *mut *const u8,
) -> usize {
    // SAFETY: the caller passes a live handle.
    let frame = unsafe { h.as_ref() }.and_then(|h| h.frames().get(i));
    let (ptr, len) = frame.map_or((std::ptr::null(), 0), |f| (f.as_ptr(), f.len()));
    if !data.is_null() {
        // SAFETY: the caller passes a writable pointer.
        unsafe { *data = ptr };
    }
    len
}

/// Every frame of the last reply at once (one call instead of one per frame): the
/// address and length of frame `i` written to `data[i]` and `lens[i]` for the first `cap`
/// frames; returns the number of frames (0 for a null handle).
///
/// # Safety
/// `h` must be a live handle (or null); `data` and `lens` must each point to `cap`
/// writable elements (either may be null when `cap` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn paddock_embed_frames(
    h: *const Embedded,
    data: *mut *const u8,
    lens: *mut usize,
    cap: usize,
) -> usize {
    // SAFETY: the caller passes a live handle or null.
    let Some(frames) = (unsafe { h.as_ref() }).map(Embedded::frames) else {
        return 0;
    };
    if !data.is_null() && !lens.is_null() {
        for (i, f) in frames.iter().take(cap).enumerate() {
            // SAFETY: the caller passes `cap` writable elements at each; i < cap.
            unsafe {
                *data.add(i) = f.as_ptr();
                *lens.add(i) = f.len();
            }
        }
    }
    frames.len()
}

#[cfg(test)]
mod tests;
