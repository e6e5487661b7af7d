//! `--vehicle FILE` on every command that simulates: the car changes the results, the
//! same car gives the same bits locally and through a broker, bad files are refused
//! naming the key and the value.

mod common;

use common::paddock;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

fn scratch(name: &str) -> PathBuf {
    common::scratch("vehicle", name)
}

/// A slippery, heavier car with a sluggish steering: what a fitted vehicle looks like.
const SLIPPERY: &str = "mu: 0.55\nm: 4.2\neffects:\n  steering_lag: { tau_s: 0.08 }\n";

/// `rollout --json` with trajectories; returns the episodes array.
fn rollout(extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "rollout",
        "--episodes",
        "3",
        "--seed",
        "5",
        "--time-limit",
        "6",
        "--trajectory",
        "20",
        "--json",
    ];
    args.extend(extra);
    let (ok, out, err) = paddock(&args);
    assert!(ok, "{args:?}: {err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    v["episodes"].clone()
}

/// A `paddock serve` on a free loopback port, killed on drop.
struct Serve(Child, String);

impl Serve {
    fn start(extra: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_paddock"))
            .args(["serve", "--bind", "tcp://127.0.0.1:0", "--threads", "2"])
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(line.starts_with("tcp://"), "serve printed {line:?}");
        Serve(child, line.trim().to_string())
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_changed_vehicle_changes_the_trajectory_and_travels_to_workers() {
    let dir = scratch("travel");
    let file = dir.join("slippery.yaml");
    std::fs::write(&file, SLIPPERY).unwrap();
    let f = file.to_str().unwrap();

    let stock = rollout(&[]);
    let slippery = rollout(&["--vehicle", f]);
    assert_ne!(stock, slippery, "the vehicle changes the trajectories");
    for (a, b) in stock
        .as_array()
        .unwrap()
        .iter()
        .zip(slippery.as_array().unwrap())
    {
        assert_eq!(a["seed"], b["seed"], "same starts");
        assert_ne!(a["trajectory"]["x"], b["trajectory"]["x"]);
    }
    assert_eq!(slippery, rollout(&["--vehicle", f]), "same car, same bits");

    // through a broker the vehicle travels with the request: the same bits
    let serve = Serve::start(&[]);
    assert_eq!(
        slippery,
        rollout(&["--vehicle", f, "--endpoint", &serve.1]),
        "remote = local"
    );
    assert_eq!(stock, rollout(&["--endpoint", &serve.1]));
    drop(serve);

    // `serve --vehicle`: requests that name no vehicle drive the served car
    let serve = Serve::start(&["--vehicle", f]);
    assert_eq!(slippery, rollout(&["--endpoint", &serve.1]));
    drop(serve);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_simulating_command_takes_a_vehicle() {
    let dir = scratch("commands");
    let file = dir.join("slippery.yaml");
    std::fs::write(&file, SLIPPERY).unwrap();
    let f = file.to_str().unwrap();
    let demo = |extra: &[&str]| {
        let mut args = vec!["demo", "--json", "--laps", "1", "--seed", "2"];
        args.extend(extra);
        let (ok, out, err) = paddock(&args);
        assert!(ok, "{err}");
        serde_json::from_str::<serde_json::Value>(&out).unwrap()["agents"][0].clone()
    };
    assert_ne!(demo(&[]), demo(&["--vehicle", f]));

    let bench = |extra: &[&str]| {
        let mut args = vec![
            "benchmark",
            "b1",
            "--episodes",
            "2",
            "--laps",
            "1",
            "--time-limit",
            "40",
            "--json",
        ];
        args.extend(extra);
        let (ok, out, err) = paddock(&args);
        assert!(ok, "{err}");
        serde_json::from_str::<serde_json::Value>(&out).unwrap()
    };
    assert_ne!(bench(&[]), bench(&["--vehicle", f]));

    let tune = |extra: &[&str]| {
        let out = dir.join(format!("tune{}", extra.len()));
        let mut args = vec![
            "tune",
            "--generations",
            "1",
            "--popsize",
            "2",
            "--seeds",
            "1",
            "--holdout",
            "2",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(extra);
        let (ok, text, err) = paddock(&args);
        assert!(ok, "{err}");
        serde_json::from_str::<serde_json::Value>(&text).unwrap()
    };
    assert_ne!(tune(&[])["default"], tune(&["--vehicle", f])["default"]);

    let (ok, out, err) = paddock(&[
        "perf",
        "--json",
        "--seconds",
        "0.1",
        "--no-scan",
        "--vehicle",
        f,
    ]);
    assert!(ok && out.contains("agent_steps_per_s_noscan"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_vehicle_files_are_refused_naming_the_key_and_value() {
    let dir = scratch("bad");
    for (text, key, value) in [
        ("m: -2.5\n", "m", "-2.5"),
        ("mu: 1.0\nmass: 3.0\n", "mass", ""),
        (
            "effects:\n  drag: { c_lin: -0.5, c_quad: 0.0 }\n",
            "effects.drag.c_lin",
            "-0.5",
        ),
    ] {
        let file = dir.join("bad.yaml");
        std::fs::write(&file, text).unwrap();
        for cmd in [&["rollout", "--episodes", "1"][..], &["demo"], &["serve"]] {
            let mut args = cmd.to_vec();
            args.extend(["--vehicle", file.to_str().unwrap()]);
            let (ok, _, err) = paddock(&args);
            assert!(!ok, "{args:?} accepted {text:?}");
            assert!(
                err.contains("--vehicle") && err.contains(key) && err.contains(value),
                "{args:?} with {text:?}: {err}"
            );
        }
    }
    let (ok, _, err) = paddock(&["demo", "--vehicle", "no/such/vehicle.yaml"]);
    assert!(!ok && err.contains("no/such/vehicle.yaml"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
