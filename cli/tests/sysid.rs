//! `paddock sysid` end to end: effects hidden in synthetic recordings are found with
//! their parameters, a control with nothing hidden reports nothing, the fitted vehicle
//! loads and replays the recording better than the nominal one, and bad input gets a
//! clear error. Run in release (`cargo test --release -p paddock --test sysid`): each case
//! writes a 40-s recording and analyses it.

mod common;

use common::paddock;

use std::path::{Path, PathBuf};

use paddock_sim::params::VehicleParams;
use paddock_sysid::recording::{Recording, RecordingTopics};
use paddock_sysid::replay::Replay;
use serde_json::Value;

fn scratch(name: &str) -> PathBuf {
    common::scratch("sysid-test", name)
}

/// Write a recording with `effects` hidden, analyse it, return (report, truth, dir).
fn synth_and_analyse(
    name: &str,
    seed: u64,
    effects: &[&str],
    extra: &[&str],
) -> (Value, Value, PathBuf) {
    let dir = scratch(name);
    let rec = dir.join("rec.csv");
    let seed = seed.to_string();
    let mut args = vec!["sysid", "synth", "--seconds", "40", "--seed", &seed];
    for e in effects {
        args.push("--effect");
        args.push(e);
    }
    let rec_s = rec.to_str().unwrap().to_string();
    args.extend(["--out", &rec_s]);
    let (ok, _, err) = paddock(&args);
    assert!(ok, "synth {name}: {err}");
    let (report, stdout) = common::sysid(&[&rec_s], &dir.join("out"), extra);
    assert!(stdout.contains("held-out rmse"), "{stdout}");
    let truth = common::read_json(&dir.join("rec.csv.truth.json"));
    (report, truth, dir)
}

/// Absolute tolerance floor per parameter (for tiny true values).
fn floor(param: &str) -> f64 {
    match param {
        "delay_s" => 0.01,
        "tau_s" => 0.02,
        "offset_rad" => 0.005,
        "c_lin" => 0.03,
        "c_quad" => 0.01,
        "mu" => 0.05,
        "D" | "C" => 0.1,
        "E" => 0.3,
        _ => 0.0,
    }
}

/// Recorded samples inside a box.
fn inside(rec: &Recording, b: &[f64]) -> Vec<usize> {
    rec.states
        .iter()
        .enumerate()
        .filter(|(_, s)| s.x >= b[0] && s.x <= b[2] && s.y >= b[1] && s.y <= b[3])
        .map(|(i, _)| i)
        .collect()
}

/// Exactly the hidden effects are significant, each parameter within 30 % (or the
/// floor); a friction patch must cover the same stretch of the recorded path.
fn check_found(name: &str, report: &Value, truth: &Value, dir: &Path) {
    let effects = report["effects"].as_array().unwrap();
    let kept: Vec<&str> = effects
        .iter()
        .filter(|e| e["significant"] == true)
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    let hidden: Vec<&str> = truth["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    let mut a = kept.clone();
    let mut b = hidden.clone();
    a.sort();
    b.sort();
    assert_eq!(a, b, "{name}: kept {kept:?}, hidden {hidden:?}\n{report:#}");
    for t in truth["effects"].as_array().unwrap() {
        let ename = t["name"].as_str().unwrap();
        let fitted = effects.iter().find(|e| e["name"] == ename).unwrap();
        for (param, tv) in t["params"].as_object().unwrap() {
            if param == "region" {
                let rec =
                    Recording::load(&dir.join("rec.csv"), &RecordingTopics::default()).unwrap();
                let tb: Vec<f64> = tv
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                let fb: Vec<f64> = fitted["params"]["region"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                let (ti, fi) = (inside(&rec, &tb), inside(&rec, &fb));
                let common = ti.iter().filter(|i| fi.contains(i)).count();
                let union = ti.len() + fi.len() - common;
                let jaccard = common as f64 / union.max(1) as f64;
                assert!(
                    jaccard >= 0.6,
                    "{name}: patch covers other samples: jaccard {jaccard:.2}, true {tb:?}, fitted {fb:?}"
                );
                continue;
            }
            let tv = tv.as_f64().unwrap();
            let fv = fitted["params"][param].as_f64().unwrap();
            let tol = (0.3 * tv.abs()).max(floor(param));
            assert!(
                (fv - tv).abs() <= tol,
                "{name}: {ename}.{param} fitted {fv}, true {tv} (tolerance {tol})"
            );
        }
    }
    // the fit improves held-out data, down towards the noise floor
    let fit = &report["fit"];
    let mut better = 0;
    for c in ["x", "y", "yaw", "vx", "vy", "yaw_rate"] {
        let before = fit["rmse_before"][c].as_f64().unwrap();
        let after = fit["rmse_after"][c].as_f64().unwrap();
        let noise = fit["noise_floor"][c].as_f64().unwrap();
        assert!(
            after <= before * 1.02,
            "{name}: {c} worse after fitting: {after} > {before}"
        );
        // the fitted vehicle replays the recording to about the noise floor
        let replayed = fit["rmse_fitted_in_sample"][c].as_f64().unwrap();
        assert!(
            replayed <= 2.0 * noise,
            "{name}: {c} replay rmse {replayed} not near the noise {noise}"
        );
        better += (after < 0.9 * before) as usize;
    }
    assert!(better >= 1, "{name}: no channel improved\n{fit:#}");
}

fn case(name: &str, seed: u64, effects: &[&str]) {
    let (report, truth, dir) = synth_and_analyse(name, seed, effects, &["--no-plots"]);
    check_found(name, &report, &truth, &dir);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn steering_delay_alone() {
    case("delay", 31, &["steering_delay:delay_s=0.05"]);
}

#[test]
fn steering_lag_alone() {
    case("lag", 32, &["steering_lag:tau_s=0.08"]);
}

#[test]
fn steering_offset_alone() {
    case("offset", 33, &["steering_offset:offset_rad=0.02"]);
}

#[test]
fn drive_lag_alone() {
    case("drive_lag", 34, &["drive_lag:tau_s=0.25"]);
}

#[test]
fn drag_alone() {
    case("drag", 35, &["drag:c_lin=0.3,c_quad=0.05"]);
}

#[test]
fn friction_alone() {
    case("friction", 36, &["friction:mu=0.7"]);
}

#[test]
fn friction_patch_alone() {
    case("patch", 37, &["friction_patch:mu=0.55"]);
}

#[test]
fn tire_saturation_alone() {
    case("tire", 38, &["tire_saturation:D=0.7,C=1.6,E=0"]);
}

#[test]
fn steering_delay_with_drag() {
    case(
        "delay+drag",
        21,
        &["steering_delay:delay_s=0.05", "drag:c_lin=0.25,c_quad=0.05"],
    );
}

#[test]
fn friction_patch_with_drive_lag() {
    case(
        "patch+drive_lag",
        22,
        &["friction_patch:mu=0.55", "drive_lag:tau_s=0.25"],
    );
}

#[test]
fn control_reports_nothing_and_the_fitted_vehicle_loads() {
    let (report, _, dir) = synth_and_analyse("control", 40, &[], &[]);
    let kept: Vec<&Value> = report["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["significant"] == true)
        .collect();
    assert!(kept.is_empty(), "false positive on the control: {kept:?}");
    // every effect of the vocabulary is a default candidate
    assert_eq!(
        report["effects"].as_array().unwrap().len(),
        paddock_sysid::effects::ALL.len()
    );
    let md = std::fs::read_to_string(dir.join("out/report.md")).unwrap();
    assert!(md.contains("Nothing significant"), "{md}");
    for plot in [
        "timeseries.png",
        "residual_by_place.png",
        "residual_by_regime.png",
    ] {
        let img = image::open(dir.join("out").join(plot)).unwrap();
        assert!(img.width() > 500, "{plot}");
    }
    let v = VehicleParams::load(dir.join("out/vehicle.yaml")).unwrap();
    assert!(v.effects.all_off());
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn fitted_vehicle_loads_and_replays_better_than_nominal() {
    let (report, truth, dir) = synth_and_analyse(
        "yaml",
        41,
        &["steering_offset:offset_rad=-0.015", "drive_lag:tau_s=0.3"],
        &[],
    );
    check_found("yaml", &report, &truth, &dir);
    let fitted = VehicleParams::load(dir.join("out/vehicle.yaml")).unwrap();
    assert!(fitted.effects.steering_offset.is_some() && fitted.effects.drive_lag.is_some());
    // the written file drives the simulator wherever it runs: `--vehicle` changes the laps
    let yaml = dir.join("out/vehicle.yaml");
    let lap = |vehicle: Option<&Path>| {
        let mut args = vec!["rollout", "--episodes", "2", "--seed", "3", "--json"];
        if let Some(v) = vehicle {
            args.extend(["--vehicle", v.to_str().unwrap()]);
        }
        let (ok, out, err) = paddock(&args);
        assert!(ok, "{err}");
        serde_json::from_str::<Value>(&out).unwrap()["episodes"].clone()
    };
    assert_ne!(
        lap(None),
        lap(Some(&yaml)),
        "the fitted car drives differently"
    );
    let rec = Recording::load(&dir.join("rec.csv"), &RecordingTopics::default()).unwrap();
    let replay = Replay::new(&rec, 1.0);
    let nominal: f64 = replay.window_costs(&VehicleParams::default()).iter().sum();
    let with: f64 = replay.window_costs(&fitted).iter().sum();
    assert!(with < 0.5 * nominal, "fitted {with} vs nominal {nominal}");
    let md = std::fs::read_to_string(dir.join("out/report.md")).unwrap();
    assert!(
        md.contains("steering_offset") && md.contains("drive_lag"),
        "{md}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn mcap_recordings_with_custom_topics() {
    let dir = scratch("mcap");
    let rec = dir.join("rec.mcap");
    let rec_s = rec.to_str().unwrap();
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--seconds",
        "30",
        "--seed",
        "5",
        "--effect",
        "steering_offset:offset_rad=0.02",
        "--out",
        rec_s,
    ]);
    assert!(ok, "{err}");
    // the bag uses /drive and /odom; asking for other topics names the ones present
    let out = dir.join("out");
    let out_s = out.to_str().unwrap();
    let (ok, _, err) = paddock(&[
        "sysid",
        "--recording",
        rec_s,
        "--out",
        out_s,
        "--drive-topic",
        "/car/drive",
    ]);
    assert!(!ok);
    assert!(err.contains("/car/drive") && err.contains("/odom"), "{err}");
    let (report, _) = common::sysid(
        &[rec_s],
        &out,
        &[
            "--drive-topic",
            "/drive",
            "--odom-topic",
            "/odom",
            "--effects",
            "steering_offset,drag",
            "--no-plots",
        ],
    );
    let offset = report["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "steering_offset")
        .unwrap();
    assert_eq!(offset["significant"], true, "{report:#}");
    let v = offset["params"]["offset_rad"].as_f64().unwrap();
    assert!((v - 0.02).abs() < 0.006, "{v}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn bad_recordings_get_clear_errors() {
    let dir = scratch("bad");
    let out = dir.join("out");
    let out_s = out.to_str().unwrap();
    let header = "t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate\n";
    let rows = |n: usize| -> String {
        (0..n)
            .map(|i| {
                format!(
                    "{},0.0,1.0,{},0,0,1,0,0\n",
                    i as f64 * 0.025,
                    i as f64 * 0.025
                )
            })
            .collect()
    };
    let cases: Vec<(&str, Vec<u8>, Vec<&str>)> = vec![
        (
            "garbled.csv",
            vec![0xff, 0xfe, 0x00, 0x13, 0x88, 0x01, 0xc3],
            vec!["not UTF-8"],
        ),
        (
            "noise.csv",
            b"hello world\nthis is not a recording\n".to_vec(),
            vec!["missing column", "t"],
        ),
        (
            "missing.csv",
            b"t,steer_cmd,x,y,yaw,vx,vy,yaw_rate\n0,0,0,0,0,0,0,0\n".to_vec(),
            vec!["missing column", "speed_cmd"],
        ),
        // a bad row is skipped and named; what is left is too short
        (
            "nan.csv",
            format!("{header}{}1.0,0.1,NaN,0,0,0,0,0,0\n", rows(40)).into_bytes(),
            vec!["row 42", "speed_cmd", "NaN", "too short"],
        ),
        (
            "text.csv",
            format!("{header}{}1.0,0.1,fast,0,0,0,0,0,0\n", rows(40)).into_bytes(),
            vec!["row 42", "speed_cmd", "fast", "too short"],
        ),
        (
            "short.csv",
            format!("{header}{}", rows(60)).into_bytes(),
            vec!["too short", "60 samples", "record more"],
        ),
        (
            "backwards.csv",
            format!("{header}{}0.5,0,0,0,0,0,0,0,0\n", rows(40)).into_bytes(),
            vec!["stray", "too short"],
        ),
        (
            "ragged.csv",
            format!("{header}{}1.0,0.1,2\n", rows(40)).into_bytes(),
            vec!["row 42", "fields", "too short"],
        ),
        (
            "all-bad.csv",
            format!("{header}x,y,z,0,0,0,0,0,0\n").into_bytes(),
            vec!["no usable rows", "row 2"],
        ),
        ("empty.csv", Vec::new(), vec!["empty"]),
        (
            "bad.mcap",
            b"\x89MCAP0\r\nnot really".to_vec(),
            vec!["MCAP"],
        ),
    ];
    for (file, bytes, needles) in cases {
        let path = dir.join(file);
        std::fs::write(&path, bytes).unwrap();
        let (ok, _, err) = paddock(&[
            "sysid",
            "--recording",
            path.to_str().unwrap(),
            "--out",
            out_s,
        ]);
        assert!(!ok, "{file} was accepted");
        assert!(!err.contains("panicked"), "{file}: {err}");
        for n in needles {
            assert!(err.contains(n), "{file}: expected {n:?} in: {err}");
        }
    }
    let (ok, _, err) = paddock(&["sysid", "--recording", "/no/such/rec.csv", "--out", out_s]);
    assert!(!ok && err.contains("/no/such/rec.csv"), "{err}");
    let (ok, _, err) = paddock(&["sysid", "--out", out_s]);
    assert!(!ok && err.contains("--recording"), "{err}");
    let rec = dir.join("x.csv");
    let rec_s = rec.to_str().unwrap();
    let (ok, _, err) = paddock(&["sysid", "synth", "--effect", "warp_drive", "--out", rec_s]);
    assert!(
        !ok && err.contains("warp_drive") && err.contains("steering_delay"),
        "{err}"
    );
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--effect",
        "drag:c_lin=-1",
        "--out",
        rec_s,
    ]);
    assert!(!ok && err.contains("c_lin") && err.contains("-1"), "{err}");
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--effect",
        "steering_lag:tau=0.1",
        "--out",
        rec_s,
    ]);
    assert!(!ok && err.contains("tau_s"), "{err}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn synth_is_deterministic_per_seed() {
    let dir = scratch("det");
    let (a, b, c) = (dir.join("a.csv"), dir.join("b.csv"), dir.join("c.csv"));
    for (p, seed) in [(&a, "7"), (&b, "7"), (&c, "8")] {
        let (ok, _, err) = paddock(&[
            "sysid",
            "synth",
            "--seconds",
            "8",
            "--seed",
            seed,
            "--effect",
            "drag",
            "--out",
            p.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
    }
    let read = |p: &PathBuf| std::fs::read(p).unwrap();
    assert_eq!(read(&a), read(&b));
    assert_ne!(read(&a), read(&c));
    let rec = Recording::load(&a, &RecordingTopics::default()).unwrap();
    // about 40 Hz with jitter and a few dropped rows
    let rate = rec.states.len() as f64 / rec.duration();
    assert!((36.0..41.0).contains(&rate), "{rate} Hz");
    let gaps: Vec<f64> = rec.states.windows(2).map(|w| w[1].t - w[0].t).collect();
    assert!(gaps.iter().any(|g| *g > 0.04), "no dropped row");
    assert!(gaps.iter().any(|g| (*g - 0.025).abs() > 0.002), "no jitter");
    let _ = std::fs::remove_dir_all(dir);
}

/// Real logs' shape: epoch timestamps, a byte-order mark, NaN and text rows, a ragged last
/// line, a stray row far in the future and a long gap (two runs) are read, reported and
/// analysed, not refused (each used to abort, hang or reject the file).
#[test]
fn real_logs_shape_is_read_not_refused() {
    let dir = scratch("shape");
    let rec = dir.join("rec.csv");
    let rec_s = rec.to_str().unwrap().to_string();
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--seconds",
        "12",
        "--seed",
        "3",
        "--effect",
        "steering_offset:offset_rad=0.03",
        "--out",
        &rec_s,
    ]);
    assert!(ok, "{err}");
    let text = std::fs::read_to_string(&rec).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let epoch = 1_732_000_000.0;
    for (i, l) in lines.iter_mut().enumerate().skip(1) {
        let (t, rest) = l.split_once(',').unwrap();
        let mut t: f64 = t.parse().unwrap();
        if t > 6.0 {
            t += 4.0; // a 4 s gap: a second run
        }
        *l = format!("{:.4},{rest}", epoch + t);
        if i == 100 {
            l.push_str("\n1732100000.0,0,0,0,0,0,0,0,0");
            l.push_str(&format!(
                "\n{:.4},NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN",
                epoch + t + 0.001
            ));
            l.push_str(&format!("\n{:.4},0.1,fast,0,0,0,0,0,0", epoch + t + 0.002));
        }
    }
    let messy = format!("\u{feff}{}\n1732000099.0,0.1,2\n", lines.join("\n"));
    std::fs::write(&rec, messy).unwrap();
    let out = dir.join("out");
    let (report, stdout) = common::sysid(
        &[&rec_s],
        &out,
        &[
            "--effects",
            "steering_offset",
            "--no-plots",
            "--threads",
            "2",
        ],
    );
    assert!(stdout.contains("steering_offset"), "{stdout}");
    let warnings = report["recording"]["warnings"].to_string();
    for needle in ["stray", "rows skipped", "fast", "split into 2 runs"] {
        assert!(warnings.contains(needle), "{needle}: {warnings}");
    }
    let runs = report["recording"]["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2, "{runs:?}");
    assert_eq!(runs[0]["t_offset"].as_f64().unwrap(), epoch);
    let _ = std::fs::remove_dir_all(dir);
}

/// A test day of short runs (3 s steps, arcs and speed steps, half starting in motion),
/// with only the pose and the VESC speed at 30 Hz: a steering calibration error is found
/// jointly over all runs, whole runs are held out, the interval covers the truth, and the
/// report gives the corrected VESC values.
#[test]
fn many_short_pose_and_speed_runs_find_a_steering_gain() {
    let dir = scratch("day");
    let day = dir.join("day");
    let day_s = day.to_str().unwrap().to_string();
    let (ok, stdout, err) = paddock(&[
        "sysid",
        "synth",
        "--manoeuvre",
        "step,arc,speed-step",
        "--runs",
        "12",
        "--rate",
        "30",
        "--channels",
        "pose+speed",
        "--effect",
        "steering_gain:gain=0.8",
        "--seed",
        "11",
        "--out",
        &day_s,
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("12 runs"), "{stdout}");
    let first = std::fs::read_to_string(day.join("run-01.csv")).unwrap();
    assert!(
        first.starts_with("t,steer_cmd,speed_cmd,x,y,yaw,vx\n"),
        "{first}"
    );
    let vesc = dir.join("vesc.yaml");
    std::fs::write(
        &vesc,
        "/**:\n  ros__parameters:\n    speed_to_erpm_gain: 4614.0\n    speed_to_erpm_offset: 0.0\n    steering_angle_to_servo_gain: -1.2135\n    steering_angle_to_servo_offset: 0.5304\n",
    )
    .unwrap();
    let out = dir.join("out");
    let (report, _) = common::sysid(
        &[&day_s],
        &out,
        &[
            "--effects",
            "steering_gain,steering_offset,steering_delay,speed_gain",
            "--vesc-config",
            vesc.to_str().unwrap(),
        ],
    );
    assert_eq!(report["recording"]["runs"].as_array().unwrap().len(), 12);
    assert_eq!(
        report["recording"]["channels_missing"],
        serde_json::json!(["vy", "yaw_rate"])
    );
    assert!(
        report["fit"]["heldout"]
            .as_str()
            .unwrap()
            .contains("whole runs")
    );
    let kept: Vec<&Value> = report["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["significant"] == true)
        .collect();
    assert_eq!(kept.len(), 1, "{report:#}");
    assert_eq!(kept[0]["name"], "steering_gain");
    let g = kept[0]["params"]["gain"].as_f64().unwrap();
    assert!((g - 0.8).abs() <= 0.3 * 0.2, "gain {g}");
    let iv = &kept[0]["interval"]["gain"];
    let (lo, hi) = (iv[0].as_f64().unwrap(), iv[1].as_f64().unwrap());
    assert!(
        lo <= 0.8 && 0.8 <= hi && hi - lo < 0.2,
        "interval [{lo}, {hi}]"
    );
    let servo = report["vesc"]["steering_angle_to_servo_gain"]["new"]
        .as_f64()
        .unwrap();
    assert!((servo - (-1.2135 / g)).abs() < 1e-3, "{servo}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "12 runs",
        "wheels turn",
        "steering_angle_to_servo_gain",
        "Not measured: vy, yaw_rate",
        "could be anywhere",
    ] {
        assert!(md.contains(needle), "{needle}:\n{md}");
    }
    for plot in [
        "timeseries.png",
        "residual_by_place.png",
        "residual_by_regime.png",
    ] {
        assert!(out.join(plot).exists(), "{plot}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Play in the steering linkage, found from steering steps and their reversals.
#[test]
fn steering_backlash_on_a_test_day() {
    let dir = scratch("backlash");
    let day = dir.join("day");
    let day_s = day.to_str().unwrap().to_string();
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--manoeuvre",
        "step",
        "--runs",
        "8",
        "--effect",
        "steering_backlash:width_rad=0.06",
        "--seed",
        "12",
        "--out",
        &day_s,
    ]);
    assert!(ok, "{err}");
    let out = dir.join("out");
    let (report, _) = common::sysid(
        &[&day_s],
        &out,
        &[
            "--effects",
            "steering_backlash,steering_gain,steering_lag",
            "--no-plots",
        ],
    );
    let kept: Vec<&Value> = report["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["significant"] == true)
        .collect();
    assert!(
        !kept.is_empty() && kept[0]["name"] == "steering_backlash",
        "{report:#}"
    );
    let w = kept[0]["params"]["width_rad"].as_f64().unwrap();
    assert!((w - 0.06).abs() <= 0.3 * 0.06, "width {w}");
    let v = VehicleParams::load(out.join("vehicle.yaml")).unwrap();
    assert!(v.effects.steering_backlash.is_some());
    let _ = std::fs::remove_dir_all(dir);
}

/// A steering delay and a lag trade off: on a test day the tool either separates them
/// (each within 30 %) or says they are not separable, and the total dead time it gives is
/// right either way, never a confident wrong pair.
#[test]
fn delay_and_lag_together_are_found_or_reported_ambiguous() {
    let dir = scratch("delay-lag");
    let day = dir.join("day");
    let day_s = day.to_str().unwrap().to_string();
    let (ok, _, err) = paddock(&[
        "sysid",
        "synth",
        "--manoeuvre",
        "step,arc,speed-step",
        "--runs",
        "12",
        "--effect",
        "steering_delay:delay_s=0.06",
        "--effect",
        "steering_lag:tau_s=0.08",
        "--seed",
        "21",
        "--out",
        &day_s,
    ]);
    assert!(ok, "{err}");
    let out = dir.join("out");
    let (report, _) = common::sysid(
        &[&day_s],
        &out,
        &[
            "--no-plots",
            "--effects",
            "steering_delay,steering_lag,measurement_delay,steering_gain",
        ],
    );
    let kept = |n: &str| {
        report["effects"]
            .as_array()
            .unwrap()
            .iter()
            .find(|e| e["name"] == n && e["significant"] == true)
            .map(|e| {
                e["params"]
                    .as_object()
                    .unwrap()
                    .values()
                    .next()
                    .unwrap()
                    .as_f64()
                    .unwrap()
            })
    };
    let delay = kept("steering_delay").unwrap_or(0.0);
    let lag = kept("steering_lag").unwrap_or(0.0);
    let latency = kept("measurement_delay").unwrap_or(0.0);
    let both_right = (delay - 0.06).abs() <= 0.018 && (lag - 0.08).abs() <= 0.024;
    let ambiguities = report["ambiguities"].to_string();
    let flagged = ambiguities.contains("steering_delay") && ambiguities.contains("steering_lag");
    assert!(
        both_right || flagged,
        "delay {delay}, lag {lag}: {ambiguities}"
    );
    let dead = delay + lag + latency;
    assert!(
        (dead - 0.14).abs() <= 0.3 * 0.14,
        "effective dead time {dead}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// `--threads 0` means one thread per core, as for every command with `--threads` (it was
/// refused here with a wording of its own).
#[test]
fn threads_zero_is_one_per_core_as_everywhere() {
    let dir = scratch("threads-zero");
    let rec = dir.join("rec.csv");
    let rec_s = rec.to_str().unwrap();
    let (ok, _, err) = paddock(&["sysid", "synth", "--seconds", "10", "--out", rec_s]);
    assert!(ok, "{err}");
    let (report, _) = common::sysid(
        &[rec_s],
        &dir.join("out"),
        &["--effects", "steering_gain", "--no-plots", "--threads", "0"],
    );
    assert!(report["effects"].is_array(), "{report}");
    let _ = std::fs::remove_dir_all(dir);
}
