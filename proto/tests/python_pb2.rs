//! The Python client's generated protobuf module must match `paddock.proto`: this fails
//! when the proto changed and `cargo run -p paddock-proto --example write_python_pb2`
//! was not run.

#[path = "../examples/write_python_pb2.rs"]
mod write_python_pb2;

#[test]
fn committed_python_pb2_is_up_to_date() {
    let tmp = std::env::temp_dir().join(format!("paddock-pb2-test-{}", std::process::id()));
    let fresh = write_python_pb2::generate_pb2(&tmp).expect("protoc runs");
    let _ = std::fs::remove_dir_all(&tmp);
    let path = write_python_pb2::pb2_path();
    let committed = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    assert!(
        committed == fresh,
        "{} is out of date with paddock.proto: run `cargo run -p paddock-proto --example write_python_pb2`",
        path.display()
    );
}
