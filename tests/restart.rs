//! A broker restart loses nothing (issue 17, item 5): a plain rollout batch whose broker
//! is killed (`kill -9`) mid-batch and restarted on the same endpoints and state
//! directory is sent again by its client and ends with results bit-identical to a local
//! run; a client whose broker is gone for good gets a transport error that names the
//! endpoint and says the broker does not answer, within a bounded time, never an
//! "invalid scenario".

use std::process::{Child, Command, Output, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use paddock_broker::client::{ClientError, ResumePolicy};
use paddock_e2e::{Cluster, paddock, paddock_bin, serial};
use paddock_proto::Body;
use paddock_rollout::{EpisodeResult, EpisodeTask, Executor, LocalExecutor, Scenario, task_seed};
use paddock_wire::{batch_to_proto, local_map, map_ref, outcome_from_bytes};

/// Follow-the-gap reads the LIDAR: its episodes take long enough for a batch to be
/// interrupted mid-way.
fn tasks(n: usize, job_seed: u64) -> Vec<EpisodeTask> {
    let mut s = Scenario::single("follow-the-gap").unwrap();
    s.time_limit = 6.0;
    let s = Arc::new(s);
    (0..n)
        .map(|k| EpisodeTask {
            scenario: s.clone(),
            seed: task_seed(job_seed, k as u64),
            record: (k % 10 == 0).then_some(10),
        })
        .collect()
}

/// A quick watch, so that the tests do not wait the CLI's seconds.
fn quick() -> ResumePolicy {
    ResumePolicy {
        quiet: Duration::from_millis(500),
        answer_within: Duration::from_secs(3),
        ping_every: Duration::from_millis(250),
        max_resends: 3,
    }
}

/// The broker's status (tasks done, queued), or None when it does not answer.
fn progress(c: &Cluster) -> Option<(u64, u64)> {
    let mut client = c.client();
    client.timeout = Duration::from_secs(2);
    match client.request(Body::StatusRequest(paddock_proto::StatusRequest {})) {
        Ok(Body::BrokerStatus(s)) => Some((s.tasks_done, s.queue_depth + s.tasks_in_flight)),
        _ => None,
    }
}

#[test]
fn a_batch_outlives_a_broker_killed_mid_batch_and_restarted() {
    let _serial = serial();
    let tasks = tasks(24, 1);
    let expected: Vec<EpisodeResult> = LocalExecutor::new(2, paddock_sim::circuit::Circuits::new())
        .unwrap()
        .run_batch(&tasks, &|_| {})
        .into_iter()
        .map(|r| r.unwrap())
        .collect();

    let mut c = Cluster::start(1, 2);
    let b = local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    let mut client = c.client();
    client.put_map(b.clone()).unwrap();
    let batch = batch_to_proto(&tasks, |_| map_ref(&b), true);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(client.request_resumable(Body::RolloutBatch(batch), &quick(), |_| {}));
    });
    // kill -9 once a few tasks are done, and start a new broker at once
    wait_until_mid_batch(&c, 0, || false);
    c.broker.as_mut().unwrap().kill9();
    c.start_broker();
    let reply = match rx.recv_timeout(Duration::from_secs(120)) {
        Ok(r) => r.unwrap_or_else(|e| panic!("the batch failed: {e}; {}", c.broker_report())),
        Err(_) => panic!(
            "the batch did not end within 120 s of the restart; {}",
            c.broker_report()
        ),
    };
    let Body::RolloutResult(r) = reply.body else {
        panic!("expected a rollout result, got {:?}", reply.body);
    };
    assert_eq!(r.outcomes as usize, tasks.len());
    let got: Vec<EpisodeResult> = reply
        .payload
        .iter()
        .map(|o| outcome_from_bytes(o).unwrap())
        .collect();
    assert!(
        got == expected,
        "the batch re-sent after the restart differs from a local run"
    );
}

/// `paddock rollout ARGS` started in the background, its output collected.
fn spawn_paddock(args: &[&str]) -> Child {
    Command::new(paddock_bin())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("running paddock {args:?}: {e}"))
}

/// Waits for `child` at most `within`; kills it and fails past that.
fn wait_within(mut child: Child, within: Duration, what: &str) -> Output {
    let t0 = Instant::now();
    while child.try_wait().expect("the child's state").is_none() {
        if t0.elapsed() > within {
            let _ = child.kill();
            let out = child.wait_with_output().expect("the child's output");
            panic!(
                "{what} did not end within {within:?}; stderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().expect("the child's output")
}

const ROLLOUT: [&str; 10] = [
    "rollout",
    "--driver",
    "follow-the-gap",
    "--episodes",
    "30",
    "--time-limit",
    "6",
    "--seed",
    "4",
    "--json",
];

/// Waits until the broker runs a batch: more than `before + 1` tasks done, some left
/// (`ended`: the batch's client ended, too soon).
fn wait_until_mid_batch(c: &Cluster, before: u64, mut ended: impl FnMut() -> bool) {
    let t0 = Instant::now();
    loop {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the batch never ran on the broker"
        );
        assert!(
            !ended(),
            "the batch ended before the broker could be killed: make it longer"
        );
        if let Some((done, left)) = progress(c)
            && done >= before + 2
            && left > 0
        {
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits until the broker runs the CLI's batch.
fn wait_mid_batch(c: &Cluster, rollout: &mut Child) {
    wait_until_mid_batch(c, 0, || rollout.try_wait().unwrap().is_some());
}

#[test]
fn paddock_rollout_endpoint_outlives_a_broker_restart_with_the_local_output() {
    let _serial = serial();
    let local = paddock(&ROLLOUT);
    assert!(
        local.status.success(),
        "{}",
        String::from_utf8_lossy(&local.stderr)
    );

    let mut c = Cluster::start(1, 2);
    let mut args = ROLLOUT.to_vec();
    args.extend(["--endpoint", &c.front]);
    let mut rollout = spawn_paddock(&args);
    wait_mid_batch(&c, &mut rollout);
    let before = c.status()["instance"].clone();
    c.broker.as_mut().unwrap().kill9();
    c.start_broker();
    let out = wait_within(
        rollout,
        Duration::from_secs(120),
        "paddock rollout --endpoint",
    );
    let after = c.status()["instance"].clone();
    assert!(
        before.as_str().is_some_and(|i| i.len() == 16) && after != before,
        "`paddock status --json` instance ids: {before} before the restart, {after} after"
    );
    assert!(
        out.status.success(),
        "paddock rollout through a restarted broker failed: {}; {}",
        String::from_utf8_lossy(&out.stderr),
        c.broker_report()
    );
    assert!(
        out.stdout == local.stdout,
        "the output through a restarted broker differs from the local one"
    );
}

#[test]
fn paddock_rollout_endpoint_names_a_broker_gone_for_good_within_seconds() {
    let _serial = serial();
    let mut c = Cluster::start(1, 2);
    let mut args = ROLLOUT.to_vec();
    args.extend(["--endpoint", &c.front]);
    let mut rollout = spawn_paddock(&args);
    wait_mid_batch(&c, &mut rollout);
    c.broker.as_mut().unwrap().kill9();
    let killed = Instant::now();
    // the CLI asks after 3 s of silence and gives a status request 10 s
    let out = wait_within(
        rollout,
        Duration::from_secs(40),
        "paddock rollout --endpoint",
    );
    let took = killed.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!(
        "paddock rollout ended {took:?} after the kill: {}",
        stderr.trim()
    );
    assert!(!out.status.success(), "paddock rollout succeeded: {stderr}");
    assert!(
        stderr.contains(&c.front) && stderr.contains("does not answer"),
        "the error does not name the endpoint and say the broker does not answer: {stderr}"
    );
    assert!(
        !stderr.contains("invalid scenario"),
        "a transport failure reported as a scenario error: {stderr}"
    );
    assert!(took < Duration::from_secs(30), "the error took {took:?}");
}

#[test]
fn a_client_of_an_absent_broker_gets_not_answering_in_bounded_time() {
    let _serial = serial();
    // nothing listens on this port
    let endpoint = format!("tcp://127.0.0.1:{}", paddock_e2e::free_port());
    let mut client = paddock_broker::client::Client::connect(&endpoint).unwrap();
    let tasks = tasks(2, 1);
    let b = local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    let batch = batch_to_proto(&tasks, |_| map_ref(&b), true);
    let t0 = Instant::now();
    let e = client
        .request_resumable(Body::RolloutBatch(batch), &quick(), |_| {})
        .expect_err("a batch with no broker");
    let took = t0.elapsed();
    eprintln!("gave up after {took:?}: {e}");
    assert!(matches!(e, ClientError::NotAnswering(_)), "{e}");
    assert!(e.is_transport());
    // quiet (0.5 s) + answer_within (3 s), and some slack for a loaded machine
    assert!(
        took >= Duration::from_millis(3400) && took < Duration::from_secs(8),
        "gave up after {took:?}"
    );
}
