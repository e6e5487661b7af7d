//! The `paddock` binary end to end: perf, demo, maps list and generate, errors.

mod common;

use common::paddock;

use std::path::PathBuf;

#[test]
fn perf_json_has_the_documented_keys() {
    let (ok, out, err) = paddock(&["perf", "--json", "--seconds", "0.2", "--agents", "2"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for k in [
        "agent_steps_per_s_scan",
        "agent_steps_per_s_noscan",
        "rays_per_s",
    ] {
        assert!(v[k].as_f64().unwrap() > 0.0, "{k} in {out}");
    }
    // where it was measured: the CPU by name, its features, the path and the map
    for k in [
        "cpu",
        "cpu_features",
        "scan_path",
        "scan_sweep_vectors",
        "map",
    ] {
        assert!(v[k].as_str().is_some_and(|s| !s.is_empty()), "{k} in {out}");
    }
    let (ok, out, err) = paddock(&["perf", "--json", "--seconds", "0.2", "--no-scan"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["agent_steps_per_s_noscan"].as_f64().unwrap() > 0.0);
    assert!(v["agent_steps_per_s_scan"].is_null());
    assert!(v["scan_sweep_share"].is_null());
    // a batch of worlds stepped in one call
    let (ok, out, err) = paddock(&[
        "perf",
        "--json",
        "--seconds",
        "0.2",
        "--agents",
        "2",
        "--worlds",
        "3",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["worlds"], 3, "{out}");
    assert_eq!(v["agents"], 2, "{out}");
    assert!(v["agent_steps_per_s_scan"].as_f64().unwrap() > 0.0, "{out}");
    // the default algorithm: the faster of the two, timed
    assert_eq!(v["scan_algorithm"], "auto", "{out}");
    let share = v["scan_sweep_share"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&share), "{out}");
    // each algorithm forced on the portable path, named in the report
    for (algorithm, share) in [("march", 0.0), ("sweep", 1.0)] {
        let (ok, out, err) = paddock(&[
            "perf",
            "--json",
            "--seconds",
            "0.2",
            "--scan-path",
            "portable",
            "--scan-algorithm",
            algorithm,
        ]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["scan_algorithm"], algorithm, "{out}");
        assert_eq!(v["scan_sweep_share"], share, "{out}");
        assert_eq!(v["scan_path"], "portable", "{out}");
        assert!(v["rays_per_s"].as_f64().unwrap() > 0.0, "{out}");
    }
    let (ok, _, err) = paddock(&["perf", "--scan-algorithm", "raytrace"]);
    assert!(
        !ok && err.contains("raytrace") && err.contains("auto, march, sweep"),
        "{err}"
    );
}

/// `paddock ARGS` with `PADDOCK_SCAN_PATH` set to `value`: its exit status, stdout, stderr.
fn paddock_with_scan_path(value: &str, args: &[&str]) -> (Option<i32>, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(args)
        .env("PADDOCK_SCAN_PATH", value)
        .output()
        .expect("run paddock");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_scan_path_variable_sets_the_default_path_and_bad_values_are_refused() {
    let perf = ["perf", "--json", "--seconds", "0.1", "--agents", "1"];
    // the narrowest path, which every CPU runs, taken by default and named in the report
    let (code, out, err) = paddock_with_scan_path("portable", &perf);
    assert_eq!(code, Some(0), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["scan_path"], "portable", "{out}");
    assert_eq!(v["scan_sweep_vectors"], "none", "{out}");
    // empty: as if unset (the widest path)
    let (code, out, err) = paddock_with_scan_path("", &perf);
    assert_eq!(code, Some(0), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let widest = v["scan_path"].as_str().expect("scan_path").to_string();
    // a flag wins over the variable
    let mut forced = perf.to_vec();
    forced.extend(["--scan-path", &widest]);
    let (code, out, err) = paddock_with_scan_path("portable", &forced);
    assert_eq!(code, Some(0), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["scan_path"], widest.as_str(), "{out}");
    // no such path: refused at start, naming the variable and its value, on any command
    for args in [&perf[..], &["maps", "list", "--json"]] {
        let (code, out, err) = paddock_with_scan_path("avx-512", args);
        assert_eq!(code, Some(2), "{out}{err}");
        assert!(out.is_empty(), "{out}");
        assert_eq!(
            err.trim(),
            "error: PADDOCK_SCAN_PATH=\"avx-512\" is not one of portable, avx, avx512"
        );
    }
}

#[test]
fn the_scan_path_variable_reaches_the_served_workers() {
    use std::io::BufRead;
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(["serve", "--bind", "tcp://127.0.0.1:0", "--threads", "1"])
        .env("PADDOCK_SCAN_PATH", "portable")
        .env("RUST_LOG", "paddock_worker=info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run paddock serve");
    let stderr = child.stderr.take().expect("its stderr");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            // the log's colours out: what is left is `key=value`
            let mut plain = String::new();
            let mut chars = line.chars();
            while let Some(c) = chars.next() {
                if c == '\u{1b}' {
                    chars.by_ref().find(|&c| c == 'm');
                } else {
                    plain.push(c);
                }
            }
            if plain.contains(" connected ") && tx.send(plain).is_err() {
                break;
            }
        }
    });
    let line = rx.recv_timeout(std::time::Duration::from_secs(60));
    let _ = child.kill();
    let _ = child.wait();
    let line = line.expect("the worker logs its connection within a minute");
    assert!(line.contains("scan_path=portable"), "{line}");
    assert!(line.contains("sweep_vectors=\"none\""), "{line}");
}

#[test]
fn demo_laps_the_default_map_deterministically() {
    let (ok, a, err) = paddock(&["demo", "--json", "--seed", "4"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&a).unwrap();
    assert_eq!(v["map"], "lakeside");
    assert_eq!(v["agents"][0]["status"], "finished", "{a}");
    assert_eq!(v["agents"][0]["lap_times"].as_array().unwrap().len(), 2);
    let (_, b, _) = paddock(&["demo", "--json", "--seed", "4"]);
    assert_eq!(a, b, "same flags, same output");
}

#[test]
fn maps_list_and_generate() {
    let (ok, out, err) = paddock(&["maps", "list", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let names: Vec<&str> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    for n in ["lakeside", "quarry", "harbour"] {
        assert!(names.contains(&n), "{names:?}");
    }
    let tmp: PathBuf =
        std::env::temp_dir().join(format!("paddock-cli-maps-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let tmp_s = tmp.to_str().unwrap();
    let (ok, _, err) = paddock(&[
        "maps", "generate", "--seed", "5", "--length", "80", "--name", "mini", "--out", tmp_s,
    ]);
    assert!(ok, "{err}");
    // the generated map is listed from its directory and can be driven
    let (ok, out, err) = paddock(&["maps", "list", tmp_s]);
    assert!(ok, "{err}");
    assert!(out.contains("mini"), "{out}");
    let (ok, out, err) = paddock(&["demo", "--map", &format!("{tmp_s}/mini"), "--laps", "1"]);
    assert!(ok, "{err}");
    assert!(out.contains("finished"), "{out}");
    std::fs::remove_dir_all(&tmp).unwrap();
}

#[test]
fn unknown_map_is_a_clear_error() {
    let (ok, _, err) = paddock(&["demo", "--map", "atlantis"]);
    assert!(!ok);
    assert!(
        err.contains("atlantis") && err.contains("unknown map"),
        "{err}"
    );
    let (ok, _, err) = paddock(&["perf", "--agents", "0"]);
    assert!(!ok);
    assert!(err.contains("--agents"), "{err}");
}

/// Regression: a short tune on lakeside finds a faster driver that crashes on one of the
/// six held-out starts; the summary used to print "improvement: 34.9%" for it.
#[test]
fn tune_claims_no_improvement_for_a_driver_that_finishes_fewer_starts() {
    let out = std::env::temp_dir().join(format!("paddock-cli-tune-{}", std::process::id()));
    let args = [
        "tune",
        "--generations",
        "2",
        "--popsize",
        "4",
        "--seeds",
        "2",
        "--holdout",
        "6",
        "--out",
        out.to_str().unwrap(),
    ];
    let (ok, text, err) = paddock(&args);
    assert!(ok, "{err}");
    assert!(
        text.contains("default: finished 6/6 starts")
            && text.contains("tuned:   finished 5/6 starts"),
        "{text}"
    );
    assert!(
        text.contains(
            "no improvement: the tuned driver finished fewer held-out starts (5/6 against 6/6)"
        ),
        "{text}"
    );
    assert!(!text.contains("  improvement:"), "{text}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    assert!(doc["improvement_pct"].is_null(), "{doc}");
    assert!(doc["tuned"]["lap_time_mean"].as_f64() < doc["default"]["lap_time_mean"].as_f64());
    let _ = std::fs::remove_dir_all(&out);
}
