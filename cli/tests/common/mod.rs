//! What the CLI's end-to-end tests share: running the `paddock` binary built for them and
//! a scratch folder per test.

// each test binary uses the part it needs
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// Runs `paddock ARGS`: whether it succeeded, its stdout and its stderr.
pub fn paddock(args: &[&str]) -> (bool, String, String) {
    let (code, stdout, stderr) = paddock_status(args);
    (code == Some(0), stdout, stderr)
}

/// Runs `paddock ARGS`: its exit status (`None` if a signal ended it), stdout and stderr.
pub fn paddock_status(args: &[&str]) -> (Option<i32>, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(args)
        .output()
        .expect("run paddock");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// An empty folder `paddock-{suite}-{pid}-{name}` in the temporary directory.
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("paddock-{suite}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The JSON in file `path`.
pub fn read_json(path: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Runs `paddock sysid` on `recordings` into `out` with `args`, which must succeed
/// without a panic: its `report.json`, and its stdout.
pub fn sysid(
    recordings: &[&str],
    out: &std::path::Path,
    args: &[&str],
) -> (serde_json::Value, String) {
    let out_s = out.to_str().expect("a UTF-8 path");
    let mut all = vec!["sysid"];
    for r in recordings {
        all.extend(["--recording", r]);
    }
    all.extend(["--out", out_s]);
    all.extend(args);
    let (ok, stdout, err) = paddock(&all);
    assert!(ok, "paddock {}: {err}", all.join(" "));
    assert!(!err.contains("panicked"), "{err}");
    (read_json(&out.join("report.json")), stdout)
}
