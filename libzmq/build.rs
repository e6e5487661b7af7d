//! Builds libzmq from the `zeromq-src` sources with CURVE, linked against the system's
//! static libsodium (Debian's `libsodium-dev`; `scripts/setup.sh` installs it).
//!
//! The `zmq` crate's own build (zmq-sys) is switched off by the links override in
//! `.cargo/config.toml`, so this crate's libzmq is the one every binary links.

use std::path::PathBuf;

fn sodium_dirs() -> (PathBuf, PathBuf) {
    if let (Ok(lib), Ok(inc)) = (
        std::env::var("SODIUM_LIB_DIR"),
        std::env::var("SODIUM_INCLUDE_DIR"),
    ) {
        return (lib.into(), inc.into());
    }
    let pkg = |var: &str| {
        std::process::Command::new("pkg-config")
            .args([&format!("--variable={var}"), "libsodium"])
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .filter(|s| !s.is_empty())
    };
    let lib = pkg("libdir").unwrap_or_else(|| "/usr/lib/x86_64-linux-gnu".into());
    let inc = pkg("includedir").unwrap_or_else(|| "/usr/include".into());
    (lib.into(), inc.into())
}

fn main() {
    println!("cargo:rerun-if-env-changed=SODIUM_LIB_DIR");
    println!("cargo:rerun-if-env-changed=SODIUM_INCLUDE_DIR");
    let (lib, inc) = sodium_dirs();
    if !lib.join("libsodium.a").exists() && !lib.join("libsodium.so").exists() {
        panic!(
            "libsodium not found in {} (install Debian's libsodium-dev: scripts/setup.sh does)",
            lib.display()
        );
    }
    zeromq_src::Build::new()
        .with_libsodium(Some(zeromq_src::LibLocation::new(lib, inc)))
        .build();
}
