//! The client commands of a cluster: `paddock status`, `paddock jobs` and `paddock tune
//! --endpoint` (a tuning job run and stored by the broker).

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use paddock_proto::{Body, JobInfo, JobState};
use paddock_sim::circuit::Circuits;

use crate::args::outln;
use crate::remote::Remote;

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
    /// This client's jobs the broker stores (an admin key: everyone's), newest last.
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
    /// Delete a job and its result from the broker (a queued or running job is
    /// cancelled first).
    Delete {
        /// The job's id (`paddock jobs list`).
        job_id: String,
    },
}

fn status_json(s: &paddock_proto::BrokerStatus) -> serde_json::Value {
    serde_json::json!({
        "version": s.version,
        "uptime_s": s.uptime_s,
        "instance": s.instance,
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

pub fn status(args: &StatusArgs, circuits: &Circuits) -> Result<()> {
    let mut remote = Remote::connect(&args.endpoint, circuits)?;
    let s = remote.status()?;
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

/// One job's info.
pub fn job_status(remote: &mut Remote, job_id: &str) -> Result<JobInfo> {
    match remote.request(Body::JobStatus(paddock_proto::JobStatusRequest {
        job_id: job_id.into(),
    }))? {
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
    match remote.request(Body::JobResultRequest(paddock_proto::JobResultRequest {
        job_id: job_id.into(),
    }))? {
        Body::JobResult(r) => Ok(r),
        other => bail!("unexpected reply {}", paddock_proto::body_name(&other)),
    }
}

pub fn jobs(args: &JobsArgs, circuits: &Circuits) -> Result<()> {
    let mut remote = Remote::connect(&args.endpoint, circuits)?;
    match &args.command {
        JobsCommand::List => {
            let Body::JobListing(l) =
                remote.request(Body::JobList(paddock_proto::JobListRequest {}))?
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
        JobsCommand::Delete { job_id } => {
            let Body::JobDeleted(d) =
                remote.request(Body::JobDelete(paddock_proto::JobDelete {
                    job_id: job_id.clone(),
                }))?
            else {
                bail!("unexpected reply to job_delete");
            };
            if args.json {
                outln!(
                    "{}",
                    serde_json::json!({ "job_id": d.job_id, "deleted": true })
                );
            } else {
                outln!("{} deleted", d.job_id);
            }
        }
        JobsCommand::Cancel { job_id } => {
            let Body::JobInfo(i) = remote.request(Body::JobCancel(paddock_proto::JobCancel {
                job_id: job_id.clone(),
            }))?
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
pub fn tune_remote(
    args: &crate::tune_cmd::TuneArgs,
    endpoint: &str,
    detach: bool,
    circuits: &Circuits,
) -> Result<()> {
    let (spec, base, circuit) = crate::tune_cmd::setup(args, circuits)?;
    let vehicle = &base.agents[0].vehicle;
    let map = args
        .map
        .clone()
        .unwrap_or_else(|| paddock_sim::circuit::DEFAULT_MAP.into());
    let mut remote = Remote::connect(endpoint, circuits)?;
    remote
        .status()
        .with_context(|| format!("no broker answering at {endpoint}"))?;
    let bundle = remote.put_map(&map)?;
    let submit = paddock_proto::JobSubmit {
        name: format!("tune {} on {}", spec.driver, circuit.name),
        spec: Some(paddock_proto::job_submit::Spec::Tune(
            paddock_proto::TuneSpec {
                map: Some(paddock_wire::map_ref(&bundle)),
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
    let Body::JobInfo(info) = remote.request(Body::JobSubmit(submit))? else {
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
