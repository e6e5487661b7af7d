"""Env replies as frames (paddock.wire): the observation's small message parsed by the
protobuf runtime, its scans a view of the received frame; and, through a real broker and
worker, the frames a learner gets for an env step: header, message, scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zmq

from paddock import errors, wire
from paddock._proto import paddock_pb2 as pb
from paddock.transport import PROTOCOL_VERSION, Connection


def test_arrays_are_views_of_the_scans_frame() -> None:
    scans = np.arange(8, dtype="<f4")
    meta = pb.EnvObservation(num_envs=2, rewards=np.array([1.5, -2.0], "<f8").tobytes())
    frame = bytearray(scans.tobytes())
    obs = wire.observation([meta.SerializeToString(), frame])
    assert obs.num_envs == 2
    np.testing.assert_array_equal(np.frombuffer(obs.rewards, "<f8"), [1.5, -2.0])
    arr = np.frombuffer(obs.scans, "<f4")
    np.testing.assert_array_equal(arr, scans)
    frame[0:4] = np.float32(42.0).tobytes()
    assert arr[0] == 42.0  # no copy was made


def test_a_reply_with_the_wrong_frames_is_refused() -> None:
    with pytest.raises(errors.BadMessage):
        wire.observation([b""])
    with pytest.raises(errors.BadMessage):
        wire.image([b"", b"", b""])


def test_an_env_step_arrives_as_header_message_and_scans(
        endpoint: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The raw frames of an env step through the broker: the EnvReply header with the
    session id the broker gave at open, the EnvObservation without scans, and the scans
    frame of num_envs x num_beams f32 values."""
    conn = Connection(endpoint)
    try:
        ref = conn.map_ref("lakeside")
        open_msg = pb.EnvOpen(map=ref, num_envs=3, seed=5, laps=1, time_limit=30.0, frame_skip=1,
                              lidar=pb.Lidar(num_beams=64, fov=4.7, max_range=30.0, noise_std=0.0))
        header, frames = conn.env(0, pb.ENV_OPEN, open_msg)
        sid = header.session_id
        assert sid != 0 and header.op == pb.ENV_OPEN
        opened = pb.EnvOpened.FromString(frames[0].bytes)
        assert (opened.num_envs, opened.num_beams) == (3, 64)
        header, frames = conn.env(sid, pb.ENV_RESET, pb.EnvReset(seeds=[1, 2, 3]))
        assert header.restart, "a seeded reset of every env is a restart point"
        step = pb.EnvStep(actions=np.tile(np.array([0.0, 2.0], "<f4"), 3).tobytes())
        header, frames = conn.env(sid, pb.ENV_STEP, step)
        assert (header.session_id, header.op, header.restart) == (sid, pb.ENV_STEP, False)
        assert len(frames) == 2
        assert isinstance(frames[1], zmq.Frame)
        assert len(frames[1].buffer) == 3 * 64 * 4
        obs = wire.observation(frames)
        assert np.frombuffer(obs.time, "<f8").tolist() == [0.01] * 3
        # a session belongs to the client that opened it (its client token): this user
        # reaches it on another connection too, another client does not
        same = Connection(endpoint)
        try:
            header, _ = same.env(sid, pb.ENV_STEP, step)
            assert header.session_id == sid
        finally:
            same.close()
        monkeypatch.setenv("PADDOCK_CLIENT_TOKEN_FILE", str(tmp_path / "another-client"))
        other = Connection(endpoint)
        try:
            with pytest.raises(errors.NotFound):
                other.env(sid, pb.ENV_STEP, step)
        finally:
            other.close()
        conn.env(sid, pb.ENV_CLOSE)
        with pytest.raises(errors.NotFound):
            conn.env(sid, pb.ENV_STEP, step)
    finally:
        conn.close()


def test_the_protocol_version_is_checked(endpoint: str) -> None:
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(endpoint)
    try:
        env = pb.Envelope(protocol_version=PROTOCOL_VERSION - 1, request_id=7,
                          status_request=pb.StatusRequest())
        s.send(env.SerializeToString())
        assert s.poll(10_000)
        reply = pb.Envelope.FromString(s.recv())
        assert reply.request_id == 7
        assert reply.error.field == "protocol_version"
    finally:
        s.close()
