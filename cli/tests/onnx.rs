//! ONNX models on the command line: `paddock rollout --driver model.onnx` runs a model
//! file locally (deterministically, a NaN action a crash), `paddock onnx-check` prints the
//! same actions as the library, bad models are refused with the library's message.

mod common;

use common::paddock;

use std::path::Path;
use std::process::Command;

use paddock_policy::onnx::{OnnxPolicy, model_hash, write};
use paddock_sim::lidar::LidarConfig;

fn write_model(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn rollout_runs_a_model_file_locally_and_deterministically() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = LidarConfig::default();
    let bytes = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.0).bytes();
    let path = write_model(dir.path(), "centering.onnx", &bytes);
    let args = [
        "rollout",
        "--driver",
        &path,
        "--episodes",
        "2",
        "--time-limit",
        "8",
        "--json",
    ];
    let (ok, out, err) = paddock(&args);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["driver"], format!("onnx:{}", model_hash(&bytes)));
    for e in v["episodes"].as_array().unwrap() {
        assert!(e["progress_m"].as_f64().unwrap() > 5.0, "{e}");
    }
    assert_eq!(paddock(&args).1, out, "same model and flags, same output");

    let nan = write_model(dir.path(), "nan.onnx", &write::nan_when_slow().bytes());
    let (ok, out, err) = paddock(&["rollout", "--driver", &nan, "--episodes", "1", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["episodes"][0]["termination"], "crashed", "{out}");

    let junk = write_model(dir.path(), "junk.onnx", b"not a model");
    let (ok, _, err) = paddock(&["rollout", "--driver", &junk]);
    assert!(!ok && err.contains("junk.onnx: not an ONNX model"), "{err}");
}

#[test]
fn onnx_check_prints_the_library_actions_on_seeded_samples() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = write::scalars_and_prev([0.5, 2.0]).bytes();
    let path = write_model(dir.path(), "scalars.onnx", &bytes);
    let (ok, out, err) = paddock(&["onnx-check", &path, "--samples", "4", "--seed", "9"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["sha256"], model_hash(&bytes));
    let policy = OnnxPolicy::from_bytes(&bytes, "scalars.onnx").unwrap();
    let names: Vec<&str> = policy.inputs().iter().map(|s| s.name.as_str()).collect();
    let samples = v["samples"].as_array().unwrap();
    assert_eq!(samples.len(), 4);
    for (k, s) in samples.iter().enumerate() {
        let feeds = policy.sample_inputs(9 + k as u64);
        for (name, f) in names.iter().zip(&feeds) {
            let got: Vec<f32> = serde_json::from_value(s["inputs"][name].clone()).unwrap();
            assert_eq!(&got, f, "sample {k} input {name}");
        }
        let want = policy.run(&feeds).unwrap();
        let got: [f32; 2] = serde_json::from_value(s["action"].clone()).unwrap();
        assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "sample {k}");
    }
    let (ok, _, err) = paddock(&["onnx-check", "no/such.onnx"]);
    assert!(!ok && err.contains("no/such.onnx: cannot read it"), "{err}");
}

#[test]
fn benchmark_runs_models_as_driver_and_opponent_locally() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = LidarConfig::default();
    let centering = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes();
    let slower = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.0).bytes();
    let me = write_model(dir.path(), "me.onnx", &centering);
    let them = write_model(dir.path(), "them.onnx", &slower);
    let b1 = [
        "benchmark",
        "b1",
        "--driver",
        &me,
        "--episodes",
        "2",
        "--laps",
        "1",
        "--time-limit",
        "60",
        "--json",
    ];
    let (ok, out, err) = paddock(&b1);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["driver"], format!("onnx:{}", model_hash(&centering)));
    assert_eq!(v["episodes"], 2);
    assert!(v["laps_counted"].as_u64().unwrap() >= 1, "{out}");
    assert!(v["lap_time_mean"].as_f64().unwrap() > 10.0, "{out}");
    assert_eq!(paddock(&b1).1, out, "same model and flags, same report");

    let (ok, out, err) = paddock(&[
        "benchmark",
        "b3",
        "--driver",
        &me,
        "--opponent",
        &them,
        "--episodes",
        "2",
        "--laps",
        "1",
        "--time-limit",
        "60",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["opponent"], format!("onnx:{}", model_hash(&slower)));
    assert!(v["win_rate"].as_f64().is_some(), "{out}");

    // a model with a built-in opponent, and a built-in driver against a model
    let (ok, _, err) = paddock(&[
        "benchmark",
        "b3",
        "--opponent",
        &me,
        "--episodes",
        "2",
        "--laps",
        "1",
        "--time-limit",
        "30",
    ]);
    assert!(ok, "{err}");
}

#[test]
fn benchmark_demo_and_bridge_refuse_bad_models_before_running() {
    let dir = tempfile::tempdir().unwrap();
    let small = write_model(
        dir.path(),
        "m64.onnx",
        &write::centering_on_scans(64, 4.7, 0.4, 2.0).bytes(),
    );
    let junk = write_model(dir.path(), "junk.onnx", b"not a model");
    let beams = "m64.onnx: input scans has 64 beams, the vehicle's LIDAR 1080";
    for (args, says) in [
        (vec!["benchmark", "b1", "--driver", &small], beams),
        (vec!["benchmark", "b3", "--opponent", &small], beams),
        (
            vec!["benchmark", "b2", "--driver", &junk],
            "junk.onnx: not an ONNX model",
        ),
        (vec!["demo", "--driver", &small], beams),
        (
            vec!["demo", "--driver", &junk],
            "junk.onnx: not an ONNX model",
        ),
        (vec!["bridge", "drive", "--driver", &small], beams),
        (
            vec!["bridge", "drive", "--driver", &junk],
            "junk.onnx: not an ONNX model",
        ),
        (vec!["bridge", "sil", "--opponent", &small], beams),
    ] {
        let (ok, _, err) = paddock(&args);
        assert!(!ok && err.contains(says), "{args:?}: {err}");
    }
    let (ok, _, err) = paddock(&["benchmark", "b1", "--driver", &small, "--params", "gain=1"]);
    assert!(!ok, "{err}");
    let (ok, _, err) = paddock(&[
        "benchmark",
        "b3",
        "--opponent",
        &junk,
        "--endpoint",
        "tcp://127.0.0.1:9",
    ]);
    assert!(!ok && err.contains("--opponent"), "{err}");
}

#[test]
fn demo_drives_a_model() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = LidarConfig::default();
    let bytes = write::centering_on_scans(lidar.num_beams, lidar.fov, 0.4, 2.5).bytes();
    let path = write_model(dir.path(), "centering.onnx", &bytes);
    let args = [
        "demo",
        "--driver",
        &path,
        "--laps",
        "1",
        "--agents",
        "2",
        "--time-limit",
        "60",
        "--json",
    ];
    let (ok, out, err) = paddock(&args);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["driver"], format!("onnx:{}", model_hash(&bytes)));
    let agents = v["agents"].as_array().unwrap();
    assert_eq!(agents.len(), 2);
    assert!(agents[0]["progress_m"].as_f64().unwrap() > 20.0, "{out}");
    assert_eq!(paddock(&args).1, out);
}

/// `paddock onnx-check model.onnx | head` panicked on the closed pipe ("failed printing
/// to stdout"); it ends quietly with status 0 as every printing command does.
#[test]
fn onnx_check_into_a_closed_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_model(
        dir.path(),
        "scalars.onnx",
        &write::scalars_and_prev([0.5, 2.0]).bytes(),
    );
    let out = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "set -o pipefail; '{}' onnx-check '{path}' --samples 2000 | head -n 1",
            env!("CARGO_BIN_EXE_paddock")
        ))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{} {err}", out.status);
    assert!(err.is_empty(), "onnx-check | head said: {err}");
    let (ok, _, err) = paddock(&["onnx-check", &path, "--samples", "0"]);
    assert!(!ok && err.contains("0 is out of range"), "{err}");
}
