"""The env-observation reader (paddock.wire) against the protobuf runtime: the same values
for every message the runtime would parse the same way, and None (so that the runtime
decides) for everything else."""

from __future__ import annotations

import random

import numpy as np
import pytest

from paddock import wire
from paddock._proto import paddock_pb2 as pb

BYTES_FIELDS = ("scans", "states", "rewards", "terminated", "truncated", "progress", "laps",
                "time", "agent_collisions", "agent_lap_counts", "agent_lap_times")


def random_observation(rng: random.Random) -> pb.EnvObservation:
    o = pb.EnvObservation(session_id=rng.choice([0, 1, 300, 2**64 - 1, rng.getrandbits(64)]),
                          num_envs=rng.choice([0, 1, 64, 2**32 - 1]))
    for name in BYTES_FIELDS:
        if rng.random() < 0.8:
            n = rng.choice([0, 1, 127, 128, 16383, 16384, 70000])
            setattr(o, name, rng.randbytes(n))
    return o


def envelope(o: pb.EnvObservation, rid: int, version: int = 1) -> bytes:
    env = pb.Envelope(protocol_version=version, request_id=rid)
    env.env_observation.CopyFrom(o)
    return env.SerializeToString()


def check_same(frame: bytes) -> None:
    runtime = pb.Envelope()
    runtime.ParseFromString(frame)
    got = wire.env_observation(memoryview(frame))
    assert got is not None
    version, rid, obs = got
    assert version == runtime.protocol_version
    assert rid == runtime.request_id
    want = runtime.env_observation
    assert obs.session_id == want.session_id
    assert obs.num_envs == want.num_envs
    for name in BYTES_FIELDS:
        assert bytes(getattr(obs, name)) == getattr(want, name), name


def test_same_values_as_the_protobuf_runtime() -> None:
    rng = random.Random(7)
    for _ in range(300):
        o = random_observation(rng)
        check_same(envelope(o, rng.choice([0, 1, 2**63, rng.getrandbits(64)]),
                            rng.choice([0, 1, 2**32 - 1])))


def test_fields_in_any_order_and_unknown_fields_skipped() -> None:
    o = pb.EnvObservation(session_id=9, num_envs=2, scans=b"\x01\x02\x03\x04" * 4, rewards=b"r" * 16)
    inner = o.SerializeToString()
    # unknown observation fields of each wire type (a newer server's additions)
    unknown = (_key(20, 0) + b"\x96\x01"            # varint
               + _key(21, 1) + b"12345678"          # fixed64
               + _key(22, 2) + b"\x03abc"           # bytes
               + _key(23, 5) + b"1234")             # fixed32
    body = unknown + inner[::-1][::-1]  # unknown fields first
    frame = (_key(44, 2) + _varint(len(body)) + body   # body before the header
             + _key(2, 0) + _varint(77) + _key(1, 0) + b"\x01")
    check_same(frame)
    got = wire.env_observation(memoryview(frame))
    assert got is not None and got[1] == 77
    assert np.frombuffer(got[2].scans, "<f4").shape == (4,)


def _key(number: int, wire_type: int) -> bytes:
    return _varint((number << 3) | wire_type)


def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def test_everything_else_is_left_to_the_runtime() -> None:
    obs = envelope(pb.EnvObservation(session_id=1, num_envs=1, scans=b"abcd"), 5)
    cases = {
        "error reply": pb.Envelope(request_id=5, error=pb.Error(message="no")).SerializeToString(),
        "other body": pb.Envelope(request_id=5, env_closed=pb.EnvClosed(session_id=1)).SerializeToString(),
        "no body": pb.Envelope(request_id=5).SerializeToString(),
        "empty frame": b"",
        # the runtime merges a repeated embedded message and keeps the last scalar
        "body twice": obs + obs,
        "field twice inside": (_key(44, 2) + b"\x0c" + b"\x1a\x04abcd" + b"\x1a\x04efgh"),
        "truncated": obs[:-2],
        "length past the end": _key(44, 2) + b"\x10abc",
        "field number too large": b"\xf8\xff\xff\xff\x0f\x01",
        "group wire type": _key(44, 3),
        "wrong wire type": _key(44, 2) + b"\x02" + _key(3, 0) + b"\x05",
        "field number 0": b"\x00\x01",
        "endless varint": _key(2, 0) + b"\xff" * 12,
    }
    for name, frame in cases.items():
        assert wire.env_observation(memoryview(frame)) is None, name
    # garbage never raises: it is unreadable here, and the runtime reports it
    rng = random.Random(3)
    for _ in range(2000):
        frame = rng.randbytes(rng.randrange(0, 64))
        got = wire.env_observation(memoryview(frame))
        if got is not None:
            check_same(frame)


def test_arrays_are_views_of_the_frame() -> None:
    scans = np.arange(8, dtype="<f4")
    frame = bytearray(envelope(pb.EnvObservation(session_id=1, num_envs=2, scans=scans.tobytes()), 3))
    got = wire.env_observation(memoryview(frame))
    assert got is not None
    arr = np.frombuffer(got[2].scans, "<f4")
    np.testing.assert_array_equal(arr, scans)
    i = bytes(frame).find(scans.tobytes())
    frame[i:i + 4] = np.float32(42.0).tobytes()
    assert arr[0] == 42.0  # no copy was made


def _run(endpoint: str, n: int, view_min: int) -> tuple[list, int]:
    """Observations of a seeded session, frames of at least `view_min` bytes read by
    paddock.wire, and how many were."""
    import paddock

    calls = {"view": 0}
    original_min, original_read = wire.VIEW_MIN_BYTES, wire.env_observation

    def counting(frame: memoryview):
        got = original_read(frame)
        calls["view"] += got is not None
        return got

    wire.VIEW_MIN_BYTES, wire.env_observation = view_min, counting
    env = paddock.make_vec(n, endpoint, num_beams=128, seed=3)
    try:
        frames = [env.reset(seed=1)]
        actions = np.tile(np.array([[0.1, 2.0]], np.float32), (n, 1))
        for _ in range(5):
            frames.append(env.step(actions))
    finally:
        env.close()
        wire.VIEW_MIN_BYTES, wire.env_observation = original_min, original_read
    return frames, calls["view"]


@pytest.mark.parametrize("n", [1, 8])
def test_env_steps_read_the_same_either_way(endpoint: str, n: int) -> None:
    viewed, fast = _run(endpoint, n, 0)
    parsed, none = _run(endpoint, n, 1 << 40)
    assert fast == 6 and none == 0
    for a, b in zip(viewed, parsed):
        obs_a, obs_b = a[0], b[0]
        for k in obs_b:
            assert obs_a[k].dtype == obs_b[k].dtype, k
            np.testing.assert_array_equal(obs_a[k], obs_b[k], err_msg=k)
        for x, y in zip(a[1:], b[1:]):
            if isinstance(y, dict):
                for k in y:
                    np.testing.assert_array_equal(x[k], y[k], err_msg=k)
            else:
                np.testing.assert_array_equal(x, y)
    assert viewed[-1][0]["scans"].shape == (n, 1, 128)
