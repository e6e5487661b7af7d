//! Circuits (map + track) on the shipped maps and on the 24 real tracks in ../shared/maps:
//! every one loads, places cars, steps with scans; lookups by name; errors.

mod common;

use std::path::PathBuf;
use std::sync::Arc;

use paddock_sim::track::{Circuit, TrackError, list_circuit_dirs};
use paddock_sim::world::{Action, Starts, World, WorldConfig};

fn exercise(circuit: &Arc<Circuit>) {
    let l = circuit.track.length();
    assert!(l > 20.0, "{}: length {l}", circuit.name);
    let mut cfg = WorldConfig::with_agents(2);
    cfg.obstacles.count = 4;
    for seed in 0..3 {
        let mut w = World::new(circuit.clone(), cfg.clone()).unwrap();
        w.reset(seed, &Starts::Random)
            .unwrap_or_else(|e| panic!("{}: seed {seed}: {e}", circuit.name));
        let obs = w.observation().unwrap();
        assert!(obs.collisions.iter().all(|c| !c), "{}", circuit.name);
        // a car on the track sees walls within 30 m in most directions
        let near = obs.scan(0).iter().filter(|&&r| r < 29.9).count();
        assert!(near > 500, "{}: only {near} beams hit", circuit.name);
        for _ in 0..50 {
            w.step(&[Action::new(0.0, 1.0), Action::new(0.0, 1.0)])
                .unwrap();
        }
        assert!(
            w.observation().unwrap().progress[0] > 0.1,
            "{}",
            circuit.name
        );
    }
}

#[test]
fn every_shipped_map_runs() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps");
    let dirs = list_circuit_dirs(&dir);
    assert!(dirs.len() >= 3, "shipped maps: {dirs:?}");
    for d in dirs {
        let c = Circuit::load(&d).unwrap();
        assert!(c.track.raceline().is_some(), "{} has a raceline", c.name);
        exercise(&c);
    }
    let default = Circuit::default_circuit().unwrap();
    assert_eq!(default.name, paddock_sim::track::DEFAULT_MAP);
}

#[test]
fn every_real_track_runs() {
    let Some(maps) = common::shared("maps") else {
        return;
    };
    let dirs = list_circuit_dirs(&maps);
    assert!(dirs.len() >= 20, "{dirs:?}");
    for d in dirs {
        let c = Circuit::load(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display()));
        exercise(&c);
        // progress along the raceline's own direction agrees with the centerline's
        let Some(r) = c.track.raceline() else {
            continue;
        };
        let a = c.track.project(r[0].x, r[0].y);
        let b = c.track.project(r[10].x, r[10].y);
        assert!(
            c.track.ds(a.s, b.s) > 0.0,
            "{}: raceline runs backwards",
            c.name
        );
    }
}

#[test]
fn circuits_are_shared_and_found_by_name() {
    let a = Circuit::resolve("lakeside", &[]).unwrap();
    let b = Circuit::resolve("LAKESIDE", &[]).unwrap();
    assert!(Arc::ptr_eq(&a, &b));
    // by name, the map compiled into the library: the same map as the project's folder
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps/lakeside");
    let c = Circuit::load(&dir).unwrap();
    assert_eq!(a.map.content_hash(), c.map.content_hash());
    assert_eq!(a.track.length().to_bits(), c.track.length().to_bits());
    assert!(Arc::ptr_eq(&a, &Circuit::load(&a.dir).unwrap()));
    let q = Circuit::resolve("quarry", &[]).unwrap();
    assert!(!Arc::ptr_eq(&a.map, &q.map));
    assert_ne!(a.map.content_hash(), q.map.content_hash());
}

/// A fresh clone's tests, sharing one cargo target directory with another checkout,
/// linked that checkout's build of this library and found maps through its source path
/// (`circuits_are_shared_and_found_by_name` failed). Shipped maps now come from the
/// library itself: every map of the project's `maps/` resolves by name to a folder
/// outside the source tree, holding the same files.
#[test]
fn shipped_maps_are_not_found_through_a_source_path() {
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .unwrap();
    let dirs = list_circuit_dirs(&source.join("maps"));
    assert_eq!(dirs.len(), paddock_sim::shipped::shipped_maps().len());
    for d in dirs {
        let name = d.file_name().unwrap().to_str().unwrap();
        let c = Circuit::resolve(name, &[]).unwrap();
        let found = c.dir.canonicalize().unwrap();
        assert!(
            !found.starts_with(&source),
            "{name} found in {}",
            found.display()
        );
        assert_eq!(
            c.map.content_hash(),
            Circuit::load(&d).unwrap().map.content_hash()
        );
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .map(|p| {
                let n = p.file_name().unwrap().to_str().unwrap().to_string();
                (n, std::fs::read(&p).unwrap())
            })
            .collect();
        files.sort();
        let m = paddock_sim::shipped::shipped_map(name).unwrap();
        let shipped: Vec<(String, Vec<u8>)> = m
            .files
            .iter()
            .map(|(n, data)| (n.to_string(), data.to_vec()))
            .collect();
        assert_eq!(files, shipped, "{name}: the shipped files are the folder's");
    }
}

#[test]
fn unknown_and_broken_maps_are_clear_errors() {
    let e = Circuit::resolve("no-such-track", &[]).unwrap_err();
    assert!(matches!(e, TrackError::UnknownMap { .. }));
    assert!(e.to_string().contains("no-such-track"), "{e}");
    // a directory with a map but a garbled centerline
    let tmp = std::env::temp_dir().join(format!("paddock-circuit-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps/harbour");
    std::fs::create_dir_all(&tmp).unwrap();
    for f in ["harbour_map.yaml", "harbour_map.png"] {
        std::fs::copy(src.join(f), tmp.join(f)).unwrap();
    }
    let e = Circuit::load(&tmp).unwrap_err();
    assert!(e.to_string().contains("centerline"), "{e}");
    std::fs::write(
        tmp.join("harbour_centerline.csv"),
        "# x_m, y_m, w_tr_right_m, w_tr_left_m\n0.0, 0.0, 1.0, 1.0\n1.0, nan, 1.0, 1.0\n",
    )
    .unwrap();
    let e = Circuit::load(&tmp).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("line 3") && msg.contains("column 2"), "{msg}");
    std::fs::remove_dir_all(&tmp).unwrap();
}
