//! The cluster commands: `paddock broker`, `paddock worker`, `paddock serve` (a broker
//! and local workers in one process), `paddock status` and `paddock jobs`.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, Subcommand};
use paddock_broker::{Broker, BrokerConfig, Security};
use paddock_proto::{Body, JobInfo, JobState};
use paddock_worker::{WorkerConfig, WorkerThread};

use crate::args::{self, outln};
use crate::remote::Remote;

/// How long a single request to the broker may wait for its reply.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);

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
    #[arg(long, value_name = "PID")]
    pub parent_pid: Option<u32>,
    /// Vehicle YAML (as `paddock sysid` writes it) of every car whose request names no
    /// vehicle (default: the f1tenth_gym vehicle); requests that carry one keep theirs.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,
}

#[derive(Args)]
pub struct StatusArgs {
    /// The broker's client endpoint.
    #[arg(long, default_value = "tcp://127.0.0.1:5555")]
    pub endpoint: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args)]
pub struct JobsArgs {
    #[command(subcommand)]
    pub command: JobsCommand,
    /// The broker's client endpoint.
    #[arg(long, global = true, default_value = "tcp://127.0.0.1:5555")]
    pub endpoint: String,
    /// Print JSON.
    #[arg(long, global = true)]
    pub json: bool,
}

#[derive(Subcommand)]
pub enum JobsCommand {
    /// Every job the broker stores.
    List,
    /// One job's state and progress.
    Status {
        /// The job's id (`paddock jobs list`).
        job_id: String,
    },
    /// Wait for a job to end, with a progress bar; prints its final state.
    Wait {
        /// The job's id (`paddock jobs list`).
        job_id: String,
    },
    /// Cancel a queued or running job.
    Cancel {
        /// The job's id (`paddock jobs list`).
        job_id: String,
    },
    /// A finished job's result document.
    Result {
        /// The job's id (`paddock jobs list`).
        job_id: String,
    },
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
    Ok(Some(Security {
        keys,
        client_keys: dir(&args.client_keys, "--client-keys")?,
        worker_keys: dir(&args.worker_keys, "--worker-keys")?,
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
    cfg.maps = paddock_proto::convert::shipped_bundles();
    let secured = cfg.security.is_some();
    let mut broker = Broker::bind(cfg).context("starting the broker")?;
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

pub fn worker(args: &WorkerArgs) -> Result<()> {
    let mut cfg = WorkerConfig::new(&args.connect);
    cfg.threads = args.threads;
    cfg.curve = crate::remote::security();
    cfg.health_file = args.health_file.clone();
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

/// Asks a broker for its status.
pub fn fetch_status(remote: &mut Remote) -> Result<paddock_proto::BrokerStatus> {
    let endpoint = remote.endpoint.clone();
    let client = remote.client();
    client.timeout = REQUEST_TIMEOUT;
    match client
        .request(Body::StatusRequest(paddock_proto::StatusRequest {}))
        .map_err(|e| anyhow!("status of the broker at {endpoint}: {e}"))?
    {
        Body::BrokerStatus(s) => Ok(s),
        other => bail!(
            "the broker answered a status request with {}",
            paddock_proto::body_name(&other)
        ),
    }
}

pub fn serve(args: &ServeArgs) -> Result<()> {
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
    let broker =
        BrokerThread::start_in(&args.bind, "tcp://127.0.0.1:0", &state, ctx.clone(), &local)?;
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
    let mut workers = Vec::with_capacity(args.workers);
    for _ in 0..args.workers {
        let mut cfg = WorkerConfig::new(&local);
        cfg.threads = threads;
        cfg.maps_dir = maps.clone();
        cfg.vehicle = vehicle.clone();
        workers.push(WorkerThread::spawn_in(cfg, ctx.clone()).context("starting a worker")?);
    }
    let mut remote = Remote::connect(&front)?;
    wait_for_workers(&mut remote, args.workers, Duration::from_secs(30))?;
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
    ) -> Result<Self> {
        let mut cfg = BrokerConfig::new(bind, backend, state);
        cfg.local_backend = Some(local.to_string());
        Self::spawn(cfg, ctx)
    }

    fn spawn(mut cfg: BrokerConfig, ctx: paddock_broker::zmq::Context) -> Result<Self> {
        cfg.maps = paddock_proto::convert::shipped_bundles();
        let (tx, rx) = std::sync::mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("paddock-broker".into())
            .spawn(move || -> Result<()> {
                let mut broker = match Broker::bind_in(cfg, ctx) {
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

/// Waits until the broker has at least `n` workers.
pub fn wait_for_workers(remote: &mut Remote, n: usize, within: Duration) -> Result<()> {
    let deadline = Instant::now() + within;
    loop {
        let s = fetch_status(remote)?;
        if s.workers.len() >= n {
            return Ok(());
        }
        if Instant::now() > deadline {
            bail!(
                "only {} of {n} workers registered within {within:?}",
                s.workers.len()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn status_json(s: &paddock_proto::BrokerStatus) -> serde_json::Value {
    serde_json::json!({
        "version": s.version,
        "uptime_s": s.uptime_s,
        "workers": s.workers.iter().map(|w| serde_json::json!({
            "worker_id": w.worker_id,
            "hostname": w.hostname,
            "capacity": w.capacity,
            "in_flight": w.in_flight,
            "tasks_done": w.tasks_done,
            "last_seen_s": w.last_seen_s,
            "env_sessions": w.env_sessions,
        })).collect::<Vec<_>>(),
        "queue_depth": s.queue_depth,
        "tasks_in_flight": s.tasks_in_flight,
        "tasks_per_s": s.tasks_per_s,
        "tasks_done": s.tasks_done,
        "jobs_running": s.jobs_running,
        "env_sessions": s.env_sessions,
        "sessions_replayed": s.sessions_replayed,
        "sessions_lost": s.sessions_lost,
        "errors": s.errors,
    })
}

pub fn status(args: &StatusArgs) -> Result<()> {
    let mut remote = Remote::connect(&args.endpoint)?;
    let s = fetch_status(&mut remote)?;
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&status_json(&s))?);
        return Ok(());
    }
    outln!(
        "broker {} at {}: up {:.0} s, {} workers alive, queue {}, in flight {}, {:.1} tasks/s, {} tasks done, {} jobs running, {} env sessions",
        s.version,
        args.endpoint,
        s.uptime_s,
        s.workers.len(),
        s.queue_depth,
        s.tasks_in_flight,
        s.tasks_per_s,
        s.tasks_done,
        s.jobs_running,
        s.env_sessions
    );
    for w in &s.workers {
        outln!(
            "  {:<36} {:<16} capacity {:>3}  in flight {:>3}  done {:>7}  seen {:.1} s ago",
            w.worker_id,
            w.hostname,
            w.capacity,
            w.in_flight,
            w.tasks_done,
            w.last_seen_s
        );
    }
    if s.sessions_replayed + s.sessions_lost > 0 {
        outln!(
            "  env sessions whose worker died: {} rebuilt on another worker, {} lost",
            s.sessions_replayed,
            s.sessions_lost
        );
    }
    if !s.errors.is_empty() {
        let errs: Vec<String> = s.errors.iter().map(|(k, v)| format!("{k} {v}")).collect();
        outln!("  refused requests: {}", errs.join(", "));
    }
    Ok(())
}

pub fn state_name(state: i32) -> &'static str {
    match JobState::try_from(state) {
        Ok(JobState::Queued) => "queued",
        Ok(JobState::Running) => "running",
        Ok(JobState::Succeeded) => "succeeded",
        Ok(JobState::Failed) => "failed",
        Ok(JobState::CancelledJob) => "cancelled",
        _ => "unknown",
    }
}

pub fn is_finished(state: i32) -> bool {
    matches!(
        JobState::try_from(state),
        Ok(JobState::Succeeded | JobState::Failed | JobState::CancelledJob)
    )
}

pub fn info_json(i: &JobInfo) -> serde_json::Value {
    let progress: serde_json::Value = if i.progress_json.is_empty() {
        serde_json::Value::Null
    } else {
        serde_json::from_str(&i.progress_json)
            .unwrap_or_else(|_| serde_json::Value::String(i.progress_json.clone()))
    };
    serde_json::json!({
        "job_id": i.job_id,
        "name": i.name,
        "kind": i.kind,
        "state": state_name(i.state),
        "rounds_done": i.rounds_done,
        "rounds_total": i.rounds_total,
        "episodes_done": i.episodes_done,
        "progress": progress,
        "error": if i.error.is_empty() { None } else { Some(&i.error) },
        "created_at": i.created_at,
        "updated_at": i.updated_at,
    })
}

fn info_line(i: &JobInfo) -> String {
    format!(
        "{:<24} {:<10} {:<10} {:>4}/{:<4} rounds {:>8} episodes  {}{}",
        i.job_id,
        i.kind,
        state_name(i.state),
        i.rounds_done,
        i.rounds_total,
        i.episodes_done,
        i.name,
        if i.error.is_empty() {
            String::new()
        } else {
            format!("  error: {}", i.error)
        }
    )
}

fn request(remote: &mut Remote, body: Body) -> Result<Body> {
    let endpoint = remote.endpoint.clone();
    let client = remote.client();
    client.timeout = REQUEST_TIMEOUT;
    client
        .request(body)
        .map_err(|e| anyhow!("broker at {endpoint}: {e}"))
}

/// One job's info.
pub fn job_status(remote: &mut Remote, job_id: &str) -> Result<JobInfo> {
    match request(
        remote,
        Body::JobStatus(paddock_proto::JobStatusRequest {
            job_id: job_id.into(),
        }),
    )? {
        Body::JobInfo(i) => Ok(i),
        other => bail!("unexpected reply {}", paddock_proto::body_name(&other)),
    }
}

/// Waits until the job ends, calling `on_info` with every new state. Polls, so it
/// rides out a broker restart (the socket reconnects; the job resumes from its store).
pub fn wait_job(
    remote: &mut Remote,
    job_id: &str,
    mut on_info: impl FnMut(&JobInfo),
) -> Result<JobInfo> {
    let mut failures = 0;
    loop {
        match job_status(remote, job_id) {
            Ok(i) => {
                failures = 0;
                on_info(&i);
                if is_finished(i.state) {
                    return Ok(i);
                }
            }
            // the broker may be restarting: keep asking for a while
            Err(e) if failures < 30 && format!("{e:#}").contains("no reply") => {
                failures += 1;
                tracing::warn!(error = %e, "broker did not answer; retrying");
            }
            Err(e) => return Err(e),
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// A finished job's result.
pub fn job_result(remote: &mut Remote, job_id: &str) -> Result<paddock_proto::JobResult> {
    match request(
        remote,
        Body::JobResultRequest(paddock_proto::JobResultRequest {
            job_id: job_id.into(),
        }),
    )? {
        Body::JobResult(r) => Ok(r),
        other => bail!("unexpected reply {}", paddock_proto::body_name(&other)),
    }
}

pub fn jobs(args: &JobsArgs) -> Result<()> {
    let mut remote = Remote::connect(&args.endpoint)?;
    match &args.command {
        JobsCommand::List => {
            let Body::JobListing(l) =
                request(&mut remote, Body::JobList(paddock_proto::JobListRequest {}))?
            else {
                bail!("unexpected reply to job_list");
            };
            if args.json {
                let v: Vec<_> = l.jobs.iter().map(info_json).collect();
                outln!("{}", serde_json::to_string_pretty(&v)?);
            } else if l.jobs.is_empty() {
                outln!("no jobs");
            } else {
                for j in &l.jobs {
                    outln!("{}", info_line(j));
                }
            }
        }
        JobsCommand::Status { job_id } => {
            let i = job_status(&mut remote, job_id)?;
            if args.json {
                outln!("{}", serde_json::to_string_pretty(&info_json(&i))?);
            } else {
                outln!("{}", info_line(&i));
            }
        }
        JobsCommand::Wait { job_id } => {
            let bar = indicatif::ProgressBar::new(1);
            bar.set_style(
                indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} rounds")
                    .expect("valid template")
                    .progress_chars("=> "),
            );
            let i = wait_job(&mut remote, job_id, |i| {
                bar.set_length(i.rounds_total.max(1).into());
                bar.set_position(i.rounds_done.into());
                bar.set_message(format!("{} {}", i.job_id, state_name(i.state)));
            })?;
            bar.finish_and_clear();
            if args.json {
                outln!("{}", serde_json::to_string_pretty(&info_json(&i))?);
            } else {
                outln!("{}", info_line(&i));
            }
            if i.state != JobState::Succeeded as i32 {
                bail!("job {} ended {}", i.job_id, state_name(i.state));
            }
        }
        JobsCommand::Cancel { job_id } => {
            let Body::JobInfo(i) = request(
                &mut remote,
                Body::JobCancel(paddock_proto::JobCancel {
                    job_id: job_id.clone(),
                }),
            )?
            else {
                bail!("unexpected reply to job_cancel");
            };
            if args.json {
                outln!("{}", serde_json::to_string_pretty(&info_json(&i))?);
            } else {
                outln!("{}", info_line(&i));
            }
        }
        JobsCommand::Result { job_id } => {
            let r = job_result(&mut remote, job_id)?;
            let info = r.info.as_ref().context("the job result has no info")?;
            if !is_finished(info.state) {
                bail!(
                    "job {job_id} is {} ({}/{} rounds): no result yet",
                    state_name(info.state),
                    info.rounds_done,
                    info.rounds_total
                );
            }
            if r.result_json.is_empty() {
                if args.json {
                    outln!("{}", serde_json::to_string_pretty(&info_json(info))?);
                } else {
                    outln!("{}", info_line(info));
                }
            } else {
                let doc: serde_json::Value = serde_json::from_str(&r.result_json)
                    .context("the job's result document is not JSON")?;
                outln!("{}", serde_json::to_string_pretty(&doc)?);
            }
        }
    }
    Ok(())
}

/// `paddock tune --endpoint`: the same tuning job run by the broker. Submits it,
/// follows it with a progress bar (or, with `--detach`, prints the job id and returns)
/// and prints the same report as a local run.
pub fn tune_remote(args: &crate::tune_cmd::TuneArgs, endpoint: &str, detach: bool) -> Result<()> {
    let (spec, base, circuit) = crate::tune_cmd::setup(args)?;
    let vehicle = &base.agents[0].vehicle;
    let map = args
        .map
        .clone()
        .unwrap_or_else(|| paddock_sim::track::DEFAULT_MAP.into());
    let mut remote = Remote::connect(endpoint)?;
    fetch_status(&mut remote).with_context(|| format!("no broker answering at {endpoint}"))?;
    let bundle = remote.put_map(&map)?;
    let submit = paddock_proto::JobSubmit {
        name: format!("tune {} on {}", spec.driver, circuit.name),
        spec: Some(paddock_proto::job_submit::Spec::Tune(
            paddock_proto::TuneSpec {
                map: Some(paddock_proto::convert::map_ref(&bundle)),
                driver: spec.driver.clone(),
                generations: spec.generations,
                popsize: u32::try_from(spec.popsize).context("--popsize is too large")?,
                seeds: u32::try_from(spec.seeds).context("--seeds is too large")?,
                holdout: u32::try_from(spec.holdout).context("--holdout is too large")?,
                seed: spec.seed,
                crash_penalty: spec.crash_penalty,
                // the default vehicle travels as nothing
                vehicle_yaml: if *vehicle == paddock_sim::params::VehicleParams::default() {
                    String::new()
                } else {
                    vehicle.to_yaml_string()
                },
            },
        )),
    };
    let started = Instant::now();
    let Body::JobInfo(info) = request(&mut remote, Body::JobSubmit(submit))? else {
        bail!("unexpected reply to job_submit");
    };
    if detach {
        outln!("{}", info.job_id);
        return Ok(());
    }
    let bar = indicatif::ProgressBar::new(info.rounds_total.max(1).into());
    bar.set_style(
        indicatif::ProgressStyle::with_template("tune {pos}/{len} [{bar:25}] {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let done = wait_job(&mut remote, &info.job_id, |i| {
        bar.set_length(i.rounds_total.max(1).into());
        bar.set_position(i.rounds_done.into());
        let best = serde_json::from_str::<serde_json::Value>(&i.progress_json)
            .ok()
            .and_then(|p| p["best_so_far"].as_f64());
        bar.set_message(match best {
            Some(b) => format!("{} best {b:.3} s", i.job_id),
            None => i.job_id.clone(),
        });
    })?;
    bar.finish_and_clear();
    if done.state != JobState::Succeeded as i32 {
        bail!(
            "tuning job {} ended {}: {}",
            done.job_id,
            state_name(done.state),
            done.error
        );
    }
    let r = job_result(&mut remote, &done.job_id)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let result: paddock_rollout::tune_job::TuneResult = serde_json::from_str(&r.result_json)
        .context("the broker's tuning result does not parse")?;
    let total_s = started.elapsed().as_secs_f64();
    crate::tune_cmd::report(
        args,
        &circuit,
        &result,
        crate::tune_cmd::Timing {
            tuning_s: total_s,
            tuning_episodes: result.episodes_run,
            total_s,
        },
    )
}
