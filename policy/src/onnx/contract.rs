//! The observation contract, checked on a model's protobuf before tract sees it: input
//! names and shapes, the action output, the metadata.

use tract_onnx::pb;

use super::{
    Feed, InputSlot, META_ACTION_REPEAT, META_LIDAR_FOV, OnnxError, PREV_ACTION, SCALAR_KEYS, SCANS,
};

fn dims_text(dims: &[Option<i64>]) -> String {
    let parts: Vec<String> = dims
        .iter()
        .map(|d| d.map_or_else(|| "?".to_string(), |v| v.to_string()))
        .collect();
    format!("[{}]", parts.join(", "))
}

/// The declared dims of a graph input (`None` for a symbolic or missing dim), or `None`
/// when the input declares no shape at all.
fn declared_dims(vi: &pb::ValueInfoProto) -> (i32, Option<Vec<Option<i64>>>) {
    use pb::tensor_shape_proto::dimension::Value;
    let Some(pb::type_proto::Value::TensorType(t)) =
        vi.r#type.as_ref().and_then(|t| t.value.as_ref())
    else {
        return (0, None);
    };
    let dims = t.shape.as_ref().map(|s| {
        s.dim
            .iter()
            .map(|d| match &d.value {
                Some(Value::DimValue(v)) => Some(*v),
                _ => None,
            })
            .collect()
    });
    (t.elem_type, dims)
}

pub(super) fn read_metadata(
    proto: &pb::ModelProto,
    model: &str,
) -> Result<(u32, Option<f64>), OnnxError> {
    let mut repeat = 1;
    let mut fov = None;
    for p in &proto.metadata_props {
        let bad = |message: &str| OnnxError::Metadata {
            model: model.into(),
            key: p.key.clone(),
            value: p.value.clone(),
            message: message.into(),
        };
        match p.key.as_str() {
            META_ACTION_REPEAT => {
                repeat = p
                    .value
                    .trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|&r| (1..=1000).contains(&r))
                    .ok_or_else(|| bad("expected an integer in [1, 1000]"))?;
            }
            META_LIDAR_FOV => {
                let v = p
                    .value
                    .trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v > 0.0 && *v <= 2.0 * std::f64::consts::PI)
                    .ok_or_else(|| bad("expected radians in (0, 2 pi]"))?;
                fov = Some(v);
            }
            _ => {}
        }
    }
    Ok((repeat, fov))
}

fn known_inputs() -> String {
    let mut k = vec![SCANS];
    k.extend(SCALAR_KEYS);
    k.push(PREV_ACTION);
    k.join(", ")
}

/// The graph inputs (initializers excluded), each checked against the contract.
pub(super) fn check_inputs(
    graph: &pb::GraphProto,
    model: &str,
) -> Result<Vec<InputSlot>, OnnxError> {
    let initializers: Vec<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let mut slots = Vec::new();
    for vi in graph
        .input
        .iter()
        .filter(|vi| !initializers.contains(&vi.name.as_str()))
    {
        let name = vi.name.clone();
        let feed = if name == SCANS {
            Feed::Scans { beams: 0 }
        } else if name == PREV_ACTION {
            Feed::PrevAction
        } else if let Some(key) = SCALAR_KEYS.iter().find(|k| **k == name) {
            Feed::Scalar(key)
        } else {
            return Err(OnnxError::UnknownInput {
                model: model.into(),
                input: name,
                known: known_inputs(),
            });
        };
        let (elem, dims) = declared_dims(vi);
        if elem != pb::tensor_proto::DataType::Float as i32 {
            let got = pb::tensor_proto::DataType::from_i32(elem)
                .map(|d| d.as_str_name().to_lowercase())
                .unwrap_or_else(|| format!("code {elem}"));
            return Err(OnnxError::InputType {
                model: model.into(),
                input: name,
                got,
            });
        }
        let expected = match feed {
            Feed::Scans { .. } => "[batch, beams] with a fixed beam count",
            Feed::Scalar(_) => "[batch] or [batch, 1]",
            Feed::PrevAction => "[batch, 2]",
        };
        let shape_err = |got: String| OnnxError::InputShape {
            model: model.into(),
            input: name.clone(),
            expected: expected.into(),
            got,
        };
        let Some(dims) = dims else {
            return Err(shape_err("no declared shape".into()));
        };
        let batch_ok = dims.first().is_some_and(|d| d.is_none() || *d == Some(1));
        let (feed, shape) = match (feed, &dims[..]) {
            (Feed::Scans { .. }, [_, Some(b)]) if batch_ok && *b > 0 => {
                (Feed::Scans { beams: *b as usize }, vec![1, *b as usize])
            }
            (Feed::Scalar(k), [_]) if batch_ok => (Feed::Scalar(k), vec![1]),
            (Feed::Scalar(k), [_, Some(1)]) if batch_ok => (Feed::Scalar(k), vec![1, 1]),
            (Feed::PrevAction, [_, Some(2)]) if batch_ok => (Feed::PrevAction, vec![1, 2]),
            _ => return Err(shape_err(dims_text(&dims))),
        };
        slots.push(InputSlot { name, feed, shape });
    }
    if slots.is_empty() {
        return Err(OnnxError::NoInputs {
            model: model.into(),
        });
    }
    Ok(slots)
}

/// The index of the action output: the one named `action`, or the only one.
pub(super) fn pick_output(graph: &pb::GraphProto, model: &str) -> Result<usize, OnnxError> {
    if let Some(i) = graph.output.iter().position(|o| o.name == "action") {
        return Ok(i);
    }
    match graph.output.len() {
        1 => Ok(0),
        n => Err(OnnxError::Output {
            model: model.into(),
            message: format!(
                "{n} outputs ({}) and none named \"action\"",
                graph
                    .output
                    .iter()
                    .map(|o| o.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}
