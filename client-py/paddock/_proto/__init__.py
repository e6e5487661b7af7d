"""Generated protobuf code for paddock.proto (package paddock.v1).

Do not edit: regenerate with `cargo run -p paddock-proto --example write_python_pb2`.
"""
