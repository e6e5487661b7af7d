//! Talking to a broker: [`Remote`] (a connection with the maps this client has read,
//! requests with timeouts) and [`RemoteExecutor`], the one [`Executor`] that runs batches
//! through a broker. It implements the same trait as the local pool, so `rollout`,
//! `benchmark` and `tune` do not care where their episodes run, and get the same results
//! bit for bit.
//!
//! A batch goes out as one `RolloutBatch` (each distinct scenario encoded once, maps
//! named by content hash); its result comes back as one frame per task, decoded here
//! through `paddock-wire`. When the broker answers NOT_FOUND for a map hash, the client
//! stores its maps there with `PutMap` and sends the batch again. A batch outlives a
//! restart of the broker (sent again when another broker instance answers); a broker
//! that does not answer ends it with a transport error, never a scenario error.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use paddock_broker::client::{Client, ClientError, Received, ResumePolicy};
use paddock_libzmq::Curve;
use paddock_proto::{Body, ErrorCode, MapBundle};
use paddock_rollout::{EpisodeResult, EpisodeTask, Executor, RolloutError};
use paddock_sim::circuit::Circuits;
use paddock_wire::{
    batch_to_proto, local_map, map_ref, outcome_from_bytes, rollout_error_from_proto,
};

/// How long a single request (status, job queries) waits for its reply.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);

/// A connection to a broker with the map bundles this client has read.
pub struct Remote {
    pub endpoint: String,
    client: Client,
    /// Where map names are looked up (`PADDOCK_MAPS`, then the shipped maps).
    pub circuits: Circuits,
    maps: HashMap<String, MapBundle>,
    stored: std::collections::HashSet<String>,
    /// How a batch watches the broker (how soon one that does not answer is given up).
    pub resume: ResumePolicy,
}

/// The CURVE keys every client connection of this process uses (set once by `main`
/// from `--key` / `--broker-key`); plain TCP when unset.
static SECURITY: std::sync::OnceLock<Curve> = std::sync::OnceLock::new();

/// Sets the client keys for this process's broker connections.
pub fn set_security(curve: Curve) {
    let _ = SECURITY.set(curve);
}

pub fn security() -> Curve {
    SECURITY.get().cloned().unwrap_or_default()
}

impl Remote {
    /// A connection to the broker at `endpoint`; maps named in requests are found in
    /// `circuits`.
    pub fn connect(endpoint: &str, circuits: &Circuits) -> Result<Self> {
        // the client carries this user's token: its jobs and sessions are this user's on a
        // broker without CURVE too
        let client = Client::connect_with(endpoint, &security())
            .with_context(|| format!("connecting to the broker at {endpoint}"))?;
        Ok(Self {
            endpoint: endpoint.to_string(),
            client,
            circuits: circuits.clone(),
            maps: HashMap::new(),
            stored: Default::default(),
            resume: ResumePolicy {
                answer_within: REQUEST_TIMEOUT,
                ..ResumePolicy::default()
            },
        })
    }

    /// One request and its reply's body, within [`REQUEST_TIMEOUT`].
    pub fn request(&mut self, body: Body) -> Result<Body> {
        self.request_frames(body).map(|r| r.body)
    }

    /// One request and its whole reply (body and payload frames), within
    /// [`REQUEST_TIMEOUT`].
    pub fn request_frames(&mut self, body: Body) -> Result<Received> {
        let endpoint = self.endpoint.clone();
        self.client.timeout = REQUEST_TIMEOUT;
        self.client
            .request_with(body, Vec::new(), |_| {})
            .map_err(|e| anyhow!("broker at {endpoint}: {e}"))
    }

    /// The broker's status.
    pub fn status(&mut self) -> Result<paddock_proto::BrokerStatus> {
        match self.request(Body::StatusRequest(paddock_proto::StatusRequest {}))? {
            Body::BrokerStatus(s) => Ok(s),
            other => bail!(
                "the broker answered a status request with {}",
                paddock_proto::body_name(&other)
            ),
        }
    }

    /// Waits until the broker has at least `n` workers.
    pub fn wait_for_workers(&mut self, n: usize, within: Duration) -> Result<()> {
        let deadline = Instant::now() + within;
        loop {
            let s = self.status()?;
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

    /// The bundle of a map name or directory (read once).
    pub fn bundle(&mut self, map: &str) -> Result<MapBundle> {
        if let Some(b) = self.maps.get(map) {
            return Ok(b.clone());
        }
        let b =
            local_map(&self.circuits, map).map_err(|e| anyhow!("map {map:?}: {}", e.message))?;
        self.maps.insert(map.to_string(), b.clone());
        Ok(b)
    }

    /// Stores a map in the broker (once per connection).
    pub fn put_map(&mut self, map: &str) -> Result<MapBundle> {
        let b = self.bundle(map)?;
        if !self.stored.contains(&b.hash) {
            self.client.put_map(b.clone()).map_err(|e| {
                anyhow!(
                    "storing map {map:?} in the broker at {}: {e}",
                    self.endpoint
                )
            })?;
            self.stored.insert(b.hash.clone());
        }
        Ok(b)
    }

    /// Stores an ONNX model in the broker (once per connection), so that workers fetch
    /// it by its hash when a scenario names it (`onnx:<hash>`).
    pub fn put_model(&mut self, model: &paddock_policy::OnnxModel) -> Result<()> {
        if self.stored.contains(model.hash()) {
            return Ok(());
        }
        let hash = self.client.put_blob(model.bytes().to_vec()).map_err(|e| {
            anyhow!(
                "storing model {} in the broker at {}: {e}",
                model.label(),
                self.endpoint
            )
        })?;
        if hash != model.hash() {
            bail!(
                "the broker at {} stored model {} under hash {hash}, not {}",
                self.endpoint,
                model.label(),
                model.hash()
            );
        }
        self.stored.insert(hash);
        Ok(())
    }

    /// Runs a batch and returns its outcomes in task order. The batch survives a
    /// restart of the broker (it is sent again: [`Client::request_resumable`]); a broker
    /// that does not answer, or a reply that makes no sense, is a
    /// [`RolloutError::Transport`], a refusal by the broker the error it names.
    pub fn run_batch(
        &mut self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<Result<EpisodeResult, RolloutError>>, RolloutError> {
        if tasks.is_empty() {
            return Ok(Vec::new());
        }
        let mut refs = HashMap::new();
        for t in tasks {
            let m = &t.scenario.map;
            if !refs.contains_key(m) {
                let bundle = self
                    .bundle(m)
                    .map_err(|e| RolloutError::invalid("map", m, &format!("{e:#}")))?;
                refs.insert(m.clone(), map_ref(&bundle));
            }
        }
        let batch = batch_to_proto(tasks, |m| refs[m].clone(), true);
        let transport = |endpoint: &str, reason: String| RolloutError::Transport {
            endpoint: endpoint.to_string(),
            reason,
        };
        let mut put_done = false;
        loop {
            let policy = self.resume;
            let reply =
                self.client
                    .request_resumable(Body::RolloutBatch(batch.clone()), &policy, |b| {
                        if let Body::RolloutProgress(p) = b {
                            progress(p.done as usize);
                        }
                    });
            match reply {
                Ok(Received {
                    body: Body::RolloutResult(r),
                    payload,
                    ..
                }) => {
                    if r.outcomes as usize != tasks.len() || payload.len() != tasks.len() {
                        return Err(transport(
                            &self.endpoint,
                            format!(
                                "the broker returned {} outcomes for {} tasks",
                                payload.len(),
                                tasks.len()
                            ),
                        ));
                    }
                    progress(tasks.len());
                    return Ok(payload.iter().map(|o| outcome_from_bytes(o)).collect());
                }
                Ok(other) => {
                    return Err(transport(
                        &self.endpoint,
                        format!(
                            "the broker answered a rollout batch with {}",
                            paddock_proto::body_name(&other.body)
                        ),
                    ));
                }
                Err(e) if e.code() == Some(ErrorCode::NotFound) && !put_done => {
                    // the broker lacks a map (a broker restarted without its state
                    // holds none of ours): store ours and send the batch again
                    put_done = true;
                    self.stored.clear();
                    let names: Vec<String> = refs.keys().cloned().collect();
                    for m in names {
                        self.put_map(&m)
                            .map_err(|e| transport(&self.endpoint, format!("{e:#}")))?;
                    }
                }
                Err(ClientError::Remote(e)) => return Err(rollout_error_from_proto(&e)),
                Err(e) => return Err(transport(&self.endpoint, format!("rollout batch: {e}"))),
            }
        }
    }
}

/// The same error again, for every task of a batch that failed as a whole.
fn batch_error(e: &RolloutError) -> RolloutError {
    match e {
        RolloutError::Transport { endpoint, reason } => RolloutError::Transport {
            endpoint: endpoint.clone(),
            reason: reason.clone(),
        },
        RolloutError::Invalid {
            field,
            value,
            reason,
        } => RolloutError::Invalid {
            field: field.clone(),
            value: value.clone(),
            reason: reason.clone(),
        },
        other => RolloutError::invalid("rollout_batch", "", &other.to_string()),
    }
}

/// An [`Executor`] that runs batches through a broker.
pub struct RemoteExecutor {
    remote: Mutex<Remote>,
}

impl RemoteExecutor {
    pub fn connect(endpoint: &str, circuits: &Circuits) -> Result<Self> {
        Ok(Self {
            remote: Mutex::new(Remote::connect(endpoint, circuits)?),
        })
    }
}

/// Bytes of results one batch through a broker brings back at most: half the broker's
/// message limit, so a batch never comes near it.
const BATCH_RESULT_BYTES: u64 = (paddock_proto::MAX_MESSAGE_BYTES / 2) as u64;

/// The most bytes a task's outcome can take (the bound the broker checks before any
/// work; see `paddock_broker::TaskBudget`).
fn result_bytes(t: &EpisodeTask) -> u64 {
    let s = &t.scenario;
    paddock_jobs::episode_budget(s.time_limit, s.agents.len(), s.laps)
        .result_bytes(paddock_wire::record_to_proto(t.record))
}

/// Consecutive runs of `tasks` whose results each fit in `limit` bytes (a task larger
/// than `limit` alone: the broker then refuses it with the reason).
fn result_chunks(tasks: &[EpisodeTask], limit: u64) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let (mut start, mut bytes) = (0, 0u64);
    for (i, t) in tasks.iter().enumerate() {
        let b = result_bytes(t);
        if i > start && bytes + b > limit {
            out.push(start..i);
            (start, bytes) = (i, 0);
        }
        bytes += b;
    }
    if start < tasks.len() {
        out.push(start..tasks.len());
    }
    out
}

impl Executor for RemoteExecutor {
    /// Runs the tasks as one batch, or as consecutive batches when their results
    /// (trajectories) would not fit in one message.
    fn run_batch(
        &self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Vec<Result<EpisodeResult, RolloutError>> {
        let mut remote = self.remote.lock().unwrap_or_else(|e| e.into_inner());
        let mut out = Vec::with_capacity(tasks.len());
        for chunk in result_chunks(tasks, BATCH_RESULT_BYTES) {
            let done = chunk.start;
            let part = &tasks[chunk];
            match remote.run_batch(part, &|n| progress(done + n)) {
                Ok(r) => out.extend(r),
                Err(e) => out.extend(part.iter().map(|_| Err(batch_error(&e)))),
            }
        }
        out
    }

    fn parallelism(&self) -> usize {
        let mut remote = self.remote.lock().unwrap_or_else(|e| e.into_inner());
        match remote.status() {
            Ok(s) => s
                .workers
                .iter()
                .map(|w| w.capacity as usize)
                .sum::<usize>()
                .max(1),
            Err(_) => 1,
        }
    }
}

/// The executor for `--endpoint`: the broker there (checked to answer), else a local
/// pool of `threads` (0: one per core). Maps are named in `circuits` (the local pool
/// loads each once from it; a broker gets their files from it).
pub fn executor(
    endpoint: Option<&str>,
    threads: usize,
    circuits: &Circuits,
) -> Result<Box<dyn Executor>> {
    match endpoint {
        None => Ok(Box::new(paddock_rollout::LocalExecutor::new(
            threads,
            circuits.clone(),
        )?)),
        Some(url) => {
            let exec = RemoteExecutor::connect(url, circuits)?;
            {
                let mut remote = exec.remote.lock().unwrap_or_else(|e| e.into_inner());
                remote
                    .status()
                    .with_context(|| format!("no broker answering at {url}"))?;
            }
            Ok(Box::new(exec))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_whose_trajectories_would_not_fit_are_cut_into_runs_that_do() {
        let mut s = paddock_rollout::Scenario::single("pure-pursuit").unwrap();
        s.time_limit = 60.0;
        let s = std::sync::Arc::new(s);
        let task = |record| EpisodeTask {
            scenario: s.clone(),
            seed: 1,
            record,
        };
        // 600 episodes of 60 s with every step recorded: ~290 KB each, ~170 MB in all
        let tasks: Vec<EpisodeTask> = (0..600).map(|_| task(Some(1))).collect();
        let per = result_bytes(&tasks[0]);
        assert!(per > 250_000 && per < 400_000, "{per}");
        let chunks = result_chunks(&tasks, BATCH_RESULT_BYTES);
        assert!(chunks.len() >= 6, "{chunks:?}");
        assert_eq!(chunks.first().unwrap().start, 0);
        assert_eq!(chunks.last().unwrap().end, 600);
        for w in chunks.windows(2) {
            assert_eq!(w[0].end, w[1].start, "consecutive, nothing lost");
        }
        for c in &chunks {
            let bytes: u64 = tasks[c.clone()].iter().map(result_bytes).sum();
            assert!(bytes <= BATCH_RESULT_BYTES, "{c:?}: {bytes}");
        }
        // summaries alone go as one batch
        let small: Vec<EpisodeTask> = (0..10_000).map(|_| task(None)).collect();
        assert_eq!(result_chunks(&small, BATCH_RESULT_BYTES), vec![0..10_000]);
    }
}
