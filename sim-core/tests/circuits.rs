//! Circuits (map + track) on the shipped maps and on the 24 real tracks in ../shared/maps:
//! every one loads, places cars, steps with scans; lookups by name; errors.

mod common;

use std::path::PathBuf;
use std::sync::Arc;

use paddock_sim::circuit::{Circuit, CircuitSource, Circuits, list_circuit_dirs};
use paddock_sim::track::TrackError;
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
        let c = Arc::new(Circuit::load(&d).unwrap());
        assert!(c.track.raceline().is_some(), "{} has a raceline", c.name);
        exercise(&c);
    }
    let default = Circuits::new().default_circuit().unwrap();
    assert_eq!(default.name, paddock_sim::circuit::DEFAULT_MAP);
}

#[test]
fn every_real_track_runs() {
    let Some(maps) = common::shared("maps") else {
        return;
    };
    let dirs = list_circuit_dirs(&maps);
    assert!(dirs.len() >= 20, "{dirs:?}");
    for d in dirs {
        let c = Arc::new(Circuit::load(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())));
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
    let circuits = Circuits::new();
    let a = circuits.get("lakeside").unwrap();
    let b = circuits.get("LAKESIDE").unwrap();
    assert!(Arc::ptr_eq(&a, &b));
    assert_eq!(circuits.loaded(), 1);
    // a clone shares what the registry loaded; another registry loads its own
    assert!(Arc::ptr_eq(
        &a,
        &circuits.clone().by_name("lakeside").unwrap()
    ));
    let other = Circuits::new().get("lakeside").unwrap();
    assert!(!Arc::ptr_eq(&a, &other));
    // by name, the map compiled into the library: the same map as the project's folder
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps/lakeside");
    let c = Circuit::load(&dir).unwrap();
    assert_eq!(a.map.content_hash(), c.map.content_hash());
    assert_eq!(a.track.length().to_bits(), c.track.length().to_bits());
    assert_eq!(a.name, c.name);
    // a folder loads once, by any spelling of its path or its map YAML's
    let f1 = circuits.load(&dir).unwrap();
    assert!(Arc::ptr_eq(&f1, &circuits.load(&dir.join(".")).unwrap()));
    assert!(Arc::ptr_eq(
        &f1,
        &circuits
            .get(&dir.join("lakeside_map.yaml").display().to_string())
            .unwrap()
    ));
    assert_eq!(circuits.loaded(), 2);
    let q = circuits.get("quarry").unwrap();
    assert!(!Arc::ptr_eq(&a.map, &q.map));
    assert_ne!(a.map.content_hash(), q.map.content_hash());
    assert_eq!(circuits.loaded(), 3);
}

#[test]
fn concurrent_lookups_load_a_circuit_once() {
    let circuits = Circuits::new();
    let got: Vec<Arc<Circuit>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| s.spawn(|| circuits.get("harbour").unwrap()))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(got.iter().all(|c| Arc::ptr_eq(c, &got[0])));
    assert_eq!(circuits.loaded(), 1);
}

/// Folders given to a registry are searched by name before the shipped maps, in order.
#[test]
fn given_folders_come_before_the_shipped_maps() {
    let tmp = std::env::temp_dir().join(format!("paddock-registry-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    // a folder called "lakeside" holding the harbour map's files
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps/harbour");
    let mine = tmp.join("lakeside");
    std::fs::create_dir_all(&mine).unwrap();
    for e in std::fs::read_dir(&src).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, mine.join(p.file_name().unwrap())).unwrap();
    }
    let circuits = Circuits::with_dirs([tmp.clone()]);
    assert_eq!(circuits.dirs(), std::slice::from_ref(&tmp));
    let c = circuits.by_name("Lakeside").unwrap();
    assert_eq!(c.name, "harbour");
    assert_eq!(c.dir(), Some(mine.canonicalize().unwrap().as_path()));
    let shipped = Circuits::new().by_name("lakeside").unwrap();
    assert_eq!(shipped.name, "lakeside");
    assert!(shipped.dir().is_none());
    // a name is never opened as a path
    let e = circuits.by_name(&src.display().to_string()).unwrap_err();
    assert!(matches!(e, TrackError::UnknownMap { .. }), "{e}");
    assert!(e.to_string().contains(&tmp.display().to_string()), "{e}");
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// A fresh clone's tests, sharing one cargo target directory with another checkout,
/// linked that checkout's build of this library and found maps through its source path
/// (`circuits_are_shared_and_found_by_name` failed). Shipped maps now come from the
/// library itself, loaded from its bytes: every map of the project's `maps/` resolves by
/// name to a shipped map (no folder at all) holding the same files.
#[test]
fn shipped_maps_are_not_found_through_a_source_path() {
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .unwrap();
    let dirs = list_circuit_dirs(&source.join("maps"));
    assert_eq!(dirs.len(), paddock_sim::shipped::shipped_maps().len());
    let circuits = Circuits::new();
    for d in dirs {
        let name = d.file_name().unwrap().to_str().unwrap();
        let c = circuits.get(name).unwrap();
        assert!(
            matches!(c.source, CircuitSource::Shipped(m) if m.name == name),
            "{name} found in {:?}",
            c.source
        );
        assert!(c.dir().is_none());
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
    let e = Circuits::new().get("no-such-track").unwrap_err();
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
