//! The server commands: `paddock broker`, `paddock worker` and `paddock serve` (a broker
//! and local workers in one process), and [`BrokerThread`], a broker on a thread of this
//! process.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use paddock_broker::{Broker, BrokerConfig, Security};
use paddock_sim::circuit::Circuits;
use paddock_worker::{WorkerConfig, WorkerThread};

use crate::args::{self, outln};
use crate::bounds_args::BoundsArgs;
use crate::remote::Remote;

#[derive(Args)]
pub struct BrokerArgs {
    /// Client endpoint (the CLI and Python learners connect here).
    #[arg(long, default_value = "tcp://127.0.0.1:5555")]
    pub bind: String,
    /// Worker endpoint: where workers connect (`paddock worker --connect`).
    #[arg(long, default_value = "tcp://127.0.0.1:5556")]
    pub worker_bind: String,
    /// State directory: the job database and the maps by hash.
    #[arg(long, default_value = "paddock-state")]
    pub state: PathBuf,
    /// The broker's CURVE key file: with it, only peers whose public keys are in
    /// --client-keys / --worker-keys get in, and all traffic is encrypted.
    #[arg(long, env = "PADDOCK_SECRET_KEY_FILE", value_name = "FILE")]
    pub secret_key: Option<PathBuf>,
    /// Directory of the public keys of allowed clients (one file each).
    #[arg(
        long,
        env = "PADDOCK_CLIENT_KEYS",
        value_name = "DIR",
        requires = "secret_key"
    )]
    pub client_keys: Option<PathBuf>,
    /// Directory of the public keys of allowed workers.
    #[arg(
        long,
        env = "PADDOCK_WORKER_KEYS",
        value_name = "DIR",
        requires = "secret_key"
    )]
    pub worker_keys: Option<PathBuf>,
    /// Allow binding a non-loopback address without keys (anyone who can reach the
    /// ports can use the broker).
    #[arg(long)]
    pub insecure: bool,
    /// Touch this file every second while the broker runs (container health check).
    #[arg(long, value_name = "FILE")]
    pub health_file: Option<PathBuf>,
    /// Public key file of an admin client (repeatable): it sees and manages every
    /// client's jobs. Needs --secret-key.
    #[arg(long, value_name = "FILE", requires = "secret_key")]
    pub admin_key: Vec<PathBuf>,
    #[command(flatten)]
    pub bounds: BoundsArgs,
}

#[derive(Args)]
pub struct WorkerArgs {
    /// The broker's worker endpoint.
    #[arg(long, env = "PADDOCK_CONNECT", default_value = "tcp://127.0.0.1:5556")]
    pub connect: String,
    /// Episodes run at once (0: one per core this process may use, i.e. the
    /// container's CPU share; at most 4 per core).
    #[arg(long, env = "PADDOCK_THREADS", default_value_t = 0, value_parser = args::threads())]
    pub threads: usize,
    /// Touch this file at every heartbeat while the broker answers (health check).
    #[arg(long, value_name = "FILE")]
    pub health_file: Option<PathBuf>,
    /// Where maps received from the broker are kept (default: the user's cache folder).
    #[arg(long)]
    pub maps: Option<PathBuf>,
}

#[derive(Args)]
pub struct ServeArgs {
    /// Client endpoint.
    #[arg(long, default_value = "tcp://127.0.0.1:5555")]
    pub bind: String,
    /// How many workers run in this process.
    #[arg(long, default_value_t = 1, value_parser = args::whole::<usize>(1, 64))]
    pub workers: usize,
    /// Threads per worker (0: one per core divided among the workers; at most 4 per
    /// core).
    #[arg(long, default_value_t = 0, value_parser = args::threads())]
    pub threads: usize,
    /// State directory (default: a fresh temporary one, removed at exit).
    #[arg(long)]
    pub state: Option<PathBuf>,
    /// Where the workers keep maps (default: inside the state directory).
    #[arg(long)]
    pub maps: Option<PathBuf>,
    /// Stop (as Ctrl-C does) once the process with this id is no longer this server's
    /// parent, i.e. it exited or was killed: a server a program started never outlives
    /// it. The Python client passes its own id.
    #[arg(long, value_name = "PID", value_parser = args::whole::<u32>(1, u32::MAX.into()))]
    pub parent_pid: Option<u32>,
    /// Vehicle YAML (as `paddock sysid` writes it) of every car whose request names no
    /// vehicle (default: the f1tenth_gym vehicle); requests that carry one keep theirs.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,
    #[command(flatten)]
    pub bounds: BoundsArgs,
}

fn stop_flag() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // a second handler cannot be installed; then Ctrl-C simply ends the process
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    stop
}

fn is_loopback(endpoint: &str) -> bool {
    let host = endpoint
        .strip_prefix("tcp://")
        .and_then(|h| h.rsplit_once(':'))
        .map(|(h, _)| h);
    match host {
        Some(h) => h == "localhost" || h.starts_with("127.") || h == "[::1]",
        // ipc:// and inproc:// never leave the machine
        None => !endpoint.starts_with("tcp://"),
    }
}

/// The broker's CURVE security from its flags; refuses a public address without keys
/// unless --insecure.
fn broker_security(args: &BrokerArgs) -> Result<Option<Security>> {
    let Some(key) = &args.secret_key else {
        let public: Vec<&str> = [&args.bind, &args.worker_bind]
            .into_iter()
            .filter(|e| !is_loopback(e))
            .map(String::as_str)
            .collect();
        if !public.is_empty() {
            if !args.insecure {
                bail!(
                    "binding {} without keys would let anyone in: give --secret-key with \
                     --client-keys and --worker-keys (see `paddock keys generate`), or pass \
                     --insecure",
                    public.join(" and ")
                );
            }
            tracing::warn!(endpoints = ?public, "broker open to the network WITHOUT keys (--insecure)");
            eprintln!(
                "warning: --insecure: anyone who reaches {} can use this broker",
                public.join(", ")
            );
        }
        return Ok(None);
    };
    let keys = paddock_libzmq::KeyPair::read(key)?;
    let dir = |d: &Option<PathBuf>, flag: &str| -> Result<PathBuf> {
        let d = d.clone().ok_or_else(|| {
            anyhow!("--secret-key needs {flag} (a directory of allowed public keys)")
        })?;
        if !d.is_dir() {
            bail!("{flag} {}: not a directory", d.display());
        }
        Ok(d)
    };
    let admin_keys = args
        .admin_key
        .iter()
        .map(|p| paddock_libzmq::read_public(p).map_err(anyhow::Error::from))
        .collect::<Result<Vec<_>>>()?;
    Ok(Some(Security {
        keys,
        client_keys: dir(&args.client_keys, "--client-keys")?,
        worker_keys: dir(&args.worker_keys, "--worker-keys")?,
        admin_keys,
    }))
}

/// Touches `path` every second until `stop` is set.
fn health_beat(path: PathBuf, stop: Arc<AtomicBool>) {
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            crate::keys::touch(&path);
            std::thread::sleep(Duration::from_secs(1));
        }
    });
}

pub fn broker(args: &BrokerArgs) -> Result<()> {
    let mut cfg = BrokerConfig::new(&args.bind, &args.worker_bind, &args.state);
    cfg.security = broker_security(args)?;
    args.bounds.apply(&mut cfg);
    cfg.maps = paddock_wire::shipped_bundles();
    let secured = cfg.security.is_some();
    let mut broker = Broker::bind(cfg, paddock_jobs::Plans).context("starting the broker")?;
    eprintln!(
        "broker: clients at {}, workers at {}, state in {}",
        broker.frontend_endpoint(),
        broker.backend_endpoint(),
        args.state.display()
    );
    if secured {
        eprintln!("broker: CURVE on; allowed keys are read from --client-keys and --worker-keys");
    }
    let stop = stop_flag();
    if let Some(h) = &args.health_file {
        health_beat(h.clone(), stop.clone());
    }
    broker.run(&stop)?;
    Ok(())
}

pub fn worker(args: &WorkerArgs, circuits: &Circuits) -> Result<()> {
    let mut cfg = WorkerConfig::new(&args.connect);
    cfg.circuits = circuits.clone();
    cfg.threads = args.threads;
    cfg.curve = crate::remote::security();
    cfg.health_file = args.health_file.clone();
    cfg.scan_path = paddock_worker::scan_path::scan_path_from_env()?;
    if let Some(m) = &args.maps {
        cfg.maps_dir = m.clone();
    }
    let mut worker = paddock_worker::Worker::new(cfg).context("starting the worker")?;
    eprintln!(
        "worker {}: {} threads (holds up to {} tasks), broker at {}",
        worker.worker_id(),
        worker.threads(),
        worker.capacity(),
        args.connect
    );
    let stop = stop_flag();
    worker.run(&stop)?;
    Ok(())
}

pub fn serve(args: &ServeArgs, circuits: &Circuits) -> Result<()> {
    if args.workers == 0 {
        bail!("--workers = 0: serve needs at least one worker");
    }
    let parent_gone = || {
        args.parent_pid
            .is_some_and(|p| std::os::unix::process::parent_id() != p)
    };
    if parent_gone() {
        bail!(
            "--parent-pid {}: this server's parent is process {}",
            args.parent_pid.unwrap_or_default(),
            std::os::unix::process::parent_id()
        );
    }
    let vehicle = args::vehicle(args.vehicle.as_deref())?;
    let tmp;
    let state = match &args.state {
        Some(s) => s.clone(),
        None => {
            tmp = tempfile::tempdir().context("creating a state directory")?;
            tmp.path().to_path_buf()
        }
    };
    let stop = stop_flag();
    // the local workers share the broker's ZeroMQ context and connect over inproc://
    // (no TCP, no I/O thread between them); the TCP worker endpoint stays open for
    // remote workers
    let ctx = paddock_broker::zmq::Context::new();
    let local = format!("inproc://paddock-serve-workers-{}", std::process::id());
    let broker = BrokerThread::start_in(
        &args.bind,
        "tcp://127.0.0.1:0",
        &state,
        ctx.clone(),
        &local,
        &args.bounds,
    )?;
    let front = broker.front.clone();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = if args.threads > 0 {
        args.threads
    } else {
        (cores / args.workers).max(1)
    };
    let maps = args
        .maps
        .clone()
        .unwrap_or_else(|| state.join("worker-maps"));
    let scan_path = paddock_worker::scan_path::scan_path_from_env()?;
    let mut workers = Vec::with_capacity(args.workers);
    for _ in 0..args.workers {
        let mut cfg = WorkerConfig::new(&local);
        cfg.threads = threads;
        cfg.maps_dir = maps.clone();
        cfg.vehicle = vehicle.clone();
        cfg.scan_path = scan_path;
        // one registry for the process: the workers load each map once between them
        cfg.circuits = circuits.clone();
        workers.push(WorkerThread::spawn_in(cfg, ctx.clone()).context("starting a worker")?);
    }
    let mut remote = Remote::connect(&front, circuits)?;
    remote.wait_for_workers(args.workers, Duration::from_secs(30))?;
    // the one line a learner or script reads to find the broker
    outln!("{front}");
    eprintln!(
        "serving: {} workers x {threads} threads; clients connect to {front} (Ctrl-C stops)",
        args.workers
    );
    while !stop.load(Ordering::Relaxed) && !broker.is_finished() && !parent_gone() {
        std::thread::sleep(Duration::from_millis(100));
    }
    if parent_gone() {
        eprintln!("serve: the parent process has gone; stopping");
        // a stop that hangs must not leave an orphan behind either
        std::thread::spawn(|| {
            std::thread::sleep(Duration::from_secs(10));
            std::process::exit(1);
        });
    }
    for w in workers {
        let _ = w.stop();
    }
    broker.stop()
}

/// A broker serving on its own thread of this process.
pub struct BrokerThread {
    pub front: String,
    pub back: String,
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<()>>>,
}

impl BrokerThread {
    /// Binds a broker (port 0: any free port) and starts serving.
    pub fn start(bind: &str, backend: &str, state: &std::path::Path) -> Result<Self> {
        let cfg = BrokerConfig::new(bind, backend, state);
        Self::spawn(cfg, paddock_broker::zmq::Context::new())
    }

    /// [`BrokerThread::start`] in the ZeroMQ context `ctx`, with the worker socket also
    /// bound to `local` (an `inproc://` endpoint for workers of this process).
    pub fn start_in(
        bind: &str,
        backend: &str,
        state: &std::path::Path,
        ctx: paddock_broker::zmq::Context,
        local: &str,
        bounds: &BoundsArgs,
    ) -> Result<Self> {
        let mut cfg = BrokerConfig::new(bind, backend, state);
        cfg.local_backend = Some(local.to_string());
        bounds.apply(&mut cfg);
        Self::spawn(cfg, ctx)
    }

    fn spawn(mut cfg: BrokerConfig, ctx: paddock_broker::zmq::Context) -> Result<Self> {
        cfg.maps = paddock_wire::shipped_bundles();
        let (tx, rx) = std::sync::mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("paddock-broker".into())
            .spawn(move || -> Result<()> {
                let mut broker = match Broker::bind_in(cfg, paddock_jobs::Plans, ctx) {
                    Ok(b) => b,
                    Err(e) => {
                        let _ = tx.send(Err(anyhow!("starting the broker: {e}")));
                        return Ok(());
                    }
                };
                let _ = tx.send(Ok((
                    broker.frontend_endpoint().to_string(),
                    broker.backend_endpoint().to_string(),
                )));
                broker.run(&flag)?;
                Ok(())
            })?;
        let (front, back) = rx
            .recv()
            .map_err(|_| anyhow!("the broker thread ended before it started"))??;
        Ok(Self {
            front,
            back,
            stop,
            handle: Some(handle),
        })
    }

    pub fn is_finished(&self) -> bool {
        self.handle.as_ref().is_none_or(|h| h.is_finished())
    }

    /// Stops the broker and waits for its thread.
    pub fn stop(mut self) -> Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        match self.handle.take() {
            Some(h) => h
                .join()
                .map_err(|_| anyhow!("the broker thread panicked"))?,
            None => Ok(()),
        }
    }
}

impl Drop for BrokerThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
