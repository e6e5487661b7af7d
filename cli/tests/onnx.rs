//! ONNX models on the command line: `paddock rollout --driver model.onnx` runs a model
//! file locally (deterministically, a NaN action a crash), `paddock onnx-check` prints the
//! same actions as the library, bad models are refused with the library's message.

use std::path::Path;
use std::process::Command;

use paddock_policy::onnx::{OnnxPolicy, model_hash, write};
use paddock_sim::lidar::LidarConfig;

fn paddock(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(args)
        .output()
        .expect("run paddock");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

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

    let (ok, _, err) = paddock(&[
        "rollout",
        "--driver",
        &path,
        "--endpoint",
        "tcp://127.0.0.1:9",
        "--episodes",
        "1",
    ]);
    assert!(!ok && err.contains("ONNX models run locally only"), "{err}");
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
