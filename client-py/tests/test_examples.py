"""Every example runs in its short mode against the test server."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("script", ["cma_pure_pursuit.py", "es_mlp.py"])
def test_example_quick(script: str, endpoint: str) -> None:
    out = subprocess.run([sys.executable, str(EXAMPLES / script), "--quick", "--endpoint", endpoint],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["seconds"] > 0
    if script == "cma_pure_pursuit.py":
        assert result["episodes"] == 2 * 4 * 2
        assert result["best_cost"] <= result["default_cost"] * 1.5
    else:
        assert result["generations"] >= 1


def test_sb3_example_compiles_and_runs_where_sb3_is_installed(endpoint: str, tmp_path) -> None:
    """The SB3 example needs torch, which the tests do not install: it must compile; with
    stable-baselines3 installed its smoke run trains, exports, checks and benchmarks."""
    script = EXAMPLES / "sb3_ppo_lidar.py"
    compile(script.read_text(), str(script), "exec")
    pytest.importorskip("stable_baselines3")
    out = subprocess.run([sys.executable, str(script), "--quick", "--endpoint", endpoint,
                          "--out", str(tmp_path / "ppo.onnx")],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["steps"] == 2048 and result["train_seconds"] > 0
    assert "largest difference" in out.stdout
