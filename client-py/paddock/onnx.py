"""Check an exported ONNX policy against the Rust runtime that drives it in Paddock.

:func:`check` runs the model in onnxruntime and in Paddock's own runtime (tract, through
``paddock onnx-check``, which also checks the model against the observation contract) on
the same seeded sample inputs, and reports the largest difference between their actions.
``pip install onnxruntime`` is needed for it; nothing else in the client needs it.

The observation contract (input names, shapes, the action output) is in docs/onnx.md.
"""

from __future__ import annotations

import json
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .server import find_paddock


@dataclass
class CheckReport:
    """What :func:`check` found: the model's inputs as Paddock feeds them, the actions of
    both runtimes on each sample, and the largest absolute difference."""

    model: str
    sha256: str
    inputs: list[dict]
    rust_actions: np.ndarray
    onnxruntime_actions: np.ndarray
    max_abs_diff: float
    samples: list[dict] = field(repr=False, default_factory=list)

    def ok(self, atol: float = 1e-5) -> bool:
        return self.max_abs_diff <= atol


def rust_actions(path: str | Path, samples: int = 8, seed: int = 0,
                 binary: str | None = None) -> dict:
    """``paddock onnx-check`` on the model: its inputs and raw actions on sample inputs, as
    the JSON document it prints. Raises ``ValueError`` with Paddock's message when the
    model breaks the contract."""
    exe = binary or find_paddock()
    out = subprocess.run(
        [exe, "onnx-check", str(path), "--samples", str(samples), "--seed", str(seed)],
        capture_output=True, text=True, check=False,
    )
    if out.returncode != 0:
        raise ValueError(f"paddock refused {path}: {out.stderr.strip()}")
    return json.loads(out.stdout)


def check(path: str | Path, samples: int = 8, seed: int = 0,
          binary: str | None = None) -> CheckReport:
    """Run the model in onnxruntime and in Paddock's Rust runtime on the same ``samples``
    seeded inputs; report the largest absolute difference of the raw (unclamped) actions."""
    import onnxruntime as ort

    doc = rust_actions(path, samples=samples, seed=seed, binary=binary)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out_names = [o.name for o in sess.get_outputs()]
    action_name = "action" if "action" in out_names else out_names[0]
    shapes = {i["name"]: i["shape"] for i in doc["inputs"]}
    rust, ref = [], []
    for s in doc["samples"]:
        feeds = {name: np.asarray(v, dtype=np.float32).reshape(shapes[name])
                 for name, v in s["inputs"].items()}
        (a,) = sess.run([action_name], feeds)
        ref.append(np.asarray(a, dtype=np.float32).reshape(2))
        rust.append(np.asarray(s["action"], dtype=np.float32))
    rust_a, ref_a = np.array(rust).reshape(-1, 2), np.array(ref).reshape(-1, 2)
    diff = np.abs(rust_a.astype(np.float64) - ref_a.astype(np.float64))
    # a NaN in either runtime is a difference, not a match
    max_diff = float(np.nanmax(np.where(np.isnan(diff), np.inf, diff))) if diff.size else 0.0
    return CheckReport(model=str(path), sha256=doc["sha256"], inputs=doc["inputs"],
                       rust_actions=rust_a, onnxruntime_actions=ref_a,
                       max_abs_diff=max_diff, samples=doc["samples"])
