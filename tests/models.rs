//! ONNX models through a real broker and workers: a model file named on the command line
//! is stored in the broker (`PutBlob`), each worker fetches it by its hash once, and the
//! episodes are bit for bit those of the same command run locally. A scenario naming a
//! model the broker does not hold, or bytes that are not a model, is refused with an
//! error naming the car's driver field, and the broker goes on serving.

use std::path::Path;
use std::time::Duration;

use paddock_e2e::{Cluster, paddock, serial};
use paddock_policy::onnx::write;
use paddock_proto::{Body, ErrorCode, RolloutBatch, RolloutTaskSpec};
use paddock_sim::lidar::LidarConfig;
use paddock_wire::{local_map, map_ref};
use prost::Message;

fn write_model(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path.display().to_string()
}

fn run(args: &[&str]) -> String {
    let out = paddock(args);
    assert!(
        out.status.success(),
        "paddock {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The same command locally and with `--endpoint`: the same output.
fn same_here_and_there(c: &Cluster, args: &[&str]) -> String {
    let here = run(args);
    let mut there = args.to_vec();
    there.extend(["--endpoint", c.front.as_str()]);
    assert_eq!(
        here,
        run(&there),
        "paddock {args:?} differs through the broker"
    );
    here
}

/// A batch of one task whose only car drives with `driver`; the broker's refusal.
fn refusal(c: &Cluster, driver: &str) -> paddock_proto::Error {
    let mut client = c.client();
    let b = local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    client.put_map(b.clone()).unwrap();
    let scenario = paddock_proto::Scenario {
        map: Some(map_ref(&b)),
        agents: vec![paddock_proto::AgentSpec {
            driver: driver.into(),
            ..Default::default()
        }],
        laps: 1,
        time_limit: 2.0,
        lidar: Some(paddock_proto::Lidar {
            num_beams: 1080,
            fov: 4.7,
            max_range: 30.0,
            ..Default::default()
        }),
        ..Default::default()
    };
    let batch = RolloutBatch {
        scenarios: vec![scenario.encode_to_vec()],
        tasks: vec![RolloutTaskSpec {
            scenario: 0,
            seed: 1,
            ..Default::default()
        }],
        ..Default::default()
    };
    client.timeout = Duration::from_secs(30);
    match client.request(Body::RolloutBatch(batch)) {
        Err(paddock_broker::client::ClientError::Remote(e)) => e,
        other => panic!("a batch naming {driver} was not refused: {other:?}"),
    }
}

#[test]
fn models_travel_by_hash_and_drive_the_same_on_workers_as_locally() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let lidar = LidarConfig::default();
    let fast = write_model(
        dir.path(),
        "fast.onnx",
        &write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes(),
    );
    let slow = write_model(
        dir.path(),
        "slow.onnx",
        &write::centering_on_scans(lidar.num_beams, lidar.fov, 0.5, 1.8).bytes(),
    );
    // two workers, each with its own caches: both fetch the models from the broker
    let c = Cluster::start(2, 1);
    let rollout = same_here_and_there(
        &c,
        &[
            "rollout",
            "--driver",
            &fast,
            "--episodes",
            "6",
            "--time-limit",
            "4",
            "--seed",
            "3",
            "--json",
        ],
    );
    let v: serde_json::Value = serde_json::from_str(&rollout).unwrap();
    let episodes = v["episodes"].as_array().unwrap();
    assert_eq!(episodes.len(), 6);
    assert!(
        episodes
            .iter()
            .all(|e| e["progress_m"].as_f64().unwrap() > 5.0),
        "the model drives: {rollout}"
    );
    // both cars models: driver and opponent of a head-to-head race
    same_here_and_there(
        &c,
        &[
            "benchmark",
            "b3",
            "--driver",
            &fast,
            "--opponent",
            &slow,
            "--episodes",
            "2",
            "--laps",
            "1",
            "--time-limit",
            "20",
            "--json",
        ],
    );

    // a model the broker does not hold
    let missing = format!("onnx:{}", "0".repeat(64));
    let e = refusal(&c, &missing);
    assert_eq!(e.code, ErrorCode::NotFound as i32, "{e:?}");
    assert_eq!(
        e.field, "rollout_batch.scenarios[0].agents[0].driver",
        "{e:?}"
    );
    assert!(e.message.contains("put_blob"), "{e:?}");
    // bytes stored in the broker that are not a model
    let mut client = c.client();
    let junk = client.put_blob(b"not an onnx model".to_vec()).unwrap();
    let e = refusal(&c, &format!("onnx:{junk}"));
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32, "{e:?}");
    assert_eq!(
        e.field, "rollout_batch.scenarios[0].agents[0].driver",
        "{e:?}"
    );
    assert!(e.message.contains("not an ONNX model"), "{e:?}");
    // and it goes on serving
    same_here_and_there(
        &c,
        &[
            "rollout",
            "--driver",
            &slow,
            "--episodes",
            "2",
            "--time-limit",
            "2",
            "--json",
        ],
    );
}
