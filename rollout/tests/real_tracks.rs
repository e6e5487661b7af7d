//! Driver defaults complete laps on every real track in ../shared/maps, not only on the
//! maps the project generates (whose corridors are wider and whose racelines keep clear
//! of the walls).

use std::path::PathBuf;

use paddock_rollout::{Scenario, Termination, run_episode, task_seed};
use paddock_sim::track::list_circuit_dirs;

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

fn laps_everywhere(driver: &str) {
    let Some(maps) = shared_maps() else { return };
    let dirs = list_circuit_dirs(&maps);
    assert!(dirs.len() >= 20);
    let mut failures = Vec::new();
    for d in &dirs {
        let mut s = Scenario::single(driver).unwrap();
        s.map = d.display().to_string();
        s.time_limit = 400.0;
        for k in 0..2 {
            let e = run_episode(&s, task_seed(7, k), None).unwrap();
            let a = &e.agents[0];
            if a.termination != Termination::Finished {
                failures.push(format!(
                    "{} seed {}: {:?} after {:.1} m",
                    e.map, e.seed, a.termination, a.progress
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{driver}: {failures:#?}");
}

#[test]
fn pure_pursuit_defaults_lap_every_real_track() {
    laps_everywhere("pure-pursuit");
}
