"""paddock.onnx.check: a small network built with the `onnx` package (no torch) runs in
onnxruntime and in Paddock's Rust runtime with the same actions; a model that breaks the
observation contract is refused with Paddock's message naming the input."""

from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from paddock import onnx as ponnx  # noqa: E402


def mlp_model(beams: int = 64, hidden: int = 16, seed: int = 0) -> bytes:
    """scans [batch, beams] + linear_vels_x [batch, 1] -> tanh MLP -> action [batch, 2]."""
    rng = np.random.default_rng(seed)
    w1 = rng.normal(0, 0.2, (beams + 1, hidden)).astype(np.float32)
    b1 = rng.normal(0, 0.1, hidden).astype(np.float32)
    w2 = rng.normal(0, 0.5, (hidden, 2)).astype(np.float32)
    b2 = np.array([0.0, 3.0], dtype=np.float32)
    nodes = [
        helper.make_node("Concat", ["scans", "linear_vels_x"], ["x"], axis=1),
        helper.make_node("Gemm", ["x", "w1", "b1"], ["h"]),
        helper.make_node("Tanh", ["h"], ["t"]),
        helper.make_node("Gemm", ["t", "w2", "b2"], ["action"]),
    ]
    graph = helper.make_graph(
        nodes, "policy",
        [helper.make_tensor_value_info("scans", TensorProto.FLOAT, ["batch", beams]),
         helper.make_tensor_value_info("linear_vels_x", TensorProto.FLOAT, ["batch", 1])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])],
        [numpy_helper.from_array(a, n) for a, n in
         [(w1, "w1"), (b1, "b1"), (w2, "w2"), (b2, "b2")]],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    helper.set_model_props(model, {"paddock.action_repeat": "2"})
    onnx.checker.check_model(model)
    return model.SerializeToString()


def test_rust_and_onnxruntime_agree(tmp_path):
    path = tmp_path / "mlp.onnx"
    path.write_bytes(mlp_model())
    report = ponnx.check(path, samples=16, seed=3)
    assert [i["name"] for i in report.inputs] == ["scans", "linear_vels_x"]
    assert report.rust_actions.shape == (16, 2)
    # the samples differ, so the comparison is not of one action 16 times
    assert len({tuple(a) for a in report.rust_actions.tolist()}) == 16
    assert report.max_abs_diff < 1e-5, report
    assert report.ok()
    doc = ponnx.rust_actions(path, samples=2, seed=3)
    assert doc["action_repeat"] == 2 and doc["beams"] == 64
    # the same seed gives the same inputs and the same action bits
    assert doc["samples"] == ponnx.rust_actions(path, samples=2, seed=3)["samples"]


def test_a_model_breaking_the_contract_is_refused_by_name(tmp_path):
    graph = helper.make_graph(
        [helper.make_node("Identity", ["lidar"], ["action"])], "bad",
        [helper.make_tensor_value_info("lidar", TensorProto.FLOAT, ["batch", 2])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])],
    )
    path = tmp_path / "bad.onnx"
    path.write_bytes(helper.make_model(graph).SerializeToString())
    with pytest.raises(ValueError, match='input "lidar" is not an observation key'):
        ponnx.check(path)
    text = tmp_path / "notes.onnx"
    text.write_text("not a model")
    with pytest.raises(ValueError, match="not an ONNX model"):
        ponnx.check(text)
