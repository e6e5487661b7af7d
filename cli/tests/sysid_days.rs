//! `paddock sysid` on concealed short test days, over seeded repeats: each effect the
//! real cars' data brought into the vocabulary (`steering_gain`, `speed_gain`,
//! `steering_backlash`, `measurement_delay`) is hidden in test days made by
//! `paddock sysid synth --runs N --manoeuvre ...` (steering steps, arcs and speed steps at
//! low and racing speeds, pose and speed only, 20-50 Hz), and must be found within 30 % in
//! every repeat (in nine of ten within 30 % of its distance from "off"), with nothing else
//! kept and an interval that covers the truth in at least 90 % of them. Run in
//! release (`cargo test --release --workspace --test sysid_days`).

mod common;

use common::paddock;

use std::path::PathBuf;

use serde_json::Value;

fn scratch(name: &str) -> PathBuf {
    common::scratch("sysid-days", name)
}

/// One repeat's outcome for the hidden effect.
#[derive(Debug)]
struct Outcome {
    seed: u64,
    /// The fitted value when the effect was kept.
    fitted: Option<f64>,
    /// Its interval.
    interval: Option<[f64; 2]>,
    /// Other effects kept.
    others: Vec<String>,
}

/// `paddock sysid synth ARGS --out DAY`, which must succeed.
fn synth(day: &str, args: &[&str]) {
    let mut all = vec!["sysid", "synth"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", day]);
    let (ok, _, err) = paddock(&all);
    assert!(ok, "synth {day}: {err}");
}

/// A small pose-and-speed day of `manoeuvres` in `dir/day` (six runs, the wheels turning
/// 80 % of the command); its path.
fn gain_day(dir: &std::path::Path, manoeuvres: &str) -> String {
    let day = dir.join("day").to_str().unwrap().to_string();
    synth(
        &day,
        &[
            "--manoeuvre",
            manoeuvres,
            "--runs",
            "6",
            "--channels",
            "pose+speed",
            "--effect",
            "steering_gain:gain=0.8",
            "--seed",
            "5",
        ],
    );
    day
}

/// A test day: `runs` runs of `manoeuvres`, pose and speed only at `rate` Hz, with
/// `effect` hidden; analysed with `candidates`; the outcome for the hidden effect.
fn day(effect: &str, param: &str, manoeuvres: &str, candidates: &str, seed: u64) -> Outcome {
    let name = format!("{}-{seed}", effect.split(':').next().unwrap());
    let dir = scratch(&name);
    let day = dir.join("day");
    let day_s = day.to_str().unwrap().to_string();
    // the logging rate and the starts vary with the seed: 20 to 50 Hz
    let rate = ["20", "30", "40", "50"][(seed % 4) as usize];
    let seed_s = seed.to_string();
    synth(
        &day_s,
        &[
            "--manoeuvre",
            manoeuvres,
            "--runs",
            "12",
            "--rate",
            rate,
            "--channels",
            "pose+speed",
            "--effect",
            effect,
            "--seed",
            &seed_s,
        ],
    );
    let out = dir.join("out");
    let (report, _) = common::sysid(&[&day_s], &out, &["--effects", candidates, "--no-plots"]);
    let hidden = effect.split(':').next().unwrap();
    let kept: Vec<&Value> = report["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["significant"] == true)
        .collect();
    let mine = kept.iter().find(|e| e["name"] == hidden);
    let outcome = Outcome {
        seed,
        fitted: mine.map(|e| e["params"][param].as_f64().unwrap()),
        interval: mine.map(|e| {
            let iv = &e["interval"][param];
            [iv[0].as_f64().unwrap(), iv[1].as_f64().unwrap()]
        }),
        others: kept
            .iter()
            .filter(|e| e["name"] != hidden)
            .map(|e| e["name"].as_str().unwrap().to_string())
            .collect(),
    };
    let _ = std::fs::remove_dir_all(dir);
    outcome
}

/// `repeats` seeded test days with `effect` (param = truth) hidden: found within 30 % in
/// each, nothing else kept, the interval covering the truth in at least 90 % of them.
fn seeded_repeats(
    effect: &str,
    param: &str,
    truth: f64,
    off: f64,
    manoeuvres: &str,
    candidates: &str,
) {
    const REPEATS: u64 = 10;
    let outcomes: Vec<Outcome> = (1..=REPEATS)
        .map(|seed| day(effect, param, manoeuvres, candidates, seed))
        .collect();
    // within 30 % of the true value in every repeat, and in nine of ten within 30 % of
    // the effect's size (its distance from "off": stricter for a gain)
    let by_size = 0.3 * (truth - off).abs();
    let mut near = 0;
    for o in &outcomes {
        let f = o
            .fitted
            .unwrap_or_else(|| panic!("{effect}: not found with seed {}: {o:?}", o.seed));
        assert!(
            (f - truth).abs() <= 0.3 * truth.abs(),
            "{effect}: seed {} fitted {param} {f}, true {truth}",
            o.seed
        );
        near += usize::from((f - truth).abs() <= by_size);
        assert!(
            o.others.is_empty(),
            "{effect}: seed {} also kept {:?}",
            o.seed,
            o.others
        );
    }
    assert!(
        near * 10 >= 9 * outcomes.len(),
        "{effect}: within {by_size} of {truth} in {near} of {}: {:?}",
        outcomes.len(),
        outcomes.iter().map(|o| o.fitted).collect::<Vec<_>>()
    );
    let covered = outcomes
        .iter()
        .filter(|o| {
            o.interval
                .is_some_and(|[lo, hi]| lo <= truth && truth <= hi)
        })
        .count();
    assert!(
        covered * 10 >= 9 * outcomes.len(),
        "{effect}: intervals cover {truth} in {covered} of {}: {:?}",
        outcomes.len(),
        outcomes
            .iter()
            .map(|o| (o.seed, o.fitted, o.interval))
            .collect::<Vec<_>>()
    );
}

#[test]
fn steering_gain_over_seeded_test_days() {
    seeded_repeats(
        "steering_gain:gain=0.85",
        "gain",
        0.85,
        1.0,
        "step,arc,speed-step",
        "steering_gain,steering_offset,friction",
    );
}

#[test]
fn speed_gain_over_seeded_test_days() {
    seeded_repeats(
        "speed_gain:gain=1.1",
        "gain",
        1.1,
        1.0,
        "speed-step,step,arc",
        "speed_gain,drive_lag,drag",
    );
}

#[test]
fn steering_backlash_over_seeded_test_days() {
    seeded_repeats(
        "steering_backlash:width_rad=0.05",
        "width_rad",
        0.05,
        0.0,
        "step,arc,speed-step",
        "steering_backlash,steering_offset,steering_gain",
    );
}

/// A pose latency among the actuation delays it can be mistaken for. It failed while the
/// replay placed each run's start from samples that, with a latency, still showed the car
/// before the run (a spurious `drive_lag` on seven days of ten, one fit 34 % off), and
/// while that start jumped each time a sample crossed it (`sysid/src/replay/start.rs`).
#[test]
fn measurement_delay_over_seeded_test_days() {
    seeded_repeats(
        "measurement_delay:delay_s=0.06",
        "delay_s",
        0.06,
        0.0,
        "step,speed-step,arc",
        "measurement_delay,steering_delay,drive_lag",
    );
}

/// Recordings with different channels fitted together (a pose-and-speed day and runs
/// with vy and yaw_rate too): the held-out error is scored in every channel some
/// recording measures (it was NaN for vy and yaw_rate when a held-out group lacked them).
#[test]
fn recordings_with_different_channels_are_scored_in_every_channel() {
    let dir = scratch("mixed-channels");
    let mut recs = Vec::new();
    // two full runs first, then six pose-only ones: whole runs are held out in turn
    // (run k in group k mod 3), so one group has no vy or yaw_rate at all
    for (name, channels, runs, seed) in [
        ("full", "all", "2", "32"),
        ("pose", "pose+speed", "6", "31"),
    ] {
        let d = dir.join(name);
        let d_s = d.to_str().unwrap().to_string();
        synth(
            &d_s,
            &[
                "--manoeuvre",
                "step,arc,speed-step",
                "--runs",
                runs,
                "--channels",
                channels,
                "--effect",
                "steering_gain:gain=0.8",
                "--seed",
                seed,
            ],
        );
        recs.push(d_s);
    }
    let out = dir.join("out");
    let (report, stdout) = common::sysid(
        &[&recs[0], &recs[1]],
        &out,
        &["--effects", "steering_gain", "--no-plots"],
    );
    assert_eq!(report["recording"]["runs"].as_array().unwrap().len(), 8);
    assert_eq!(report["effects"][0]["significant"], true, "{stdout}");
    for c in ["x", "y", "yaw", "vx", "vy", "yaw_rate"] {
        let before = report["fit"]["rmse_before"][c].as_f64();
        let after = report["fit"]["rmse_after"][c].as_f64();
        assert!(
            before.is_some_and(f64::is_finite) && after.is_some_and(f64::is_finite),
            "{c}: {before:?} -> {after:?}\n{stdout}"
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Every candidate not kept says how large it could be without these data telling,
/// multi-parameter ones too (drag, tire_saturation and friction_patch said nothing): each
/// scanned parameter gets a range from "off", with the parameters held named.
#[test]
fn every_candidate_not_kept_says_what_it_could_be() {
    let dir = scratch("could-be");
    let day_s = gain_day(&dir, "step,arc,speed-step");
    let out = dir.join("out");
    let (report, stdout) = common::sysid(
        &[&day_s],
        &out,
        &[
            "--effects",
            "steering_gain,drag,tire_saturation,friction_patch,drive_lag",
            "--no-plots",
        ],
    );
    let effects = report["effects"].as_array().unwrap();
    let scanned = |name: &str| -> &[&str] {
        match name {
            "drag" => &["c_lin", "c_quad"],
            "tire_saturation" => &["D"],
            "friction_patch" => &["mu"],
            _ => &["tau_s"],
        }
    };
    let mut not_kept = 0;
    for e in effects.iter().filter(|e| e["significant"] == false) {
        not_kept += 1;
        let name = e["name"].as_str().unwrap();
        let range = &e["not_detected_range"];
        for p in scanned(name) {
            let r = &range[*p];
            let (lo, hi) = (r[0].as_f64(), r[1].as_f64());
            assert!(
                lo.zip(hi).is_some_and(|(lo, hi)| lo < hi),
                "{name}.{p}: {range}\n{stdout}"
            );
        }
        let multi = name != "drive_lag";
        assert_eq!(e["not_detected_with"].is_object(), multi, "{name}: {e}");
    }
    assert_eq!(not_kept, 4, "{stdout}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "c_lin could be anywhere in [0.0000, ",
        "(c_lin 0 held)",
        "(C 1.5, E 0 held)",
        "could peak as low as",
        "mu could be anywhere in [",
    ] {
        assert!(md.contains(needle), "{needle}:\n{md}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Pixels of `png` inside columns `x0..x1` that carry colour (not white, grey or black).
fn coloured_pixels(png: &std::path::Path, x0: u32, x1: u32) -> usize {
    let img = image::open(png).unwrap().to_rgb8();
    img.enumerate_pixels()
        .filter(|(x, _, p)| {
            let [r, g, b] = p.0;
            *x >= x0 && *x < x1 && r.max(g).max(b) - r.min(g).min(b) > 60
        })
        .count()
}

/// The residual map of a pose-and-speed day is coloured by the residual of the channels
/// measured (every sample was black: the missing vy and yaw_rate made each score NaN),
/// with its colour scale beside the two maps.
#[test]
fn residual_map_of_a_pose_only_day_is_coloured_with_a_scale() {
    let dir = scratch("map");
    let day_s = gain_day(&dir, "step,arc");
    let out = dir.join("out");
    let _ = common::sysid(&[&day_s], &out, &["--effects", "steering_gain"]);
    let png = out.join("residual_by_place.png");
    let (w, _) = image::image_dimensions(&png).unwrap();
    // the two maps, then the colour bar in the last 110 columns
    let maps = coloured_pixels(&png, 0, w - 110);
    let bar = coloured_pixels(&png, w - 110, w);
    assert!(maps > 2000, "{maps} coloured pixels on the maps");
    assert!(bar > 2000, "{bar} coloured pixels in the colour bar");
    let _ = std::fs::remove_dir_all(dir);
}
