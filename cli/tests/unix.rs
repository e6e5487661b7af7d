//! The `paddock` binary behaves like a Unix tool: a closed pipe ends it quietly, numeric
//! flags are range-checked with one wording, output stays readable, files are not
//! overwritten by surprise.

mod common;

use std::io::Read;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use common::paddock_status as paddock;

fn scratch(name: &str) -> PathBuf {
    common::scratch("unix", name)
}

/// Runs `paddock args` with its stdout a pipe whose reading end is closed before the
/// program writes: every write meets EPIPE. It must end with status 0 and say nothing.
fn into_closed_pipe(args: &[&str]) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run paddock");
    drop(child.stdout.take());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    let status = child.wait().unwrap();
    assert_eq!(
        status.code(),
        Some(0),
        "{args:?} into a closed pipe: {status}, stderr {err}"
    );
    assert!(
        !err.contains("panicked") && !err.to_lowercase().contains("broken pipe"),
        "{args:?} into a closed pipe said: {err}"
    );
}

#[test]
fn a_closed_pipe_ends_every_printing_command_quietly() {
    for args in [
        &["drivers"][..],
        &["drivers", "--json"],
        &["drivers", "--verbose"],
        &["maps", "list"],
        &["maps", "list", "--json"],
        &["demo", "--laps", "1"],
        &[
            "rollout",
            "--episodes",
            "2",
            "--time-limit",
            "5",
            "--threads",
            "1",
        ],
        &[
            "benchmark",
            "b1",
            "--episodes",
            "1",
            "--laps",
            "1",
            "--time-limit",
            "5",
        ],
        &["perf", "--seconds", "0.1", "--no-scan"],
        &["--help"],
        &["rollout", "--help"],
    ] {
        into_closed_pipe(args);
    }
}

/// The commands that write files and then say what they wrote: the files are written,
/// and the closed pipe ends them as quietly (`sysid synth --runs` printed its summary
/// with `println!`, which panicked there).
#[test]
fn a_closed_pipe_ends_every_file_writing_command_quietly() {
    let dir = scratch("closed-pipe-files");
    let at = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let (csv, runs, mcap) = (at("rec.csv"), at("runs"), at("runs.mcap"));
    let (keys, maps, tuned) = (at("keys"), at("maps"), at("tune"));
    for args in [
        &["sysid", "synth", "--seconds", "5", "--out", &csv][..],
        &[
            "sysid",
            "synth",
            "--manoeuvre",
            "step",
            "--runs",
            "2",
            "--out",
            &runs,
        ],
        &[
            "sysid",
            "synth",
            "--manoeuvre",
            "arc",
            "--runs",
            "2",
            "--out",
            &mcap,
        ],
        &["keys", "generate", "--out", &keys],
        &[
            "maps", "generate", "--name", "gen", "--seed", "3", "--out", &maps,
        ],
        &[
            "tune",
            "--generations",
            "2",
            "--popsize",
            "4",
            "--seeds",
            "1",
            "--holdout",
            "2",
            "--out",
            &tuned,
        ],
    ] {
        into_closed_pipe(args);
    }
    for written in [
        "rec.csv",
        "runs/truth.json",
        "keys",
        "maps/gen",
        "tune/result.json",
    ] {
        assert!(dir.join(written).exists(), "{written} was not written");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn head_reading_one_line_ends_the_pipeline_with_status_0() {
    let exe = env!("CARGO_BIN_EXE_paddock");
    for cmd in ["drivers --verbose", "drivers --json", "maps list"] {
        let out = Command::new("bash")
            .arg("-c")
            .arg(format!("set -o pipefail; '{exe}' {cmd} | head -n 1"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{cmd} | head: {} {err}", out.status);
        assert_eq!(String::from_utf8_lossy(&out.stdout).lines().count(), 1);
        assert!(err.is_empty(), "{cmd} | head said: {err}");
    }
}

#[test]
fn numeric_flags_have_ranges_with_one_wording() {
    for (args, flag, message) in [
        (
            &["rollout", "--episodes", "-3"][..],
            "--episodes",
            "-3 is out of range: must be a whole number in [1, 1000000]",
        ),
        (
            &["rollout", "--laps", "0"],
            "--laps",
            "0 is out of range: must be a whole number in [1, 100]",
        ),
        (
            &["benchmark", "b1", "--time-limit", "-1"],
            "--time-limit",
            "-1 is out of range: must be a number in (0, 36000]",
        ),
        (
            &["demo", "--seed", "-1"],
            "--seed",
            "-1 is out of range: must be a whole number in [0, 18446744073709551615]",
        ),
        (
            &["tune", "--popsize", "1"],
            "--popsize",
            "1 is out of range: must be a whole number in [2, 1000]",
        ),
        (
            &["maps", "generate", "--name", "x", "--length", "-50"],
            "--length",
            "-50 is out of range: must be a number in [40, 600]",
        ),
        (
            &["serve", "--workers", "0"],
            "--workers",
            "0 is out of range: must be a whole number in [1, 64]",
        ),
        (
            &["rollout", "--episodes", "many"],
            "--episodes",
            "\"many\" is not a whole number in [1, 1000000]",
        ),
        // flags that once had a second, narrower range checked later in other words
        (
            &[
                "sysid",
                "synth",
                "--manoeuvre",
                "step",
                "--runs",
                "501",
                "--out",
                "x",
            ],
            "--runs",
            "501 is out of range: must be a whole number in [1, 500]",
        ),
        (
            &[
                "sysid",
                "synth",
                "--manoeuvre",
                "step",
                "--rate",
                "300",
                "--out",
                "x",
            ],
            "--rate",
            "300 is out of range: must be a number in [5, 200]",
        ),
        // flags that took clap's own wording, or were checked only once running
        (
            &["rollout", "--fps", "-1"],
            "--fps",
            "-1 is out of range: must be a whole number that divides 100",
        ),
        (
            &["rollout", "--video-width", "99999"],
            "--video-width",
            "99999 is out of range: must be a whole number in [160, 2048]",
        ),
        (
            &["rollout", "--video-episode", "-1"],
            "--video-episode",
            "-1 is out of range: must be a whole number in [0, 999999]",
        ),
        (
            &["serve", "--parent-pid", "-1"],
            "--parent-pid",
            "-1 is out of range: must be a whole number in [1, 4294967295]",
        ),
        (
            &[
                "bridge",
                "drive",
                "--driver",
                "pure-pursuit",
                "--max-invalid-ahead",
                "-1",
            ],
            "--max-invalid-ahead",
            "-1 is out of range: must be a number in [0, 1]",
        ),
        (
            &[
                "bridge",
                "drive",
                "--driver",
                "pure-pursuit",
                "--max-clock-drift",
                "inf",
            ],
            "--max-clock-drift",
            "inf is out of range: must be a number in [0, 1]",
        ),
        (
            &[
                "bridge",
                "drive",
                "--driver",
                "pure-pursuit",
                "--laser-x",
                "nan",
            ],
            "--laser-x",
            "nan is out of range: must be a number in [-5, 5]",
        ),
        (
            &[
                "bridge",
                "drive",
                "--driver",
                "pure-pursuit",
                "--laser-yaw",
                "7",
            ],
            "--laser-yaw",
            "7 is out of range: must be a number in [-2 pi, 2 pi]",
        ),
    ] {
        let (code, _, err) = paddock(args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(
            err.contains(flag) && err.contains(message),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn threads_are_capped_at_four_per_core() {
    let cores = std::thread::available_parallelism().unwrap().get();
    let max = 4 * cores;
    for cmd in [&["rollout"][..], &["tune"], &["serve"], &["worker"]] {
        let over = (max + 1).to_string();
        let mut args = cmd.to_vec();
        args.extend(["--threads", &over]);
        let (code, _, err) = paddock(&args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(
            err.contains(&format!(
                "{over} is out of range: must be a whole number in [0, {max}]"
            )),
            "{args:?}: {err}"
        );
    }
    let (code, _, err) = paddock(&[
        "rollout",
        "--threads",
        &max.to_string(),
        "--episodes",
        "1",
        "--time-limit",
        "1",
    ]);
    assert_eq!(code, Some(0), "{err}");
}

#[test]
fn drivers_lists_parameters_and_keeps_weights_behind_verbose() {
    let (code, short, err) = paddock(&["drivers"]);
    assert_eq!(code, Some(0), "{err}");
    let (_, long, _) = paddock(&["drivers", "--verbose"]);
    let (_, json, _) = paddock(&["drivers", "--json"]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let mlp = v
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["name"] == "mlp")
        .unwrap();
    let weights = mlp["params"].as_array().unwrap().len();
    assert!(weights > 400, "{weights}");
    assert!(short.lines().count() < 120, "{short}");
    assert!(short.contains(&format!("({weights} parameters; --verbose lists them)")));
    for name in [
        "pure-pursuit",
        "follow-the-gap",
        "mlp",
        "lattice",
        "lookahead",
    ] {
        assert!(short.contains(name), "{name} in {short}");
    }
    assert!(
        long.lines().count() > weights,
        "--verbose lists every weight"
    );
}

#[test]
fn maps_generate_does_not_overwrite_without_force() {
    let dir = scratch("generate");
    let out = dir.to_str().unwrap();
    let generate = |extra: &[&str]| {
        let mut args = vec![
            "maps", "generate", "--seed", "3", "--length", "80", "--name", "mini", "--out", out,
        ];
        args.extend(extra);
        paddock(&args)
    };
    let (code, _, err) = generate(&[]);
    assert_eq!(code, Some(0), "{err}");
    let yaml = dir.join("mini/mini_map.yaml");
    std::fs::write(&yaml, "edited by hand\n").unwrap();
    let (code, _, err) = generate(&[]);
    assert_eq!(code, Some(1));
    assert!(err.contains("--force") && err.contains("mini"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&yaml).unwrap(),
        "edited by hand\n",
        "untouched"
    );
    let (code, _, err) = generate(&["--force"]);
    assert_eq!(code, Some(0), "{err}");
    assert_ne!(std::fs::read_to_string(&yaml).unwrap(), "edited by hand\n");

    // a map's own folder lists that map; a folder of maps lists each; others are refused
    let (code, list, err) = paddock(&["maps", "list", "--json", &format!("{out}/mini")]);
    assert_eq!(code, Some(0), "{err}");
    let v: serde_json::Value = serde_json::from_str(&list).unwrap();
    let given: Vec<&serde_json::Value> = v
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["source"] == "given")
        .collect();
    assert_eq!(given.len(), 1, "{list}");
    assert_eq!(given[0]["name"], "mini");
    let (code, list, _) = paddock(&["maps", "list", out]);
    assert_eq!(code, Some(0));
    assert!(list.contains("mini"), "{list}");
    let empty = scratch("empty");
    let (code, _, err) = paddock(&["maps", "list", empty.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("no maps in"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&empty);
}

#[test]
fn one_name_for_the_thing_that_drives() {
    // `--driver` everywhere a driver is named; the output says `driver` too
    let (code, out, err) = paddock(&[
        "rollout",
        "--driver",
        "follow-the-gap",
        "--episodes",
        "1",
        "--time-limit",
        "2",
        "--json",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["driver"], "follow-the-gap");
    for cmd in [
        &["rollout", "--help"][..],
        &["benchmark", "--help"],
        &["tune", "--help"],
        &["perf-cluster", "--help"],
        &["bridge", "drive", "--help"],
    ] {
        let (_, help, _) = paddock(cmd);
        assert!(help.contains("--driver"), "{cmd:?}: {help}");
        assert!(!help.contains("--policy"), "{cmd:?}: {help}");
    }
    // the broker's worker endpoint is --worker-bind; --workers is serve's count only
    let (_, help, _) = paddock(&["broker", "--help"]);
    assert!(
        help.contains("--worker-bind") && !help.contains("--workers"),
        "{help}"
    );
}

/// A TCP port out of range is said at once: ZeroMQ took `tcp://host:99999`, connected to
/// nothing, and the client waited its whole timeout ("no reply from the broker within
/// 10s"), the worker for good; a server bound another port than the one asked for.
#[test]
fn endpoints_with_a_port_out_of_range_are_refused_at_once() {
    for args in [
        &["status", "--endpoint", "tcp://127.0.0.1:99999"][..],
        &["jobs", "list", "--endpoint", "tcp://127.0.0.1:0"],
        &["worker", "--connect", "tcp://127.0.0.1:70000"],
        // to bind, libzmq took port 99999 as 99999 - 65536 = 34463
        &["serve", "--bind", "tcp://127.0.0.1:99999"],
    ] {
        let t0 = std::time::Instant::now();
        let (code, _, err) = paddock(args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        assert!(
            err.contains("is out of range: must be a whole number in [1, 65535]")
                || err.contains("is out of range: must be a whole number in [0, 65535]"),
            "{args:?}: {err}"
        );
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(5),
            "{args:?} took {:?}",
            t0.elapsed()
        );
    }
}
