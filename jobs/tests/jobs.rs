//! Jobs through the real broker: stored after every round, resumed by a new broker on
//! the same state directory, with the same result as a local run.

mod common;

use std::sync::atomic::Ordering;
use std::time::Duration;

use common::*;
use paddock_proto::{Body, ErrorCode, JobState, job_submit};
use paddock_rollout::tune_job::{TuneJob, TuneSpec};
use paddock_rollout::{EpisodeResult, Executor, LocalExecutor, Scenario};

const T: Duration = Duration::from_secs(120);

fn tune_submit(map: &paddock_proto::MapRef) -> paddock_proto::JobSubmit {
    paddock_proto::JobSubmit {
        name: "small tune".into(),
        spec: Some(job_submit::Spec::Tune(paddock_proto::TuneSpec {
            map: Some(map.clone()),
            driver: "pure-pursuit".into(),
            generations: 2,
            popsize: 4,
            seeds: 2,
            holdout: 2,
            seed: 3,
            crash_penalty: 100.0,
            vehicle_yaml: String::new(),
        })),
    }
}

/// The same job run locally the way `paddock tune` sets it up.
fn tune_locally() -> String {
    let circuit = paddock_sim::circuit::Circuits::new()
        .get("lakeside")
        .unwrap();
    let spec = TuneSpec {
        driver: "pure-pursuit".into(),
        generations: 2,
        popsize: 4,
        seeds: 2,
        holdout: 2,
        seed: 3,
        crash_penalty: 100.0,
    };
    let mut base = Scenario::single("pure-pursuit").unwrap();
    base.map = "lakeside".into();
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * circuit.track.length();
    let mut job = TuneJob::new(spec, base, circuit.track.length()).unwrap();
    let exec = LocalExecutor::new(2, paddock_sim::circuit::Circuits::new()).unwrap();
    while let Some(tasks) = job.next_round().unwrap() {
        let r: Vec<EpisodeResult> = exec
            .run_batch(&tasks, &|_| {})
            .into_iter()
            .map(|r| r.unwrap())
            .collect();
        job.tell(&r).unwrap();
    }
    serde_json::to_string(job.result().unwrap()).unwrap()
}

fn info(body: Body) -> paddock_proto::JobInfo {
    match body {
        Body::JobInfo(i) => i,
        other => panic!("expected job_info, got {other:?}"),
    }
}

/// A job's result and its outcome frames, decoded.
fn result(
    c: &RawPeer,
    rid: u64,
    id: &str,
) -> (paddock_proto::JobResult, Vec<paddock_proto::TaskOutcome>) {
    c.send(
        rid,
        Body::JobResultRequest(paddock_proto::JobResultRequest { job_id: id.into() }),
    );
    match c.reply_frames_to(rid, T) {
        (Body::JobResult(r), frames) => {
            assert_eq!(r.outcomes as usize, frames.len());
            let outcomes = frames.iter().map(|f| decode_outcome(f)).collect();
            (r, outcomes)
        }
        other => panic!("expected job_result, got {other:?}"),
    }
}

#[test]
fn a_tune_job_survives_a_broker_restart_and_ends_as_a_local_run() {
    let state = tempfile::tempdir().unwrap();
    let cache = tempfile::tempdir().unwrap();
    let local = std::thread::spawn(tune_locally);

    let mut first = TestBroker::start(state.path().into(), |_| {});
    let c = RawPeer::connect(&first.frontend);
    let map = put_lakeside(&c);
    let w1 = TestWorker::spawn(
        &first.backend,
        WorkerOpts::default(),
        cache.path().join("1"),
    );
    c.send(1, Body::JobSubmit(tune_submit(&map)));
    let submitted = info(c.reply_to(1, T));
    assert_eq!(submitted.state, JobState::Queued as i32);
    assert_eq!(submitted.kind, "tune");
    let id = submitted.job_id.clone();
    c.send(
        2,
        Body::JobWatch(paddock_proto::JobWatch { job_id: id.clone() }),
    );
    // the watch answers now, then after every round: stop after the first round
    loop {
        let i = info(c.reply_to(2, T));
        if i.rounds_done >= 1 {
            assert_eq!(i.state, JobState::Running as i32);
            assert_eq!(i.rounds_total, 4);
            break;
        }
    }
    first.shutdown();
    drop(w1);
    drop(c);

    let second = TestBroker::start(state.path().into(), |_| {});
    let c = RawPeer::connect(&second.frontend);
    c.send(
        3,
        Body::JobStatus(paddock_proto::JobStatusRequest { job_id: id.clone() }),
    );
    let resumed = info(c.reply_to(3, T));
    assert!(
        resumed.rounds_done >= 1,
        "resumed from round {}",
        resumed.rounds_done
    );
    let w2 = TestWorker::spawn(
        &second.backend,
        WorkerOpts::default(),
        cache.path().join("2"),
    );
    c.send(
        4,
        Body::JobWatch(paddock_proto::JobWatch { job_id: id.clone() }),
    );
    loop {
        let i = info(c.reply_to(4, T));
        if i.state == JobState::Succeeded as i32 {
            assert_eq!(i.rounds_done, 4);
            assert_eq!(i.episodes_done, 28);
            break;
        }
        assert_eq!(i.state, JobState::Running as i32, "{i:?}");
    }
    // only the rounds after the stored one ran again
    let rerun = w2.stats.received.load(Ordering::Relaxed);
    assert!(rerun <= 28 - 8, "the new broker ran {rerun} of 28 episodes");
    let (r, _) = result(&c, 5, &id);
    assert_eq!(
        r.result_json,
        local.join().unwrap(),
        "remote tune == local tune"
    );

    // a finished job stays listed with its result after another restart
    drop(second);
    let third = TestBroker::start(state.path().into(), |_| {});
    let c = RawPeer::connect(&third.frontend);
    c.send(6, Body::JobList(paddock_proto::JobListRequest {}));
    match c.reply_to(6, T) {
        Body::JobListing(l) => {
            assert_eq!(l.jobs.len(), 1);
            assert_eq!(l.jobs[0].state, JobState::Succeeded as i32);
        }
        other => panic!("expected job_listing, got {other:?}"),
    }
    assert!(!result(&c, 7, &id).0.result_json.is_empty());
}

#[test]
fn rollout_and_benchmark_jobs_reduce_like_local_runs_and_jobs_cancel() {
    let state = tempfile::tempdir().unwrap();
    let cache = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(state.path().into(), |_| {});
    let c = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&c);

    // a bad job is refused naming the field
    let mut bad = tune_submit(&map);
    if let Some(job_submit::Spec::Tune(t)) = &mut bad.spec {
        t.crash_penalty = f64::NAN;
    }
    c.send(1, Body::JobSubmit(bad));
    let e = expect_error(c.reply_to(1, T));
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
    assert_eq!(e.field, "job_submit.tune.crash_penalty");
    // so is a bad vehicle, naming its key and value
    let mut bad = tune_submit(&map);
    if let Some(job_submit::Spec::Tune(t)) = &mut bad.spec {
        t.vehicle_yaml = "m: -2.5\n".into();
    }
    c.send(1, Body::JobSubmit(bad));
    let e = expect_error(c.reply_to(1, T));
    assert_eq!(e.field, "job_submit.tune.vehicle_yaml.m");
    assert!(e.message.contains("-2.5"), "{}", e.message);

    // no worker yet: a job waits queued and can be cancelled
    c.send(2, Body::JobSubmit(tune_submit(&map)));
    let doomed = info(c.reply_to(2, T)).job_id;
    c.send(
        3,
        Body::JobCancel(paddock_proto::JobCancel {
            job_id: doomed.clone(),
        }),
    );
    assert_eq!(info(c.reply_to(3, T)).state, JobState::CancelledJob as i32);

    let b = batch(&map, 5, 11, 1.0);
    c.send(
        4,
        Body::JobSubmit(paddock_proto::JobSubmit {
            name: "rollouts".into(),
            spec: Some(job_submit::Spec::Rollouts(b.clone())),
        }),
    );
    let rollouts = info(c.reply_to(4, T)).job_id;
    let bench = paddock_proto::BenchmarkSpec {
        task: "b1".into(),
        map: Some(map.clone()),
        driver: Some(paddock_proto::AgentSpec {
            driver: "pure-pursuit".into(),
            params: paddock_rollout::AgentSpec::with_defaults("pure-pursuit")
                .unwrap()
                .params,
            vehicle_yaml: String::new(),
        }),
        opponent: None,
        episodes: 3,
        seed: 5,
        laps: 1,
        obstacles: 0,
        time_limit: 20.0,
    };
    c.send(
        5,
        Body::JobSubmit(paddock_proto::JobSubmit {
            name: "bench".into(),
            spec: Some(job_submit::Spec::Benchmark(bench)),
        }),
    );
    let benchmark = info(c.reply_to(5, T)).job_id;
    let _w = TestWorker::spawn(&broker.backend, WorkerOpts::default(), cache.path().into());
    for (rid, id) in [(6, &rollouts), (7, &benchmark)] {
        c.send(
            rid,
            Body::JobWatch(paddock_proto::JobWatch { job_id: id.clone() }),
        );
        while info(c.reply_to(rid, T)).state != JobState::Succeeded as i32 {}
    }
    let (_, outcomes) = result(&c, 8, &rollouts);
    assert_eq!(outcomes, run_locally(&b));

    let spec = paddock_rollout::benchmark::BenchmarkSpec {
        task: paddock_rollout::benchmark::Task::B1,
        map: "lakeside".into(),
        driver: paddock_rollout::AgentSpec::with_defaults("pure-pursuit").unwrap(),
        opponent: None,
        episodes: 3,
        seed: 5,
        laps: 1,
        obstacles: 8,
        time_limit: 20.0,
    };
    let results = LocalExecutor::new(1, paddock_sim::circuit::Circuits::new())
        .unwrap()
        .run_batch(&spec.tasks().unwrap(), &|_| {});
    let local =
        serde_json::to_string(&paddock_rollout::benchmark::report(&spec, &results)).unwrap();
    assert_eq!(result(&c, 9, &benchmark).0.result_json, local);

    c.send(10, Body::JobList(paddock_proto::JobListRequest {}));
    match c.reply_to(10, T) {
        Body::JobListing(l) => {
            let states: Vec<i32> = l.jobs.iter().map(|j| j.state).collect();
            assert_eq!(
                states,
                [
                    JobState::CancelledJob as i32,
                    JobState::Succeeded as i32,
                    JobState::Succeeded as i32
                ]
            );
        }
        other => panic!("expected job_listing, got {other:?}"),
    }
}
