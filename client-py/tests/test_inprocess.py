"""The simulator inside the learner's process (``endpoint=paddock.IN_PROCESS``) against a
real `paddock serve`: the same observations bit for bit, the same refusals, gymnasium's
checker, local maps and ONNX opponents."""

from __future__ import annotations

import copy
import gc
import os
import pickle
import shutil
import signal
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import paddock
from paddock import errors
from paddock._proto import paddock_pb2 as pb
from paddock.inprocess import InProcess

ROOT = Path(__file__).resolve().parents[2]


def rollout(endpoint: str, n: int, steps: int, **kw) -> list[tuple]:
    """Observations, rewards and flags of a vector env driven by seeded random actions
    (some cars crash, so the autoreset runs too)."""
    env = paddock.make_vec(n, endpoint, **kw)
    rng = np.random.default_rng(5)
    try:
        out = [env.reset(seed=11)]
        for _ in range(steps):
            a = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(0.5, 6.0, n)])
            out.append(env.step(a.astype(np.float32)))
        return out
    finally:
        env.close()


# 6 envs' scans (26 KB) are copied out of the library's frame; 16 envs' (69 KB) are
# written by the library into each step's own array
@pytest.mark.parametrize("n", [6, 16])
def test_in_process_equals_the_server_bit_for_bit(endpoint: str, n: int) -> None:
    kw = dict(num_beams=1080, time_limit=1.5, frame_skip=3, num_agents=2)
    # every step's observations are kept and compared at the end: a step that wrote
    # into an earlier step's arrays would show
    local = rollout(paddock.IN_PROCESS, n, 80, **kw)
    served = rollout(endpoint, n, 80, **kw)
    ended = 0
    for a, b in zip(local, served):
        for x, y in zip(a, b):
            if isinstance(x, dict):
                assert x.keys() == y.keys()
                for k in x:
                    np.testing.assert_array_equal(x[k], y[k], err_msg=k)
            else:
                np.testing.assert_array_equal(x, y)
        if len(a) == 5:
            ended += int(a[2].sum() + a[3].sum())
    assert ended > 0, "no env ended: the autoreset went untested"
    scans = local[-1][0]["scans"]
    assert scans.shape == (n, 1, 1080)
    assert not scans.flags.writeable, "read-only, as a server's reply is"


def test_check_env_passes_in_process() -> None:
    env = gym.make("paddock/F110-v0", endpoint=paddock.IN_PROCESS, map="lakeside", num_beams=108)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=3)
        assert env.observation_space.contains(obs)
        frame = env.unwrapped.session.render()
        assert frame.ndim == 4 and frame.shape[-1] == 3
    finally:
        env.close()


def test_refusals_name_the_field_and_the_session_goes_on() -> None:
    with pytest.raises(FileNotFoundError, match="no-such-map"):
        paddock.make_vec(1, paddock.IN_PROCESS, map="no-such-map")
    with pytest.raises(errors.InvalidArgument) as e:
        paddock.make_vec(1, paddock.IN_PROCESS, num_agents=2, opponents=["nobody"])
    assert e.value.field == "env_open.opponents[0].driver"
    env = gym.make("paddock/F110-v0", endpoint=paddock.IN_PROCESS, num_beams=16)
    try:
        env.reset(seed=0)
        with pytest.raises(errors.InvalidArgument) as e:
            env.step(np.array([0.0, np.nan], dtype=np.float32))
        assert e.value.field == "env_step.actions[1]"
        env.step(np.array([0.0, 1.0], dtype=np.float32))
    finally:
        env.close()
    with InProcess() as conn:
        with pytest.raises(errors.NotFound) as e:
            conn.env(0, pb.ENV_OPEN, pb.EnvOpen(map=pb.MapRef(name="x", hash="ab" * 32),
                                                num_envs=1, laps=1, time_limit=10, frame_skip=1))
        assert e.value.field == "env_open.map.hash"
        with pytest.raises(errors.NotFound) as e:
            conn.env(987654, pb.ENV_STEP, pb.EnvStep())
        assert e.value.field == "env_request.session_id"
    with pytest.raises(errors.PaddockError, match="closed"):
        conn.status()
    # batch rollouts and jobs need a server: said so, naming the endpoint
    with pytest.raises(ValueError, match="'in-process'.*need a server"):
        paddock.Client(paddock.IN_PROCESS)
    # a TCP port out of range is said at once (ZeroMQ connected to nothing, and the first
    # request waited its whole timeout), and so is a timeout a socket cannot take
    with pytest.raises(ValueError, match=r"port 99999 is out of range: must be a whole number in \[1, 65535\]"):
        paddock.Client("tcp://127.0.0.1:99999")
    with pytest.raises(ValueError, match=r"has no host and port"):
        paddock.make_vec(1, "tcp://127.0.0.1")
    for bad in [0, 1e12, float("nan")]:
        with pytest.raises(ValueError, match=r"timeout = .* is out of range: must be a number of seconds"):
            paddock.Client("tcp://127.0.0.1:5555", timeout=bad)
        with pytest.raises(ValueError, match=r"timeout = .* is out of range"):
            paddock.make_vec(1, paddock.IN_PROCESS, timeout=bad)


def test_whole_number_fields_name_themselves_and_the_session_goes_on() -> None:
    # A value an unsigned field of the request cannot carry was refused by the protobuf
    # runtime as "Value out of range: -1", naming nothing, and a fraction was cut.
    for kw, said in [
        (dict(num_beams=-1), "num_beams = -1 is out of range: must be a whole number in [0, "),
        (dict(obstacles=-1), "obstacles = -1 is out of range"),
        (dict(laps=2**32), "laps = 4294967296 is out of range"),
        (dict(frame_skip=2.5), "frame_skip = 2.5 is not a whole number"),
        (dict(num_agents=0), "num_agents = 0 is out of range: must be a whole number in [1, "),
    ]:
        with pytest.raises(ValueError) as e:
            paddock.make_vec(2, paddock.IN_PROCESS, **kw)
        assert said in str(e.value), (kw, str(e.value))
    with pytest.raises(ValueError, match=r"num_envs = -1 is out of range"):
        paddock.make_vec(-1, paddock.IN_PROCESS)
    # the wrappers took int() of their counts first: 2.5 cars became 2
    from paddock import pettingzoo, sb3
    with pytest.raises(ValueError, match=r"num_agents = 2.5 is not a whole number"):
        pettingzoo.ParallelEnv(2.5, paddock.IN_PROCESS)
    with pytest.raises(ValueError, match=r"num_envs = 2.5 is not a whole number"):
        sb3.VecEnv(2.5, paddock.IN_PROCESS)
    with pytest.raises(ValueError, match=r"render_width = 640.5 is not a whole number"):
        paddock.F110Env(endpoint=paddock.IN_PROCESS, render_width=640.5)
    with InProcess() as conn:
        s = paddock.EnvSession(conn, 3, num_beams=16)
        # indices as numpy arrays, as a vector env passes them
        s.reset(seeds=np.array([1, 2, 3]), envs=np.array([0, 1, 2]))
        with pytest.raises(ValueError, match=r"envs\[1\] = -1 is out of range"):
            s.reset(envs=[0, -1])
        with pytest.raises(ValueError, match=r"reset_envs\[0\] = -2 is out of range"):
            s.step(np.zeros((3, 2), np.float32), reset_envs=[-2])
        with pytest.raises(ValueError, match=r"width = -5 is out of range"):
            s.render(width=-5)
        # the session goes on
        assert s.step(np.zeros((3, 2), np.float32)).scans.shape == (3, 1, 16)
        s.close()


def test_seeds_are_checked_and_unknown_reset_options_named() -> None:
    """Seeds were wrapped modulo 2**64 (two seeds, one episode) and cut to whole numbers:
    now refused, naming them, before anything resets. A reset option an env does not take
    (a misspelt ``poses``) was ignored unsaid: now with a warning naming it. The envs go
    on."""
    from paddock import pettingzoo, sb3
    ip = paddock.IN_PROCESS
    vec = paddock.make_vec(3, ip, num_beams=16)
    single = gym.make("paddock/F110-v0", endpoint=ip, num_beams=16)
    learner = sb3.VecEnv(2, ip, num_beams=16)
    race = pettingzoo.parallel_env(num_agents=2, endpoint=ip, num_beams=16)
    try:
        for call, said in [
            (lambda: vec.reset(seed=-1), r"seed = -1 is out of range: must be a whole number "
                                         r"in \[0, 18446744073709551613\]"),
            (lambda: vec.reset(seed=2**64 - 1), r"seed = 18446744073709551615 is out of range"),
            (lambda: vec.reset(seed=1.5), r"seed = 1.5 is not a whole number"),
            (lambda: vec.reset(seed=[1, 2, 3.5]), r"seed\[2\] = 3.5 is not a whole number"),
            (lambda: vec.reset(options=[1]), r"options = \[1\] is not a dict"),
            (lambda: single.reset(seed=2**64), r"seed = 18446744073709551616 is out of range"),
            (lambda: single.reset(seed=-1), r"seed = -1 is out of range"),
            (lambda: learner.seed(2**64 - 1), r"seed = 18446744073709551615 is out of range"),
            (lambda: race.reset(seed=1.5), r"seed = 1.5 is not a whole number"),
            (lambda: paddock.make_vec(1, ip, num_beams=16, seed=-1), r"seed = -1 is out of range"),
        ]:
            with pytest.raises(ValueError, match=said):
                call()
        # an option the env does not take is ignored with a warning naming it (by the
        # PettingZoo env without one: its API test passes one and fails on a warning)
        for call, key, takes in [
            (lambda: vec.reset(options={"pose": [[0, 0, 0]] * 3}), "pose", "poses, reset_mask"),
            (lambda: single.reset(options={"posse": [[0, 0, 0]]}), "posse", "poses"),
            (lambda: learner.set_options({"posses": [[0, 0, 0]]}), "posses", "poses"),
        ]:
            with pytest.warns(UserWarning, match=rf"options: unknown key '{key}' ignored "
                                                 rf"\(this env takes {takes}\)"):
                call()
        # the largest seeds are taken, as numpy integers too, and the envs go on
        assert vec.reset(seed=np.uint64(2**64 - 3))[0]["scans"].shape == (3, 1, 16)
        assert single.reset(seed=2**64 - 1)[0]["scans"].shape == (1, 16)
        learner.seed(5)
        assert learner.reset()["scans"].shape == (2, 16)
        assert len(race.reset(seed=3)[0]) == 2
    finally:
        for e in (vec, single, learner, race):
            e.close()


def test_an_env_says_it_cannot_be_pickled_or_copied() -> None:
    """pickle and copy.deepcopy of an env failed deep inside, naming a protobuf module."""
    env = gym.make("paddock/F110-v0", endpoint=paddock.IN_PROCESS, num_beams=16)
    try:
        for f in (pickle.dumps, copy.deepcopy):
            with pytest.raises(TypeError, match=r"cannot be pickled or copied: make a new one"):
                f(env)
        # its spec makes a new one, which steps
        other = gym.make(env.spec)
        assert other.reset(seed=1)[0]["scans"].shape == (1, 16)
        other.close()
    finally:
        env.close()
    # an env with its own local server (what it holds first is the server, not the session)
    env = gym.make("paddock/F110-v0", endpoint=None, num_beams=16, threads=1)
    try:
        for f in (pickle.dumps, copy.deepcopy):
            with pytest.raises(TypeError, match=r"cannot be pickled or copied: make a new one"):
                f(env)
    finally:
        env.close()


def test_a_map_directory_and_an_onnx_opponent_in_process(tmp_path: Path) -> None:
    onnx = pytest.importorskip("onnx")
    from test_onnx import mlp_model

    track = tmp_path / "harbour-copy"
    shutil.copytree(ROOT / "maps" / "harbour", track)
    model = tmp_path / "opponent.onnx"
    model.write_bytes(mlp_model(beams=64))
    assert onnx.load(str(model)).graph.input[0].name == "scans"
    env = paddock.make_vec(2, paddock.IN_PROCESS, map=str(track), num_beams=64, num_agents=2,
                           opponents=[str(model)])
    try:
        obs, _ = env.reset(seed=4)
        for _ in range(20):
            obs, *_ = env.step(np.tile(np.array([0.0, 1.0], dtype=np.float32), (2, 1)))
        # the opponent (car 1) drove away from its start
        assert np.all(obs["linear_vels_x"][:, 1] > 0.1)
    finally:
        env.close()


def test_pettingzoo_api_test_passes_in_process() -> None:
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test

    from paddock.pettingzoo import parallel_env

    env = parallel_env(num_agents=2, endpoint=paddock.IN_PROCESS, num_beams=64)
    try:
        parallel_api_test(env, num_cycles=50)
    finally:
        env.close()


def _scans_of(env, steps: int) -> list[np.ndarray]:
    """The scans of a seeded reset and ``steps`` steps straight ahead."""
    out = [env.reset(seed=3)[0]["scans"].copy()]
    for _ in range(steps):
        out.append(env.step(np.tile(np.array([0.0, 2.0], dtype=np.float32), (env.num_envs, 1)))[0]["scans"].copy())
    return out


def test_a_forked_child_steps_its_own_envs_and_leaves_the_parents_alone(
        tmp_path: Path, monkeypatch) -> None:
    """A fork after stepping (the default start method of ``multiprocessing`` on Linux):
    the child's own envs step on threads made again for it, bit for bit as in the parent;
    the parent's env is refused there, naming why, and the child freeing it leaves the
    parent's map cache alone. Four envs, so that with two cores the copies step on the
    pool's threads."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # where the library's map cache goes
    track = tmp_path / "harbour-copy"
    shutil.copytree(ROOT / "maps" / "harbour", track)
    env = paddock.make_vec(4, paddock.IN_PROCESS, map=str(track), num_beams=16)
    fresh = paddock.make_vec(4, paddock.IN_PROCESS, map="lakeside", num_beams=16)
    try:
        expected = _scans_of(fresh, 5)
        _scans_of(env, 2)
        caches = sorted(tmp_path.glob("paddock-embed-maps-*"))
        assert len(caches) == 1
        pid = os.fork()
        if pid == 0:  # the child: exit code bits say what went wrong; it never returns
            code = 0
            try:
                try:
                    child = paddock.make_vec(4, paddock.IN_PROCESS, map="lakeside", num_beams=16)
                    got = _scans_of(child, 5)
                    code |= 0 if all(np.array_equal(a, b) for a, b in zip(got, expected)) else 1
                    child.close()
                except BaseException:
                    code |= 2
                try:
                    env.step(np.zeros((4, 2), dtype=np.float32))
                    code |= 4
                except errors.PaddockError as e:
                    code |= 0 if "before it forked" in str(e) and "in this process" in str(e) else 8
                env.close()
            except BaseException:
                code |= 16
            finally:
                os._exit(code)
        deadline = time.monotonic() + 60
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                pytest.fail("the forked child hung")
            time.sleep(0.05)
        assert os.waitstatus_to_exitcode(status) == 0
        # the parent goes on: its env steps, its map cache is still there, and it resets
        # to the same bits as before
        assert all(c.is_dir() for c in caches)
        env.step(np.zeros((4, 2), dtype=np.float32))
        again = _scans_of(fresh, 5)
        assert all(np.array_equal(a, b) for a, b in zip(again, expected))
    finally:
        env.close()
        fresh.close()


def _library_threads() -> int:
    """This process's threads of the in-process library's pool (Linux names them; a
    thread that ends while they are read is not one)."""
    count = 0
    for t in Path("/proc/self/task").iterdir():
        try:
            count += (t / "comm").read_text().startswith("paddock-embed-")
        except OSError:  # ended meanwhile (no such file, or no such process)
            pass
    return count


def _library_threads_become(ok, seconds: float = 10.0) -> int:
    """The library's thread count once ``ok(count)`` holds (a new thread names itself
    when it first runs, an ended one leaves soon after), or the last count read."""
    deadline = time.monotonic() + seconds
    while not ok(n := _library_threads()) and time.monotonic() < deadline:
        time.sleep(0.01)
    return n


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_the_librarys_threads_end_with_its_last_env() -> None:
    """The pool ends with the process's last in-process env, so that a process that closed
    its envs (gymnasium's AsyncVectorEnv closes the one it read the spaces from) forks
    without them, and an env made later makes it again."""
    gc.collect()  # envs of earlier tests that nobody closed
    for _ in range(2):
        env = paddock.make_vec(2, paddock.IN_PROCESS, num_beams=16)
        other = paddock.make_vec(1, paddock.IN_PROCESS, num_beams=16)
        env.reset(seed=0)
        assert _library_threads_become(lambda n: n >= 1) >= 1
        env.close()
        time.sleep(0.05)
        assert _library_threads() >= 1  # the other env still holds them
        other.close()
        assert _library_threads_become(lambda n: n == 0) == 0


def test_gymnasium_async_vector_env_forks_in_process_envs() -> None:
    """``gymnasium.make_vec(..., vectorization_mode="async")`` on Linux: the parent makes
    one env to read the spaces, then forks a process per env; they step as the same envs
    in one process do, bit for bit."""
    kw = {"endpoint": paddock.IN_PROCESS, "num_beams": 16}
    actions = np.tile(np.array([0.05, 2.0], dtype=np.float32), (2, 1))
    sync = gym.make_vec("paddock/F110-v0", num_envs=2, vectorization_mode="sync", **kw)
    forked = gym.make_vec("paddock/F110-v0", num_envs=2, vectorization_mode="async",
                          vector_kwargs={"context": "fork"}, **kw)
    try:
        want = [sync.reset(seed=7)[0]["scans"]] + [sync.step(actions)[0]["scans"] for _ in range(5)]
        # bounded waits: a child that hung would fail the test instead of stalling it
        forked.reset_async(seed=7)
        got = [forked.reset_wait(timeout=60)[0]["scans"]]
        for _ in range(5):
            forked.step_async(actions)
            got.append(forked.step_wait(timeout=60)[0]["scans"])
        assert all(np.array_equal(a, b) for a, b in zip(got, want))
    finally:
        sync.close()
        forked.close(terminate=True)


def test_each_library_file_is_its_own_simulator(tmp_path: Path, monkeypatch) -> None:
    """A session made after ``$PADDOCK_EMBED_LIB`` names another file runs that file's
    copy of the simulator; sessions made before keep theirs, and both step alike."""
    from paddock.inprocess import find_library
    lib = Path(find_library())
    copy = tmp_path / lib.name
    shutil.copy(lib, copy)
    first = InProcess()
    monkeypatch.setenv("PADDOCK_EMBED_LIB", str(copy))
    second = InProcess()
    monkeypatch.setenv("PADDOCK_EMBED_LIB", str(lib))
    third = InProcess()
    try:
        assert second._lib is not first._lib
        assert third._lib is first._lib
        assert second._lib._name == str(copy)
    finally:
        for c in (first, second, third):
            c.close()
    a = rollout(paddock.IN_PROCESS, 2, 5, num_beams=1080)
    monkeypatch.setenv("PADDOCK_EMBED_LIB", str(copy))
    b = rollout(paddock.IN_PROCESS, 2, 5, num_beams=1080)
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            if isinstance(u, dict):
                for k in u:
                    np.testing.assert_array_equal(u[k], v[k], err_msg=k)
            else:
                np.testing.assert_array_equal(u, v)


SCAN_PATH_SCRIPT = """
import hashlib, sys
import numpy as np
import paddock
from paddock import errors
try:
    env = paddock.make_vec(3, paddock.IN_PROCESS, num_beams=1080, num_agents=2, frame_skip=2)
except errors.InvalidArgument as e:
    print("refused", e.field, e)
    sys.exit(0)
rng = np.random.default_rng(2)
h = hashlib.sha256()
obs, _ = env.reset(seed=4)
h.update(obs["scans"].tobytes())
for _ in range(40):
    a = np.column_stack([rng.uniform(-0.4, 0.4, 3), rng.uniform(0.5, 6.0, 3)])
    obs, r, term, trunc, _ = env.step(a.astype(np.float32))
    h.update(obs["scans"].tobytes())
    h.update(r.tobytes())
env.close()
print("scans", h.hexdigest())
"""


def in_process_with_scan_path(value: str | None) -> str:
    """The last line a learner's process prints that steps an in-process vector env with
    ``PADDOCK_SCAN_PATH`` set to ``value`` (unset for None)."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PADDOCK_SCAN_PATH"}
    if value is not None:
        env["PADDOCK_SCAN_PATH"] = value
    done = subprocess.run([sys.executable, "-c", SCAN_PATH_SCRIPT], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def test_the_scan_path_variable_keeps_the_bits_and_a_bad_value_is_refused() -> None:
    # every path gives the same bits: the portable one, chosen by the variable, against the
    # widest this CPU has
    widest = in_process_with_scan_path(None)
    assert widest.startswith("scans ")
    assert in_process_with_scan_path("portable") == widest
    # a value that names no path: the env's opening is refused, naming the variable
    refused = in_process_with_scan_path("sse9")
    assert refused.startswith("refused PADDOCK_SCAN_PATH "), refused
    assert "PADDOCK_SCAN_PATH=\"sse9\" is not one of portable, avx, avx512" in refused
