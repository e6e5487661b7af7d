"""env.render(): frames drawn by the worker, the same bytes local and remote; gymnasium's
render checks, RecordVideo, the human window; `paddock rollout --video out.mp4`."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import paddock
from paddock import errors
from paddock.server import find_paddock

SMALL = {"num_beams": 108, "time_limit": 20.0}


def _drive(env: gym.Env, steps: int) -> list[np.ndarray]:
    """Frames after a seeded reset and after each of `steps` fixed actions."""
    env.reset(seed=5)
    frames = [env.render()]
    for k in range(steps):
        env.step(np.array([0.05 * np.sin(k / 4), 3.0], dtype=np.float32))
        frames.append(env.render())
    return frames


def test_rgb_array_frames_are_the_same_bytes_local_and_remote(endpoint: str) -> None:
    remote = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array",
                      num_agents=2, **SMALL)
    local = gym.make("paddock/F110-v0", endpoint=None, render_mode="rgb_array",
                     num_agents=2, **SMALL)
    try:
        a = _drive(remote, 25)
        b = _drive(local, 25)
    finally:
        remote.close()
        local.close()
    for fa, fb in zip(a, b):
        assert fa.dtype == np.uint8 and fa.ndim == 3 and fa.shape[1:] == (800, 3)
        assert fa.shape[0] % 2 == 0
        np.testing.assert_array_equal(fa, fb)
    # the race moves on: consecutive frames differ, and the same episode is the same bytes
    assert not np.array_equal(a[0], a[-1])
    again = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array",
                     num_agents=2, **SMALL)
    try:
        c = _drive(again, 25)
    finally:
        again.close()
    digest = lambda frames: hashlib.sha256(b"".join(f.tobytes() for f in frames)).hexdigest()  # noqa: E731
    assert digest(a) == digest(c)
    # the learner's car (red) and the opponent (blue) are on the picture
    last = a[-1].reshape(-1, 3).astype(int)
    red = np.sum((last[:, 0] > 200) & (last[:, 1] < 80) & (last[:, 2] < 90))
    blue = np.sum((last[:, 2] > 200) & (last[:, 0] < 60) & (last[:, 1] < 140))
    assert red >= 15 and blue >= 15, (red, blue)


def test_gymnasium_render_checks_pass(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> None:
    # check_env also makes the env in every declared mode: the human window off-screen
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    env = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array", **SMALL)
    try:
        assert "rgb_array" in env.metadata["render_modes"]
        assert env.metadata["render_fps"] == 100
        check_env(env.unwrapped)  # render checks included, rgb_array and human
    finally:
        env.close()
    env = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array",
                   render_width=320, frame_skip=4, **SMALL)
    try:
        assert env.metadata["render_fps"] == 25
        env.reset(seed=1)
        assert env.render().shape[1] == 320
    finally:
        env.close()


def test_render_without_a_mode_warns_and_bad_settings_name_themselves(endpoint: str) -> None:
    env = gym.make("paddock/F110-v0", endpoint=endpoint, **SMALL)
    try:
        env.reset(seed=1)
        with pytest.warns(UserWarning, match="render_mode"):
            assert env.unwrapped.render() is None
    finally:
        env.close()
    with pytest.raises(ValueError, match="render_mode = 'video'"):
        paddock.F110Env(endpoint, render_mode="video", **SMALL)
    # a width the server does not draw is refused when the env is made (0 went on the wire
    # as "the default" and drew 800 pixels unsaid)
    for width in (9000, 159, 0):
        with pytest.raises(ValueError, match=rf"render_width = {width} is out of range: must be a "
                                             r"whole number in \[160, 2048\]"):
            paddock.F110Env(endpoint, render_mode="rgb_array", render_width=width, **SMALL)
    env = paddock.F110Env(endpoint, render_mode="rgb_array", **SMALL)
    try:
        env.reset(seed=1)
        # the server's own check, for a session asked directly
        with pytest.raises(errors.InvalidArgument) as e:
            env.session.render([0], 9000)
        assert e.value.field == "env_render.width" and "9000" in str(e.value)
    finally:
        env.close()


CENTERLINE = Path(__file__).resolve().parents[2] / "maps" / "lakeside" / "lakeside_centerline.csv"


def _pure_pursuit(obs: dict[str, np.ndarray], line: np.ndarray) -> np.ndarray:
    """Steer car 0 towards the centerline point 1.5 m ahead of its nearest one."""
    x, y, th = obs["poses_x"][0], obs["poses_y"][0], obs["poses_theta"][0]
    k = int(np.argmin(np.hypot(line[:, 0] - x, line[:, 1] - y)))
    tx, ty = line[(k + 15) % len(line)]
    alpha = np.arctan2(ty - y, tx - x) - th
    alpha = (alpha + np.pi) % (2 * np.pi) - np.pi
    steer = np.arctan2(2 * 0.33 * np.sin(alpha), np.hypot(tx - x, ty - y))
    return np.array([np.clip(steer, -0.4, 0.4), 4.0], dtype=np.float32)


def test_record_video_records_a_lap(endpoint: str, tmp_path: Path) -> None:
    pytest.importorskip("moviepy", reason="RecordVideo needs moviepy (the test extra)")
    line = np.loadtxt(CENTERLINE, delimiter=",", comments="#")[:, :2]
    env = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array",
                   render_width=320, frame_skip=4, laps=1, time_limit=120.0, num_beams=108)
    env = gym.wrappers.RecordVideo(env, str(tmp_path), episode_trigger=lambda k: True,
                                   disable_logger=True)
    try:
        obs, info = env.reset(seed=2)
        done, steps = False, 0
        while not done:
            obs, _, terminated, truncated, info = env.step(_pure_pursuit(obs, line))
            done = terminated or truncated
            steps += 1
        assert terminated and info["laps"] == 1, info
    finally:
        env.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1, videos
    assert videos[0].stat().st_size > 10_000
    # one frame per step at the env's 25 steps per simulated second, plus the reset's
    from moviepy import VideoFileClip

    with VideoFileClip(str(videos[0])) as clip:
        assert clip.fps == 25
        assert clip.size[0] == 320
        assert abs(clip.duration * 25 - (steps + 1)) <= 2, (clip.duration, steps)


def test_vector_env_renders_every_env(endpoint: str) -> None:
    env = gym.make_vec("paddock/F110-v0", num_envs=3, endpoint=endpoint, render_mode="rgb_array",
                       render_width=320, **SMALL)
    try:
        env.reset(seed=7)
        frames = env.render()
        assert len(frames) == 3
        assert all(f.shape == frames[0].shape and f.shape[1] == 320 for f in frames)
        assert not np.array_equal(frames[0], frames[1]), "env i is seeded s + i"
        # env 1 of the vector env is the single env seeded 8
        one = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="rgb_array",
                       render_width=320, **SMALL)
        try:
            one.reset(seed=8)
            np.testing.assert_array_equal(one.render(), frames[1])
        finally:
            one.close()
    finally:
        env.close()


def test_human_mode_shows_frames_in_a_window(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("pygame", reason='render_mode="human" needs pygame (the human extra)')
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # no display in tests
    env = gym.make("paddock/F110-v0", endpoint=endpoint, render_mode="human", render_width=320,
                   frame_skip=10, **SMALL)
    try:
        env.reset(seed=3)
        for _ in range(3):
            env.step(np.array([0.0, 2.0], dtype=np.float32))
        window = env.unwrapped._window
        assert window is not None and window._screen is not None
        assert window._screen.get_size()[0] == 320
        assert env.render() is None
    finally:
        env.close()


def test_human_mode_without_pygame_says_how_to_install(endpoint: str,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame raises ImportError
    with pytest.raises(gym.error.DependencyNotInstalled, match=r"paddock\[human\]"):
        paddock.F110Env(endpoint, render_mode="human", **SMALL)


def test_cli_writes_mp4_through_ffmpeg(tmp_path: Path) -> None:
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="an ffmpeg binary (test extra)")
    bindir = tmp_path / "bin"
    bindir.mkdir()
    os.symlink(imageio_ffmpeg.get_ffmpeg_exe(), bindir / "ffmpeg")
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    out = tmp_path / "lap.mp4"
    subprocess.run([find_paddock(), "rollout", "--episodes", "1", "--time-limit", "2",
                    "--video-width", "320", "--video", str(out)],
                   check=True, env=env, capture_output=True, timeout=300)
    probe = subprocess.run([str(bindir / "ffmpeg"), "-i", str(out)], capture_output=True,
                           text=True, env=env)
    assert "Video:" in probe.stderr and "320x" in probe.stderr, probe.stderr
    assert out.stat().st_size > 5_000
    assert shutil.which("ffmpeg", path=env["PATH"])


def test_cli_video_through_the_broker_is_the_local_video(endpoint: str, tmp_path: Path) -> None:
    args = ["rollout", "--episodes", "1", "--seed", "9", "--time-limit", "2",
            "--video-width", "320"]
    local, remote = tmp_path / "local.gif", tmp_path / "remote.gif"
    subprocess.run([find_paddock(), *args, "--video", str(local)], check=True,
                   capture_output=True, timeout=300)
    subprocess.run([find_paddock(), *args, "--endpoint", endpoint, "--video", str(remote)],
                   check=True, capture_output=True, timeout=300)
    assert local.read_bytes() == remote.read_bytes()
    assert local.stat().st_size > 1_000
