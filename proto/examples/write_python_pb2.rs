//! Writes the Python protobuf module of `paddock.proto` for the Python client
//! (`client-py/paddock/_proto/paddock_pb2.py`) with the vendored protoc, so no system
//! protoc is needed. Run it after every change to `paddock.proto`:
//!
//! ```text
//! cargo run -p paddock-proto --example write_python_pb2
//! ```
//!
//! The test `tests/python_pb2.rs` fails when the committed module has drifted.

use std::path::{Path, PathBuf};

/// Where the generated module is committed, relative to this crate.
pub const PB2_PATH: &str = "../client-py/paddock/_proto/paddock_pb2.py";

/// Generates `paddock_pb2.py` from `paddock.proto` into a fresh folder under `out` and
/// returns its text.
pub fn generate_pb2(out: &Path) -> Result<String, Box<dyn std::error::Error>> {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    std::fs::create_dir_all(out)?;
    let status = std::process::Command::new(&protoc)
        .arg(format!("--proto_path={}", crate_dir.display()))
        .arg(format!("--python_out={}", out.display()))
        .arg("paddock.proto")
        .current_dir(crate_dir)
        .status()?;
    if !status.success() {
        return Err(format!("{} failed: {status}", protoc.display()).into());
    }
    Ok(std::fs::read_to_string(out.join("paddock_pb2.py"))?)
}

/// The committed module's path.
pub fn pb2_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(PB2_PATH)
}

#[allow(dead_code)] // the drift test includes this file for `generate_pb2` only
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let tmp = std::env::temp_dir().join(format!("paddock-pb2-{}", std::process::id()));
    let text = generate_pb2(&tmp)?;
    let _ = std::fs::remove_dir_all(&tmp);
    let dest = pb2_path();
    std::fs::write(&dest, text)?;
    println!("wrote {}", dest.display());
    Ok(())
}
