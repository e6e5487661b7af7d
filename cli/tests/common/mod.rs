//! What the CLI's end-to-end tests share: running the `paddock` binary built for them and
//! a scratch folder per test.

// each test binary uses the part it needs
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// Runs `paddock ARGS`: whether it succeeded, its stdout and its stderr.
pub fn paddock(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_paddock"))
        .args(args)
        .output()
        .expect("run paddock");
    (
        out.status.success(),
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
