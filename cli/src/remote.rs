//! Running batches through a broker: [`RemoteExecutor`] implements the same
//! [`Executor`] trait as the local pool, so `rollout`, `benchmark` and `tune` do not
//! care where their episodes run, and get the same results bit for bit.
//!
//! A batch goes out as one `RolloutBatch` (scenarios shared by tasks sent once, maps
//! named by content hash). When the broker answers NOT_FOUND for a map hash, the
//! client stores its maps there with `PutMap` and sends the batch again.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use paddock_broker::client::{Client, ClientError};
use paddock_libzmq::Curve;
use paddock_proto::convert::{batch_to_proto, local_map, map_ref, outcome_from_proto};
use paddock_proto::{Body, ErrorCode, MapBundle};
use paddock_rollout::{EpisodeResult, EpisodeTask, Executor, RolloutError};

/// How long a batch may go without any message from the broker before it is given up.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(600);

/// A connection to a broker with the map bundles this client has read.
pub struct Remote {
    pub endpoint: String,
    client: Client,
    maps: HashMap<String, MapBundle>,
    stored: std::collections::HashSet<String>,
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
    pub fn connect(endpoint: &str) -> Result<Self> {
        let client = Client::connect_with(endpoint, &security())
            .with_context(|| format!("connecting to the broker at {endpoint}"))?;
        Ok(Self {
            endpoint: endpoint.to_string(),
            client,
            maps: HashMap::new(),
            stored: Default::default(),
        })
    }

    /// The client, for single requests; its timeout bounds each reply.
    pub fn client(&mut self) -> &mut Client {
        &mut self.client
    }

    /// The bundle of a map name or directory (read once).
    pub fn bundle(&mut self, map: &str) -> Result<MapBundle> {
        if let Some(b) = self.maps.get(map) {
            return Ok(b.clone());
        }
        let b = local_map(map).map_err(|e| anyhow!("map {map:?}: {}", e.message))?;
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

    /// Sends `request` and waits for its final reply, passing progress and job updates
    /// to `on_update`; gives up after `idle` without any message for it.
    pub fn exchange(
        &mut self,
        request: Body,
        idle: Duration,
        mut on_update: impl FnMut(&Body),
    ) -> Result<Body, ClientError> {
        let id = self.client.send(request)?;
        let mut last = Instant::now();
        loop {
            let left = idle.saturating_sub(last.elapsed());
            if left.is_zero() {
                return Err(ClientError::Timeout(idle));
            }
            let (rid, reply) = match self.client.recv(left.min(Duration::from_millis(500))) {
                Ok(x) => x,
                Err(ClientError::Timeout(_)) => continue,
                Err(e) => return Err(e),
            };
            if rid != id {
                continue;
            }
            last = Instant::now();
            match reply {
                Body::Error(e) => return Err(ClientError::Remote(e)),
                Body::RolloutProgress(_) => on_update(&reply),
                other => return Ok(other),
            }
        }
    }

    /// Runs a batch and returns its outcomes in task order.
    pub fn run_batch(
        &mut self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<Result<EpisodeResult, RolloutError>>> {
        if tasks.is_empty() {
            return Ok(Vec::new());
        }
        let mut maps: Vec<String> = tasks.iter().map(|t| t.scenario.map.clone()).collect();
        maps.dedup();
        let mut refs = HashMap::new();
        for m in &maps {
            if !refs.contains_key(m) {
                refs.insert(m.clone(), map_ref(&self.bundle(m)?));
            }
        }
        let batch = batch_to_proto(tasks, |m| refs[m].clone(), true);
        let mut put_done = false;
        loop {
            let reply = self.exchange(Body::RolloutBatch(batch.clone()), IDLE_TIMEOUT, |b| {
                if let Body::RolloutProgress(p) = b {
                    progress(p.done as usize);
                }
            });
            match reply {
                Ok(Body::RolloutResult(r)) => {
                    if r.outcomes.len() != tasks.len() {
                        bail!(
                            "the broker returned {} outcomes for {} tasks",
                            r.outcomes.len(),
                            tasks.len()
                        );
                    }
                    progress(tasks.len());
                    return Ok(r.outcomes.iter().map(outcome_from_proto).collect());
                }
                Ok(other) => bail!(
                    "the broker answered a rollout batch with {}",
                    paddock_proto::body_name(&other)
                ),
                Err(e) if e.code() == Some(ErrorCode::NotFound) && !put_done => {
                    // the broker lacks a map: store ours and send the batch again
                    put_done = true;
                    let names: Vec<String> = refs.keys().cloned().collect();
                    for m in names {
                        self.put_map(&m)?;
                    }
                }
                Err(e) => {
                    return Err(anyhow!("rollout batch through {}: {e}", self.endpoint));
                }
            }
        }
    }
}

/// An [`Executor`] that runs batches through a broker.
pub struct RemoteExecutor {
    remote: Mutex<Remote>,
    endpoint: String,
}

impl RemoteExecutor {
    pub fn connect(endpoint: &str) -> Result<Self> {
        Ok(Self {
            remote: Mutex::new(Remote::connect(endpoint)?),
            endpoint: endpoint.to_string(),
        })
    }
}

impl Executor for RemoteExecutor {
    fn run_batch(
        &self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Vec<Result<EpisodeResult, RolloutError>> {
        let mut remote = self.remote.lock().unwrap_or_else(|e| e.into_inner());
        match remote.run_batch(tasks, progress) {
            Ok(r) => r,
            Err(e) => tasks
                .iter()
                .map(|_| {
                    Err(RolloutError::Invalid {
                        field: "endpoint".into(),
                        value: self.endpoint.clone(),
                        reason: format!("{e:#}"),
                    })
                })
                .collect(),
        }
    }

    fn parallelism(&self) -> usize {
        let mut remote = self.remote.lock().unwrap_or_else(|e| e.into_inner());
        match remote
            .client()
            .request(Body::StatusRequest(paddock_proto::StatusRequest {}))
        {
            Ok(Body::BrokerStatus(s)) => s
                .workers
                .iter()
                .map(|w| w.capacity as usize)
                .sum::<usize>()
                .max(1),
            _ => 1,
        }
    }
}

/// The executor for `--endpoint`: the broker there (checked to answer), else a local
/// pool of `threads` (0: one per core).
pub fn executor(endpoint: Option<&str>, threads: usize) -> Result<Box<dyn Executor>> {
    match endpoint {
        None => Ok(Box::new(paddock_rollout::LocalExecutor::new(threads)?)),
        Some(url) => {
            let exec = RemoteExecutor::connect(url)?;
            {
                let mut remote = exec.remote.lock().unwrap_or_else(|e| e.into_inner());
                crate::cluster::fetch_status(&mut remote)
                    .with_context(|| format!("no broker answering at {url}"))?;
            }
            Ok(Box::new(exec))
        }
    }
}
