"""What a Python user installs, away from the checkout: into a fresh venv in a temporary
folder, first `pip install ./client-py` (not editable, with $PADDOCK_BIN, the binary
under test), then the wheel scripts/wheel.sh builds from that binary. Each is run from a
folder outside the checkout: shipped map names resolve through the server (nothing is
read beside the installed package), a map given as a path is uploaded, and with the wheel
the env starts the `paddock` binary the wheel installed, with nothing else in sight; and
`endpoint=paddock.IN_PROCESS` loads the in-process simulator's library the wheel put
beside the package (the plain package: the one beside $PADDOCK_BIN). The wheel also goes
into fresh venvs of the oldest Python the package supports (3.10) and the newest on the
machine (3.13), with the versions of its dependencies that Python gets."""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys
import textwrap
from importlib.metadata import version
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

USER = textwrap.dedent("""
    import sys
    import gymnasium as gym
    import numpy as np
    import paddock
    from paddock.inprocess import find_library
    from paddock.server import find_paddock

    venv, harbour, binary, library = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
    assert paddock.__file__.startswith(venv), paddock.__file__
    assert find_paddock() == binary, find_paddock()
    assert find_library() == library, find_library()
    for endpoint in (None, paddock.IN_PROCESS):
        for m in ("lakeside", "QUARRY", harbour):
            env = gym.make("paddock/F110-v0", endpoint=endpoint, map=m, num_beams=108,
                           time_limit=5.0, threads=1)
            obs, _ = env.reset(seed=1)
            obs, reward, terminated, truncated, _ = env.step(
                np.zeros(env.action_space.shape, dtype=np.float32))
            assert obs["scans"].shape == (1, 108) and not terminated
            env.close()
            print("stepped", m, endpoint)
    # 16 envs' scans (69 KB) are written by the library into the array this process gets
    vec = paddock.make_vec(16, paddock.IN_PROCESS, num_beams=1080, time_limit=5.0)
    vec.reset(seed=1)
    obs = vec.step(np.zeros((16, 2), dtype=np.float32))[0]
    assert obs["scans"].shape == (16, 1, 1080) and not obs["scans"].flags.writeable
    assert (obs["scans"] > 0).all()
    vec.close()
    print("16 envs in place")
""")


def run(args: list[str], **kw: object) -> subprocess.CompletedProcess[str]:
    p = subprocess.run(args, capture_output=True, text=True, **kw)  # type: ignore[call-overload]
    assert p.returncode == 0, f"{args}: {p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return p


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel scripts/wheel.sh builds (from $PADDOCK_BIN when set)."""
    built = run(["bash", str(ROOT / "scripts" / "wheel.sh"), str(tmp_path_factory.mktemp("dist"))])
    path = Path(built.stdout.strip().splitlines()[-1])
    assert path.is_file() and path.name.startswith("paddock-") and "-py3-none-linux" in path.name
    return path


def user_env() -> dict[str, str]:
    """This test's environment without the checkout's settings: what a user has."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PADDOCK_BIN", "PADDOCK_MAPS", "PADDOCK_EMBED_LIB", "CARGO_TARGET_DIR",
                        "PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = "/usr/bin:/bin"
    return env


def test_client_and_wheel_install_and_run_from_anywhere(tmp_path: Path, wheel: Path) -> None:
    binary = os.environ.get("PADDOCK_BIN")

    venv = tmp_path / "venv"
    py = str(venv / "bin" / "python")
    run([sys.executable, "-m", "venv", str(venv)])
    # the dependency versions this test run uses, so the fresh venv is like it
    pins = tmp_path / "constraints.txt"
    pins.write_text("".join(f"{d}=={version(d)}\n" for d in ("pyzmq", "protobuf", "gymnasium", "numpy")))
    pip = [py, "-m", "pip", "install", "-q", "--disable-pip-version-check", "-c", str(pins)]

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    script = elsewhere / "user.py"
    script.write_text(USER)
    env = user_env()
    harbour = str(ROOT / "maps" / "harbour")

    # the package alone (the README's `pip install ./client-py`), given a binary
    if binary:
        # from a copy: building in place would leave build/ in the checkout
        src = tmp_path / "client-py"
        shutil.copytree(ROOT / "client-py", src,
                        ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__", "tests"))
        run(pip + [str(src)], cwd=elsewhere)
        # the in-process simulator's library: the one beside the binary under test
        library = str(Path(binary).resolve().parent / "libpaddock_embed.so")
        out = run([py, str(script), str(venv), harbour, binary, library], cwd=elsewhere,
                  env={**env, "PADDOCK_BIN": binary})
        assert out.stdout.count("stepped") == 6, out.stdout
        assert "16 envs in place" in out.stdout, out.stdout

    # the wheel: the package and its binary, nothing else needed
    run([py, "-m", "pip", "uninstall", "-q", "-y", "paddock"])
    run(pip + [str(wheel)], cwd=elsewhere)
    site = run([py, "-c", "import paddock, os; print(os.path.dirname(paddock.__file__))"],
               cwd=elsewhere, env=env).stdout.strip()
    out = run([py, str(script), str(venv), harbour, str(venv / "bin" / "paddock"),
               str(Path(site) / "_native" / "libpaddock_embed.so")], cwd=elsewhere, env=env)
    assert out.stdout.count("stepped") == 6, out.stdout
    assert "16 envs in place" in out.stdout, out.stdout


def interpreter(minor: str) -> str | None:
    """A working ``python3.N`` for ``minor`` ("3.N"): on PATH, or one pyenv installed."""
    roots = [os.environ.get("PYENV_ROOT", ""), str(Path.home() / ".pyenv")]
    found = [shutil.which(f"python{minor}")] + sorted(
        p for r in roots if r for p in glob.glob(f"{r}/versions/{minor}.*/bin/python{minor}"))
    for p in found:
        if p and subprocess.run([p, "-c", "import sys; assert sys.version_info[:2] == "
                                 f"{tuple(int(x) for x in minor.split('.'))}"],
                                capture_output=True).returncode == 0:
            return p
    return None


# The package supports Python 3.10 and later (pyproject.toml); the test run's own Python
# is tested above. numpy left 3.10 after 2.2: that Python gets the last numpy it has.
@pytest.mark.parametrize("minor, numpy", [("3.10", "2.2.6"), ("3.13", None)])
def test_the_wheel_on_the_oldest_and_the_newest_python(tmp_path: Path, wheel: Path, minor: str,
                                                      numpy: str | None) -> None:
    py = interpreter(minor)
    if py is None:
        pytest.skip(f"no Python {minor} on this machine")
    venv = tmp_path / "venv"
    run([py, "-m", "venv", str(venv)])
    pins = tmp_path / "constraints.txt"
    pins.write_text("".join(f"{d}=={version(d)}\n" for d in ("pyzmq", "protobuf", "gymnasium"))
                    + f"numpy=={numpy or version('numpy')}\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    vpy = str(venv / "bin" / "python")
    run([vpy, "-m", "pip", "install", "-q", "--disable-pip-version-check", "-c", str(pins),
         str(wheel)], cwd=elsewhere)
    script = elsewhere / "user.py"
    script.write_text(USER)
    site = run([vpy, "-c", "import paddock, os; print(os.path.dirname(paddock.__file__))"],
               cwd=elsewhere, env=user_env()).stdout.strip()
    out = run([vpy, str(script), str(venv), str(ROOT / "maps" / "harbour"),
               str(venv / "bin" / "paddock"), str(Path(site) / "_native" / "libpaddock_embed.so")],
              cwd=elsewhere, env=user_env())
    assert out.stdout.count("stepped") == 6, out.stdout
    assert "16 envs in place" in out.stdout, out.stdout
