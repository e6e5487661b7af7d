//! Every driver's defaults complete a lap on every shipped map and on every real track in
//! ../shared/maps, not only on the maps the project generates (whose corridors are wider
//! and whose racelines keep clear of the walls).
//!
//! One test per driver; inside it the tracks run in parallel (rayon), one lap each from a
//! seeded random start, with a time limit that grows with the lap length. Release mode:
//! `cargo test --release -p paddock-rollout --test real_tracks`.

use std::path::PathBuf;

use paddock_rollout::{Scenario, Termination, run_episode, task_seed};
use paddock_sim::circuit::{Circuits, list_circuit_dirs};
use rayon::prelude::*;

/// The shipped maps, by name.
const SHIPPED: [&str; 3] = ["lakeside", "quarry", "harbour"];

fn shared_maps() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("PADDOCK_SHARED") {
        return Some(PathBuf::from(p).join("maps"));
    }
    let mut dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    while let Some(parent) = dir.parent() {
        if parent.join("shared/maps").is_dir() {
            return Some(parent.join("shared/maps"));
        }
        dir = parent.to_path_buf();
    }
    if std::env::var("PADDOCK_ALLOW_MISSING_SHARED").as_deref() == Ok("1") {
        return None;
    }
    panic!("shared/maps not found: set PADDOCK_SHARED, or PADDOCK_ALLOW_MISSING_SHARED=1 to skip");
}

/// The shipped maps and (unless explicitly allowed to be missing) the real tracks.
fn every_track() -> Vec<String> {
    let mut maps: Vec<String> = SHIPPED.iter().map(|s| s.to_string()).collect();
    if let Some(dir) = shared_maps() {
        let dirs = list_circuit_dirs(&dir);
        assert!(
            dirs.len() >= 20,
            "{} real tracks in {}",
            dirs.len(),
            dir.display()
        );
        maps.extend(dirs.iter().map(|d| d.display().to_string()));
    }
    maps
}

/// One lap of `driver` with its defaults on every track; the failures, one line each.
fn lap_failures(driver: &str) -> Vec<String> {
    every_track()
        .par_iter()
        .enumerate()
        .filter_map(|(k, map)| {
            let circuit = Circuits::new().get(map).expect("track loads");
            let mut s = Scenario::single(driver).expect("registered");
            s.map = map.clone();
            // generous for a slow car: 1.2 m/s average over the lap, plus a start
            s.time_limit = 20.0 + circuit.track.length() / 1.2;
            let e = run_episode(
                &paddock_sim::circuit::Circuits::new(),
                &s,
                task_seed(7, k as u64),
                None,
            )
            .expect("episode runs");
            let a = &e.agents[0];
            (a.termination != Termination::Finished).then(|| {
                format!(
                    "{} seed {}: {:?} after {:.1} m of {:.1} m, {:.1} s",
                    e.map,
                    e.seed,
                    a.termination,
                    a.progress,
                    circuit.track.length(),
                    e.time
                )
            })
        })
        .collect()
}

fn laps_everywhere(driver: &str) {
    let failures = lap_failures(driver);
    assert!(failures.is_empty(), "{driver}: {failures:#?}");
}

#[test]
fn pure_pursuit_defaults_lap_every_track() {
    laps_everywhere("pure-pursuit");
}

#[test]
fn follow_the_gap_defaults_lap_every_track() {
    laps_everywhere("follow-the-gap");
}

#[test]
fn mlp_defaults_lap_every_track() {
    laps_everywhere("mlp");
}

#[test]
fn lattice_defaults_lap_every_track() {
    laps_everywhere("lattice");
}

#[test]
fn rrt_star_defaults_lap_every_track() {
    laps_everywhere("rrt-star");
}

/// Every registered driver has a test above: a new driver must be added here.
#[test]
fn every_registered_driver_is_covered() {
    let covered = [
        "pure-pursuit",
        "follow-the-gap",
        "mlp",
        "lattice",
        "rrt-star",
    ];
    for d in paddock_policy::drivers() {
        assert!(
            covered.contains(&d.name),
            "no real-track test for {}",
            d.name
        );
    }
}
