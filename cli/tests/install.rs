//! The `paddock` binary away from the tree it was built from: the shipped maps travel
//! inside it.

use std::path::PathBuf;
use std::process::Command;

/// The bug this pins: maps were found through the source path compiled into the library
/// (`CARGO_MANIFEST_DIR/../maps`), so a binary copied elsewhere had no maps, and a fresh
/// clone sharing a cargo target directory with another checkout resolved maps from that
/// other tree. Here the binary runs from a folder with no maps beside it, with an empty
/// `PADDOCK_MAPS` and its own temporary directory, and every map of the project's `maps/`
/// must resolve by name with the bundle hash of that folder. Shipped maps load from the
/// binary's own bytes: nothing is written to the temporary directory (they were once
/// copied there first).
#[test]
fn copied_binary_does_not_find_maps_through_the_source_tree() {
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../maps");
    let tmp = std::env::temp_dir().join(format!("paddock-install-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(tmp.join("bin")).unwrap();
    std::fs::create_dir_all(tmp.join("tmp")).unwrap();
    let bin = tmp.join("bin/paddock");
    std::fs::copy(env!("CARGO_BIN_EXE_paddock"), &bin).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(&bin)
            .args(args)
            .current_dir(&tmp)
            .env("PADDOCK_MAPS", "")
            .env("TMPDIR", tmp.join("tmp"))
            .output()
            .expect("run the copied paddock");
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "paddock {args:?}: {stderr}");
        stdout
    };
    let listed: serde_json::Value =
        serde_json::from_str(&run(&["maps", "list", "--json"])).unwrap();
    let listed = listed.as_array().unwrap();
    let dirs = paddock_sim::circuit::list_circuit_dirs(&source);
    assert!(dirs.len() >= 3, "{dirs:?}");
    assert_eq!(listed.len(), dirs.len(), "{listed:?}");
    for d in &dirs {
        let name = d.file_name().unwrap().to_str().unwrap();
        let want = paddock_proto::read_map_dir(d, name).unwrap().hash;
        let row = listed
            .iter()
            .find(|r| r["name"] == name)
            .unwrap_or_else(|| panic!("{name} not listed: {listed:?}"));
        assert_eq!(row["source"], "shipped", "{row}");
        assert_eq!(row["path"], "(built in)", "{row}");
        assert_eq!(
            row["hash"],
            want.as_str(),
            "{name}: bundle hash of the folder"
        );
        // resolved by name and driven
        let perf: serde_json::Value = serde_json::from_str(&run(&[
            "perf",
            "--map",
            name,
            "--seconds",
            "0.1",
            "--no-scan",
            "--json",
        ]))
        .unwrap();
        assert_eq!(perf["map"], name);
    }
    let written: Vec<PathBuf> = std::fs::read_dir(tmp.join("tmp"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert!(
        written.is_empty(),
        "written to the temporary directory: {written:?}"
    );
    std::fs::remove_dir_all(&tmp).unwrap();
}
