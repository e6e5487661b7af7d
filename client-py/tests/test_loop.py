"""The loop end to end, as a user runs it, with a network built here with the `onnx`
package (no torch): export it, check it against onnxruntime, benchmark it through a real
broker and worker processes (the model travels by its hash; the results equal the local
run's), race it as an env opponent, and drive the software-in-the-loop car with it over
ROS 2 (`paddock bridge sil` and `paddock bridge drive --driver model.onnx`): its SIL lap
matches the plain rollout from the same start within the bridge's transport tolerance.
Bad models are refused with an error naming the car that drives with them."""

from __future__ import annotations

import json
import math
import signal
import subprocess

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

import paddock  # noqa: E402
from _cluster import cluster  # noqa: E402
from paddock import errors  # noqa: E402
from paddock import onnx as ponnx  # noqa: E402
from paddock.server import find_paddock  # noqa: E402

BEAMS, FOV = 1080, 4.7


def centering_model(gain: float = 0.4, speed: float = 2.5) -> bytes:
    """A linear wall-centering policy on the scan: steering = gain * (mean range over the
    left sector - mean over the right; 0.3 to 1.6 rad off the heading), speed constant."""
    angles = -FOV / 2 + FOV * np.arange(BEAMS) / (BEAMS - 1)
    left = (angles >= 0.3) & (angles <= 1.6)
    right = (angles >= -1.6) & (angles <= -0.3)
    w = np.zeros((BEAMS, 2), dtype=np.float32)
    w[left, 0] = gain / left.sum()
    w[right, 0] = -gain / right.sum()
    b = np.array([0.0, speed], dtype=np.float32)
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["scans", "w"], ["m"]),
         helper.make_node("Add", ["m", "b"], ["action"])],
        "centering",
        [helper.make_tensor_value_info("scans", TensorProto.FLOAT, ["batch", BEAMS])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model.SerializeToString()


def paddock_json(*args: str) -> dict:
    out = subprocess.run([find_paddock(), *args, "--json"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_train_export_race_drive(tmp_path):
    model = tmp_path / "centering.onnx"
    model.write_bytes(centering_model())
    # export checked: Paddock's runtime and onnxruntime give the same actions
    assert ponnx.check(model, samples=8, seed=1).ok()

    bench = ("benchmark", "b1", "--driver", str(model), "--episodes", "2", "--laps", "1",
             "--time-limit", "60", "--seed", "5")
    local = paddock_json(*bench)
    assert local["success_rate"] == 1.0, local
    with cluster(2) as (front, _procs):
        # the model is stored in the broker once; both worker processes fetch it by hash
        assert paddock_json(*bench, "--endpoint", front) == local
        # an env opponent: the worker fetches the model for the session
        env = paddock.F110Env(endpoint=front, num_agents=2, opponents=[str(model)],
                              time_limit=5.0)
        try:
            obs, _ = env.reset(seed=3)
            start = np.array([obs["poses_x"][1], obs["poses_y"][1]])
            for _ in range(60):
                obs, *_ = env.step(np.array([0.0, 2.0], dtype=np.float32))
            moved = np.hypot(*(np.array([obs["poses_x"][1], obs["poses_y"][1]]) - start))
            assert moved > 0.5, "the model drives the opponent's car"
        finally:
            env.close()
        # a file that is not a model is refused by name, and the server goes on serving
        junk = tmp_path / "junk.onnx"
        junk.write_bytes(b"not a model")
        with pytest.raises(errors.ServerError) as e:
            paddock.F110Env(endpoint=front, num_agents=2, opponents=[str(junk)])
        assert e.value.field == "env_open.opponents[0].driver", e.value
        assert "not an ONNX model" in e.value.message
        assert paddock_json(*bench, "--endpoint", front) == local

    # the SIL car over ROS 2, from the rollout's start with its LIDAR noise seed
    rollout = paddock_json("rollout", "--driver", str(model), "--episodes", "1", "--laps", "1",
                           "--start-s", "0", "--time-limit", "120")
    episode = rollout["episodes"][0]
    want = episode["lap_times"][0]
    exe, domain = find_paddock(), "71"
    sil = subprocess.Popen(
        [exe, "bridge", "sil", "--map", "lakeside", "--rate", "2", "--scan-hz", "100",
         "--laps", "1", "--seconds", "120", "--start-s", "0", "--seed", str(episode["seed"]),
         "--wait-for-drive", "--json", "--domain-id", domain],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    drive = subprocess.Popen(
        [exe, "bridge", "drive", "--driver", str(model), "--max-speed", "20",
         "--sensor-timeout", "0.5", "--domain-id", domain, "--seconds", "100"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        sil_out, sil_err = sil.communicate(timeout=150)
    finally:
        drive.send_signal(signal.SIGINT)
        drive_out, drive_err = drive.communicate(timeout=30)
    assert sil.returncode == 0, sil_err
    assert drive.returncode == 0, drive_err
    assert "zero speed sent" in drive_out, drive_out
    summary = json.loads(sil_out)
    got = summary["lap_times"][0][0]
    assert summary["collision_steps"][0] == 0, summary
    assert math.isclose(got, want, rel_tol=0.01), (got, want)
