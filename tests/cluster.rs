//! End-to-end tests across real processes: a `paddock broker`, `paddock worker`s and
//! clients on loopback. Results through the broker must equal local results bit for
//! bit, whatever happens to workers and the broker on the way (issue 4, item 6).

use std::sync::Arc;
use std::time::{Duration, Instant};

use paddock_e2e::{Cluster, paddock, serial};
use paddock_proto::{Body, MapBundle};
use paddock_rollout::{EpisodeResult, EpisodeTask, Executor, LocalExecutor, Scenario, task_seed};
use paddock_wire::{batch_to_proto, local_map, map_ref, outcome_from_bytes};

fn tasks(n: usize, time_limit: f64, job_seed: u64) -> Vec<EpisodeTask> {
    driver_tasks("pure-pursuit", n, time_limit, job_seed)
}

/// Follow-the-gap reads the LIDAR, so its episodes take long enough (tens of ms) for a
/// batch to be interrupted mid-way.
fn driver_tasks(driver: &str, n: usize, time_limit: f64, job_seed: u64) -> Vec<EpisodeTask> {
    let mut s = Scenario::single(driver).unwrap();
    s.time_limit = time_limit;
    let s = Arc::new(s);
    (0..n)
        .map(|k| EpisodeTask {
            scenario: s.clone(),
            seed: task_seed(job_seed, k as u64),
            // a few tasks also bring their trajectories back
            record: (k % 50 == 0).then_some(10),
        })
        .collect()
}

fn local(tasks: &[EpisodeTask]) -> Vec<EpisodeResult> {
    LocalExecutor::new(2, paddock_sim::circuit::Circuits::new())
        .unwrap()
        .run_batch(tasks, &|_| {})
        .into_iter()
        .map(|r| r.unwrap())
        .collect()
}

fn bundle() -> MapBundle {
    local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap()
}

/// Runs a batch through the broker; `on_progress` sees every progress report.
fn remote(
    c: &Cluster,
    tasks: &[EpisodeTask],
    mut on_progress: impl FnMut(u32),
) -> Vec<EpisodeResult> {
    let mut client = c.client();
    let b = bundle();
    client.put_map(b.clone()).unwrap();
    let batch = batch_to_proto(tasks, |_| map_ref(&b), true);
    let id = client.send(Body::RolloutBatch(batch)).unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        assert!(
            Instant::now() < deadline,
            "the batch did not finish in 120 s"
        );
        let reply = client.recv(Duration::from_secs(60)).unwrap();
        assert_eq!(reply.request_id, id, "a reply for another request");
        match reply.body {
            Body::RolloutProgress(p) => on_progress(p.done),
            Body::RolloutResult(r) => {
                assert_eq!(r.outcomes as usize, tasks.len());
                return reply
                    .payload
                    .iter()
                    .map(|o| outcome_from_bytes(o).unwrap())
                    .collect();
            }
            other => panic!("unexpected reply {other:?}"),
        }
    }
}

#[test]
fn a_same_batch_on_one_worker_three_workers_and_locally() {
    let _serial = serial();
    let batch = tasks(200, 2.0, 11);
    let expected = local(&batch);
    let mut c = Cluster::start(1, 1);
    let one = remote(&c, &batch, |_| {});
    assert!(one == expected, "1 worker differs from the local run");
    c.add_worker(1);
    c.add_worker(1);
    c.wait_workers(3, Duration::from_secs(20));
    let three = remote(&c, &batch, |_| {});
    assert!(three == expected, "3 workers differ from the local run");
    assert!(expected.iter().any(|e| e.trajectory.is_some()));

    // the CLI: `paddock rollout --endpoint` prints what the local run prints
    let args = [
        "rollout",
        "--episodes",
        "12",
        "--time-limit",
        "2",
        "--seed",
        "4",
        "--json",
    ];
    let here = paddock(&args);
    assert!(
        here.status.success(),
        "{}",
        String::from_utf8_lossy(&here.stderr)
    );
    let mut with_endpoint = args.to_vec();
    with_endpoint.extend(["--endpoint", c.front.as_str()]);
    let there = paddock(&with_endpoint);
    assert!(
        there.status.success(),
        "{}",
        String::from_utf8_lossy(&there.stderr)
    );
    assert_eq!(
        String::from_utf8_lossy(&here.stdout),
        String::from_utf8_lossy(&there.stdout)
    );
}

#[test]
fn b_kill_9_one_of_three_workers_mid_batch() {
    let _serial = serial();
    let batch = driver_tasks("follow-the-gap", 200, 6.0, 12);
    let expected = local(&batch);
    let mut c = Cluster::start(3, 1);
    let mut killed_at = None;
    let results = {
        let workers = &mut c.workers;
        let mut victim = workers.remove(0);
        let r = remote(&c, &batch, |done| {
            if killed_at.is_none() && done >= 10 {
                victim.kill9();
                killed_at = Some(done);
            }
        });
        assert!(!victim.alive());
        r
    };
    let killed_at = killed_at.expect("the batch reported progress before it ended");
    assert!(
        killed_at < 200,
        "the worker was killed before the batch ended"
    );
    assert!(results == expected, "the batch differs after a worker died");
}

#[test]
fn d_sigstopped_worker_is_declared_dead_within_3_s_and_its_tasks_rerun() {
    let _serial = serial();
    let batch = driver_tasks("follow-the-gap", 200, 6.0, 14);
    let expected = local(&batch);
    let c = Cluster::start(2, 1);
    let front = c.front.clone();
    let mut watcher: Option<std::thread::JoinHandle<Option<Duration>>> = None;
    let results = remote(&c, &batch, |done| {
        if watcher.is_none() && done >= 10 {
            c.workers[0].signal("STOP");
            let stopped = Instant::now();
            let front = front.clone();
            // watch with `paddock status --json`, as a user would
            watcher = Some(std::thread::spawn(move || {
                while stopped.elapsed() < Duration::from_secs(10) {
                    let out = paddock(&["status", "--endpoint", &front, "--json"]);
                    let s: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
                    if s["workers"].as_array().map(|w| w.len()) == Some(1) {
                        return Some(stopped.elapsed());
                    }
                }
                None
            }));
        }
    });
    let dead_after = watcher
        .expect("the batch reported progress")
        .join()
        .unwrap()
        .expect("the stopped worker was never declared dead");
    eprintln!("SIGSTOPped worker declared dead after {dead_after:?}");
    // 3 missed 1 s beats, plus the broker's tick and one status round trip
    assert!(
        dead_after <= Duration::from_millis(3500),
        "declared dead after {dead_after:?}"
    );
    assert!(
        results == expected,
        "the batch differs after a worker stopped"
    );
    c.workers[0].signal("CONT");
}

#[test]
fn c_broker_killed_mid_tuning_job_resumes_with_the_same_result() {
    use paddock_rollout::tune_job::{TuneJob, TuneSpec};
    let _serial = serial();
    let spec = TuneSpec {
        driver: "pure-pursuit".into(),
        generations: 5,
        popsize: 6,
        seeds: 2,
        holdout: 2,
        seed: 5,
        crash_penalty: 100.0,
    };
    // the uninterrupted run, locally
    let circuit = paddock_sim::circuit::Circuits::new()
        .get("lakeside")
        .unwrap();
    let mut base = Scenario::single("pure-pursuit").unwrap();
    base.map = "lakeside".into();
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * circuit.track.length();
    let mut job = TuneJob::new(spec.clone(), base, circuit.track.length()).unwrap();
    let exec = LocalExecutor::new(2, paddock_sim::circuit::Circuits::new()).unwrap();
    while let Some(round) = job.next_round().unwrap() {
        let results: Vec<EpisodeResult> = exec
            .run_batch(&round, &|_| {})
            .into_iter()
            .map(|r| r.unwrap())
            .collect();
        job.tell(&results).unwrap();
    }
    let expected = serde_json::to_value(job.result().unwrap()).unwrap();

    let mut c = Cluster::start(1, 2);
    let b = bundle();
    let mut client = c.client();
    client.put_map(b.clone()).unwrap();
    let submit = paddock_proto::JobSubmit {
        name: "e2e tune".into(),
        spec: Some(paddock_proto::job_submit::Spec::Tune(
            paddock_proto::TuneSpec {
                map: Some(map_ref(&b)),
                driver: spec.driver.clone(),
                generations: spec.generations,
                popsize: spec.popsize as u32,
                seeds: spec.seeds as u32,
                holdout: spec.holdout as u32,
                seed: spec.seed,
                crash_penalty: spec.crash_penalty,
                vehicle_yaml: String::new(),
            },
        )),
    };
    let Body::JobInfo(info) = client.request(Body::JobSubmit(submit)).unwrap() else {
        panic!("expected job info");
    };
    let job_id = info.job_id.clone();
    let status = |client: &mut paddock_broker::client::Client| -> Option<paddock_proto::JobInfo> {
        client.timeout = Duration::from_secs(2);
        match client.request(Body::JobStatus(paddock_proto::JobStatusRequest {
            job_id: job_id.clone(),
        })) {
            Ok(Body::JobInfo(i)) => Some(i),
            _ => None,
        }
    };
    // kill -9 the broker once some rounds are stored, before the job ends
    let t0 = Instant::now();
    let killed_at = loop {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the job made no progress"
        );
        if let Some(i) = status(&mut client) {
            assert!(
                i.state != paddock_proto::JobState::Succeeded as i32,
                "the job ended before the broker could be killed: make it longer"
            );
            if i.rounds_done >= 2 {
                c.broker.as_mut().unwrap().kill9();
                break i.rounds_done;
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    c.start_broker();
    let mut client = c.client();
    let t0 = Instant::now();
    let done = loop {
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "the resumed job did not end"
        );
        if let Some(i) = status(&mut client)
            && i.state != paddock_proto::JobState::Running as i32
            && i.state != paddock_proto::JobState::Queued as i32
        {
            break i;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_eq!(
        done.state,
        paddock_proto::JobState::Succeeded as i32,
        "job failed: {}",
        done.error
    );
    assert!(done.rounds_done > killed_at);
    client.timeout = Duration::from_secs(10);
    let Body::JobResult(r) = client
        .request(Body::JobResultRequest(paddock_proto::JobResultRequest {
            job_id: done.job_id.clone(),
        }))
        .unwrap()
    else {
        panic!("expected a job result");
    };
    let got: serde_json::Value = serde_json::from_str(&r.result_json).unwrap();
    assert_eq!(
        got, expected,
        "the resumed job's result differs from an uninterrupted run"
    );

    // the CLI: `paddock tune --endpoint` prints what the local `paddock tune` prints,
    // apart from the wall-clock figures
    let out = tempfile::tempdir().unwrap();
    let tune = |dir: &str, endpoint: Option<&str>| -> serde_json::Value {
        let dir = out.path().join(dir).display().to_string();
        let mut args = vec![
            "tune",
            "--generations",
            "2",
            "--popsize",
            "4",
            "--seeds",
            "2",
            "--holdout",
            "2",
            "--seed",
            "3",
            "--json",
            "--out",
            &dir,
        ];
        if let Some(e) = endpoint {
            args.extend(["--endpoint", e]);
        }
        let o = paddock(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        for k in ["tuning_s", "total_s", "rollouts_per_s"] {
            v.as_object_mut().unwrap().remove(k);
        }
        v
    };
    assert_eq!(tune("local", None), tune("remote", Some(&c.front)));
}

#[test]
fn e_fifty_concurrent_clients_get_their_own_replies() {
    let _serial = serial();
    let c = Cluster::start(2, 1);
    let b = bundle();
    c.client().put_map(b.clone()).unwrap();
    let per_client: Vec<Vec<EpisodeTask>> =
        (0..50).map(|i| tasks(2, 0.5, 1000 + i as u64)).collect();
    let all: Vec<EpisodeTask> = per_client.iter().flatten().cloned().collect();
    let expected = local(&all);
    let front = c.front.clone();
    let handles: Vec<_> = per_client
        .into_iter()
        .enumerate()
        .map(|(i, t)| {
            let front = front.clone();
            let b = b.clone();
            std::thread::spawn(move || {
                let mut client = paddock_broker::client::Client::connect(&front).unwrap();
                client.timeout = Duration::from_secs(60);
                // interleave a status request with the batch on the same socket
                let batch = batch_to_proto(&t, |_| map_ref(&b), i % 2 == 0);
                let batch_id = client.send(Body::RolloutBatch(batch)).unwrap();
                let status_id = client
                    .send(Body::StatusRequest(paddock_proto::StatusRequest {}))
                    .unwrap();
                let mut results = None;
                let mut status = false;
                let deadline = Instant::now() + Duration::from_secs(90);
                while results.is_none() || !status {
                    assert!(Instant::now() < deadline, "client {i}: replies lost");
                    let reply = client.recv(Duration::from_secs(60)).unwrap();
                    let rid = reply.request_id;
                    match reply.body {
                        Body::RolloutResult(_) => {
                            assert_eq!(rid, batch_id, "client {i}: crossed reply");
                            assert!(results.is_none(), "client {i}: two results");
                            results = Some(
                                reply
                                    .payload
                                    .iter()
                                    .map(|o| outcome_from_bytes(o).unwrap())
                                    .collect::<Vec<_>>(),
                            );
                        }
                        Body::RolloutProgress(_) => assert_eq!(rid, batch_id),
                        Body::BrokerStatus(_) => {
                            assert_eq!(rid, status_id, "client {i}: crossed reply");
                            status = true;
                        }
                        other => panic!("client {i}: unexpected {other:?}"),
                    }
                }
                results.unwrap()
            })
        })
        .collect();
    let got: Vec<EpisodeResult> = handles
        .into_iter()
        .flat_map(|h| h.join().expect("a client thread failed"))
        .collect();
    assert_eq!(got.len(), expected.len());
    assert!(got == expected, "a client got another client's results");
}
