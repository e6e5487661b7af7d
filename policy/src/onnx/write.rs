//! A minimal ONNX writer: small models built in code as protobuf with tract-onnx's own
//! ONNX types, for tests and examples (no Python, no model files checked in). The
//! builders at the end write the models the tests and docs use.

use prost::Message;
use tract_onnx::pb;
use tract_onnx::pb::tensor_proto::DataType;

/// A dim of a declared input/output shape.
#[derive(Clone, Copy)]
pub enum D {
    /// The symbolic batch dim.
    Batch,
    N(i64),
}

pub fn value_info(name: &str, elem: DataType, dims: &[D]) -> pb::ValueInfoProto {
    use pb::tensor_shape_proto::{Dimension, dimension::Value};
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            denotation: String::new(),
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: elem as i32,
                shape: Some(pb::TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|d| Dimension {
                            denotation: String::new(),
                            value: Some(match d {
                                D::Batch => Value::DimParam("batch".into()),
                                D::N(n) => Value::DimValue(*n),
                            }),
                        })
                        .collect(),
                }),
            })),
        }),
        doc_string: String::new(),
    }
}

pub fn f32_input(name: &str, dims: &[D]) -> pb::ValueInfoProto {
    value_info(name, DataType::Float, dims)
}

pub fn f32_tensor(name: &str, dims: &[i64], data: &[f32]) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: DataType::Float as i32,
        float_data: data.to_vec(),
        ..Default::default()
    }
}

pub fn i64_tensor(name: &str, dims: &[i64], data: &[i64]) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: DataType::Int64 as i32,
        int64_data: data.to_vec(),
        ..Default::default()
    }
}

pub fn node(op: &str, inputs: &[&str], outputs: &[&str]) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: outputs.iter().map(|s| s.to_string()).collect(),
        name: format!("{op}_{}", outputs[0]),
        ..Default::default()
    }
}

pub fn with_int_attr(mut n: pb::NodeProto, name: &str, v: i64) -> pb::NodeProto {
    n.attribute.push(pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i: v,
        ..Default::default()
    });
    n
}

/// A model: nodes, graph inputs, outputs, initializers, metadata; opset 13.
pub struct Model {
    pub nodes: Vec<pb::NodeProto>,
    pub inputs: Vec<pb::ValueInfoProto>,
    pub outputs: Vec<pb::ValueInfoProto>,
    pub initializers: Vec<pb::TensorProto>,
    pub metadata: Vec<(String, String)>,
}

impl Model {
    pub fn new(nodes: Vec<pb::NodeProto>, inputs: Vec<pb::ValueInfoProto>) -> Self {
        Self {
            nodes,
            inputs,
            outputs: vec![f32_input("action", &[D::Batch, D::N(2)])],
            initializers: Vec::new(),
            metadata: Vec::new(),
        }
    }

    pub fn init(mut self, t: pb::TensorProto) -> Self {
        self.initializers.push(t);
        self
    }

    pub fn meta(mut self, k: &str, v: &str) -> Self {
        self.metadata.push((k.into(), v.into()));
        self
    }

    pub fn bytes(&self) -> Vec<u8> {
        pb::ModelProto {
            ir_version: 8,
            opset_import: vec![pb::OperatorSetIdProto {
                domain: String::new(),
                version: 13,
            }],
            producer_name: "paddock".into(),
            graph: Some(pb::GraphProto {
                name: "policy".into(),
                node: self.nodes.clone(),
                input: self.inputs.clone(),
                output: self.outputs.clone(),
                initializer: self.initializers.clone(),
                ..Default::default()
            }),
            metadata_props: self
                .metadata
                .iter()
                .map(|(k, v)| pb::StringStringEntryProto {
                    key: k.clone(),
                    value: v.clone(),
                })
                .collect(),
            ..Default::default()
        }
        .encode_to_vec()
    }
}

/// action = scans @ w + b: w is [beams, 2] row-major, b [2].
pub fn linear_on_scans(beams: usize, w: &[f32], b: [f32; 2]) -> Model {
    assert_eq!(w.len(), beams * 2);
    Model::new(
        vec![
            node("MatMul", &["scans", "w"], &["wx"]),
            node("Add", &["wx", "b"], &["action"]),
        ],
        vec![f32_input("scans", &[D::Batch, D::N(beams as i64)])],
    )
    .init(f32_tensor("w", &[beams as i64, 2], w))
    .init(f32_tensor("b", &[2], &b))
}

/// action = [poses_theta, linear_vels_x] * k + prev_action, with poses_theta as
/// [batch, 1] and linear_vels_x as [batch] (reshaped in the graph).
pub fn scalars_and_prev(k: [f32; 2]) -> Model {
    Model::new(
        vec![
            node("Reshape", &["linear_vels_x", "col"], &["v"]),
            with_int_attr(node("Concat", &["poses_theta", "v"], &["tv"]), "axis", 1),
            node("Mul", &["tv", "k"], &["tvk"]),
            node("Add", &["tvk", "prev_action"], &["action"]),
        ],
        vec![
            f32_input("poses_theta", &[D::Batch, D::N(1)]),
            f32_input("linear_vels_x", &[D::Batch]),
            f32_input("prev_action", &[D::Batch, D::N(2)]),
        ],
    )
    .init(i64_tensor("col", &[2], &[-1, 1]))
    .init(f32_tensor("k", &[1, 2], &k))
}

/// action = [log(poses_x), log(poses_x)]: NaN when poses_x < 0.
pub fn log_of_x() -> Model {
    Model::new(
        vec![
            node("Log", &["poses_x"], &["l"]),
            with_int_attr(node("Concat", &["l", "l"], &["action"]), "axis", 1),
        ],
        vec![f32_input("poses_x", &[D::Batch, D::N(1)])],
    )
}

/// A linear wall-centering policy on a `beams`-beam scan spanning `fov` rad: steering =
/// `gain` * (mean range over the left sector - mean over the right), sectors from 0.3 to
/// 1.6 rad either side of the heading; speed = `speed` m/s. A reference model for tests
/// and the docs' examples, not a good driver.
pub fn centering_on_scans(beams: usize, fov: f64, gain: f32, speed: f32) -> Model {
    let angle = |i: usize| -fov / 2.0 + fov * i as f64 / (beams - 1) as f64;
    let left: Vec<bool> = (0..beams)
        .map(|i| (0.3..=1.6).contains(&angle(i)))
        .collect();
    let right: Vec<bool> = (0..beams)
        .map(|i| (-1.6..=-0.3).contains(&angle(i)))
        .collect();
    let nl = left.iter().filter(|b| **b).count().max(1) as f32;
    let nr = right.iter().filter(|b| **b).count().max(1) as f32;
    let mut w = Vec::with_capacity(beams * 2);
    for i in 0..beams {
        let s = if left[i] {
            gain / nl
        } else if right[i] {
            -gain / nr
        } else {
            0.0
        };
        w.extend([s, 0.0]);
    }
    linear_on_scans(beams, &w, [0.0, speed]).meta(super::META_LIDAR_FOV, &fov.to_string())
}

/// action = [log(linear_vels_x - 1)] twice: NaN while the car is slower than 1 m/s, so
/// from the first step of an episode.
pub fn nan_when_slow() -> Model {
    Model::new(
        vec![
            node("Sub", &["linear_vels_x", "one"], &["v1"]),
            node("Log", &["v1"], &["l"]),
            with_int_attr(node("Concat", &["l", "l"], &["action"]), "axis", 1),
        ],
        vec![f32_input("linear_vels_x", &[D::Batch, D::N(1)])],
    )
    .init(f32_tensor("one", &[1], &[1.0]))
}
