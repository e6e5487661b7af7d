"""The wheel a Python user installs: built by scripts/wheel.sh (from $PADDOCK_BIN, the
binary under test), installed (not editable) into a fresh venv in a temporary folder, and
run from a folder outside the checkout with nothing of the checkout in sight: the env
starts the `paddock` binary the wheel installed, shipped map names resolve through that
server, and a map given as a path is uploaded."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from importlib.metadata import version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

USER = textwrap.dedent("""
    import sys
    import gymnasium as gym
    import numpy as np
    import paddock
    from paddock.server import find_paddock

    venv, harbour = sys.argv[1], sys.argv[2]
    assert paddock.__file__.startswith(venv), paddock.__file__
    assert find_paddock() == venv + "/bin/paddock", find_paddock()
    for m in ("lakeside", "QUARRY", harbour):
        env = gym.make("paddock/F110-v0", map=m, num_beams=108, time_limit=5.0, threads=1)
        obs, _ = env.reset(seed=1)
        obs, reward, terminated, truncated, _ = env.step(
            np.zeros(env.action_space.shape, dtype=np.float32))
        assert obs["scans"].shape == (1, 108) and not terminated
        env.close()
        print("stepped", m)
""")


def run(args: list[str], **kw: object) -> subprocess.CompletedProcess[str]:
    p = subprocess.run(args, capture_output=True, text=True, **kw)  # type: ignore[call-overload]
    assert p.returncode == 0, f"{args}: {p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return p


def test_wheel_installs_and_runs_from_anywhere(tmp_path: Path) -> None:
    built = run(["bash", str(ROOT / "scripts" / "wheel.sh"), str(tmp_path / "dist")])
    wheel = Path(built.stdout.strip().splitlines()[-1])
    assert wheel.is_file() and wheel.name.startswith("paddock-") and "-py3-none-linux" in wheel.name

    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", str(venv)])
    # the dependency versions this test run uses, so the fresh venv is like it
    pins = tmp_path / "constraints.txt"
    pins.write_text("".join(f"{d}=={version(d)}\n" for d in ("pyzmq", "protobuf", "gymnasium", "numpy")))
    run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
         "-c", str(pins), str(wheel)])

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    script = elsewhere / "user.py"
    script.write_text(USER)
    env = {k: v for k, v in os.environ.items()
           if k not in ("PADDOCK_BIN", "PADDOCK_MAPS", "CARGO_TARGET_DIR", "PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = "/usr/bin:/bin"
    out = run([str(venv / "bin" / "python"), str(script), str(venv), str(ROOT / "maps" / "harbour")],
              cwd=elsewhere, env=env)
    assert out.stdout.count("stepped") == 3, out.stdout
