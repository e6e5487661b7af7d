"""``benchmarks/ab_steps.py``, the side-by-side timing of two builds of the simulator in
one process: two copies of the library coexist (each with its own worlds), the report's
figures are what they say, and bad arguments are refused naming the value."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from paddock.inprocess import find_library

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "client-py" / "benchmarks" / "ab_steps.py"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def two_copies(tmp_path: Path) -> tuple[Path, Path]:
    lib = Path(find_library())
    a, b = tmp_path / "a" / lib.name, tmp_path / "b" / lib.name
    for p in (a, b):
        p.parent.mkdir()
        shutil.copy(lib, p)
    return a, b


@pytest.mark.parametrize("first", ["base", "head"])
def test_two_copies_of_one_build_run_side_by_side(two_copies, first: str) -> None:
    a, b = two_copies
    r = run("--base", a, "--head", b, "--envs", 2, "--seconds", 1.5, "--block-ms", 5,
            "--load-first", first, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["load_first"] == first and doc["envs"] == 2 and doc["pairs"] >= 4
    assert doc["block_steps"] >= 1
    lo, hi = doc["head_speed_over_base_ci95"]
    assert lo <= doc["head_speed_over_base"] <= hi
    assert doc["head_speed_over_base"] == pytest.approx(1 / doc["head_time_over_base_median"])
    # one build against itself: the same speed within the noise of a loaded test machine
    assert 0.5 < doc["head_speed_over_base"] < 2.0
    assert 0.0 <= doc["head_faster_share"] <= 1.0
    assert all(v > 0 for v in doc["env_steps_per_cpu_s"].values())


def test_the_table(two_copies) -> None:
    a, b = two_copies
    r = run("--base", a, "--head", b, "--envs", 1, "--seconds", 1, "--block-ms", 5)
    assert r.returncode == 0, r.stderr
    assert "| head |" in r.stdout and "| base |" in r.stdout and "pairs of" in r.stdout
    assert "env-steps per CPU-s" in r.stdout


def test_the_wall_clock_for_several_cores(two_copies) -> None:
    a, b = two_copies
    r = run("--base", a, "--head", b, "--envs", 4, "--seconds", 1, "--block-ms", 5,
            "--clock", "wall", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["clock"] == "wall" and doc["pairs"] >= 4 and "env_steps_per_cpu_s" not in doc
    assert all(v > 0 for v in doc["env_steps_per_wall_s"].values())
    # by the clock the host's other load counts (the test tracks run side by side), so
    # only the report's shape is checked, not how close the two copies came
    lo, hi = doc["head_speed_over_base_ci95"]
    assert 0 < lo <= doc["head_speed_over_base"] <= hi


@pytest.mark.parametrize("args, named", [
    (["--seconds", "0"], "--seconds = 0.0"),
    (["--seconds", "nan"], "--seconds = nan"),
    (["--block-ms", "-5"], "--block-ms = -5.0"),
    (["--envs", "0"], "--envs = 0"),
    (["--clock", "gpu"], "--clock: invalid choice: 'gpu'"),
    (["--seconds", "0.01", "--block-ms", "20"], "--seconds = 0.01"),
])
def test_bad_arguments_are_refused_by_name(two_copies, args: list[str], named: str) -> None:
    a, b = two_copies
    r = run("--base", a, "--head", b, *args)
    assert r.returncode == 2
    assert named in r.stderr


def test_a_missing_library_is_named(two_copies, tmp_path: Path) -> None:
    a, _ = two_copies
    missing = tmp_path / "nowhere.so"
    r = run("--base", a, "--head", missing, "--seconds", 1)
    assert r.returncode != 0
    assert str(missing) in r.stderr


def base_rev(base: str, scan_path: str | None) -> subprocess.CompletedProcess:
    """``base_rev BASE`` of scripts/rounds.sh (what scripts/ab_rounds.sh and
    scripts/perf_rounds.sh check their base with), ``PADDOCK_SCAN_PATH`` set to
    ``scan_path`` (unset for None)."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "PADDOCK_SCAN_PATH"}
    if scan_path is not None:
        env["PADDOCK_SCAN_PATH"] = scan_path
    script = 'rounds=1 seconds=1; source scripts/rounds.sh; base_rev "$1"'
    return subprocess.run(["bash", "-c", script, "base_rev", base], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)


def test_a_base_that_predates_the_scan_path_variable_is_refused_while_it_is_set() -> None:
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    head = base_rev("HEAD", "avx")
    assert head.returncode == 0, head.stderr
    assert len(head.stdout.strip()) == 40
    # the last commit before the variable (as the build 4acddcb is) is refused
    # while it is set, and taken while it is not
    added = subprocess.run(["git", "log", "--reverse", "--format=%H", "--diff-filter=A",
                            "--", "worker/src/scan_path.rs"],
                           cwd=ROOT, capture_output=True, text=True).stdout.split()
    assert added, "no commit adds worker/src/scan_path.rs"
    parent = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{added[0]}^"],
                            cwd=ROOT, capture_output=True, text=True).stdout.strip()
    if not parent:
        pytest.skip("a shallow clone without the commits before the variable")
    refused = base_rev(parent, "avx")
    assert refused.returncode == 2
    assert f"PADDOCK_SCAN_PATH = 'avx' is set, but BASE = '{parent}' predates" in refused.stderr
    assert base_rev(parent, None).returncode == 0
    assert base_rev(parent, "").returncode == 0
