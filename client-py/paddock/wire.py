"""Env observations read straight from the received frame, without a protobuf parse.

An env observation is the one large reply a learner receives on every step (a 64-env
vector env with 1080-beam scans: about 280 KB). Parsing it with the protobuf runtime copies
every bytes field out of the frame, and the copies land in freshly mapped memory (page
faults on every step); that cost more than a third of a 64-env step. This module walks the
protobuf wire format of ``Envelope{request_id, env_observation}`` itself and hands out
``memoryview`` slices of the frame, which ``numpy.frombuffer`` turns into arrays without
copying.

The reader is deliberately narrow: it accepts only what the protobuf runtime would parse
to the same values (each known field once, with its declared wire type; unknown
observation fields are skipped as the runtime skips them). Anything else (an error reply,
another body, a repeated field, a truncated or garbled frame) returns None and the caller
parses the frame with the protobuf runtime, which gives the exact semantics and errors.
"""

from __future__ import annotations

from dataclasses import dataclass

# Frames at least this long are read here; below it the protobuf runtime's parse (copies
# included) costs less than walking the fields in Python.
VIEW_MIN_BYTES = 16 * 1024

# Envelope field numbers (proto/paddock.proto)
_PROTOCOL_VERSION = 1
_REQUEST_ID = 2
_ENV_OBSERVATION = 44

# EnvObservation: varint fields and bytes fields, by number
_OBS_VARINTS = {1: "session_id", 2: "num_envs"}
_OBS_BYTES = {3: "scans", 4: "states", 5: "rewards", 6: "terminated", 7: "truncated",
              8: "progress", 9: "laps", 10: "time", 11: "agent_collisions",
              12: "agent_lap_counts", 13: "agent_lap_times"}

_EMPTY = memoryview(b"")
_MAX_FIELD = (1 << 29) - 1


@dataclass
class Observation:
    """The fields of an ``EnvObservation``, bytes fields as views of the received frame
    (the same names as the protobuf message, so code reading one reads the other)."""

    session_id: int = 0
    num_envs: int = 0
    scans: memoryview = _EMPTY
    states: memoryview = _EMPTY
    rewards: memoryview = _EMPTY
    terminated: memoryview = _EMPTY
    truncated: memoryview = _EMPTY
    progress: memoryview = _EMPTY
    laps: memoryview = _EMPTY
    time: memoryview = _EMPTY
    agent_collisions: memoryview = _EMPTY
    agent_lap_counts: memoryview = _EMPTY
    agent_lap_times: memoryview = _EMPTY


class _Unreadable(Exception):
    """The frame is not one this reader takes: the protobuf runtime decides."""


def _varint(buf: memoryview, i: int, end: int) -> tuple[int, int]:
    if i < end:
        b = buf[i]
        if b < 0x80:
            return b, i + 1
    value = 0
    shift = 0
    while i < end and shift < 70:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value & 0xFFFFFFFFFFFFFFFF, i
        shift += 7
    raise _Unreadable


def _fields(buf: memoryview, i: int, end: int) -> list[tuple[int, int, int, int]]:
    """(field number, wire type, value or start, stop) for each field in buf[i:end];
    a field seen twice makes the message unreadable here (the runtime merges or keeps
    the last one)."""
    out = []
    seen = set()
    while i < end:
        key, i = _varint(buf, i, end)
        number, wire = key >> 3, key & 7
        if number == 0 or number > _MAX_FIELD or number in seen:
            raise _Unreadable
        seen.add(number)
        if wire == 0:
            value, i = _varint(buf, i, end)
            out.append((number, 0, value, i))
        elif wire == 2:
            n, i = _varint(buf, i, end)
            if i + n > end:
                raise _Unreadable
            out.append((number, 2, i, i + n))
            i += n
        elif wire == 1 or wire == 5:
            i += 8 if wire == 1 else 4
            if i > end:
                raise _Unreadable
        else:
            raise _Unreadable  # groups: never in Paddock's protocol
    return out


def env_observation(frame: memoryview) -> tuple[int, int, Observation] | None:
    """``(protocol_version, request_id, observation)`` when ``frame`` is an Envelope whose
    body is an env observation, else None (parse it with the protobuf runtime)."""
    buf = frame if frame.format == "B" else frame.cast("B")
    try:
        version = request_id = 0
        body = None
        for number, wire, a, b in _fields(buf, 0, len(buf)):
            if number == _PROTOCOL_VERSION and wire == 0:
                version = a & 0xFFFFFFFF
            elif number == _REQUEST_ID and wire == 0:
                request_id = a
            elif number == _ENV_OBSERVATION and wire == 2:
                body = (a, b)
            else:
                return None  # another body, or a known field with the wrong wire type
        if body is None:
            return None
        values: dict[str, int | memoryview] = {}
        for number, wire, a, b in _fields(buf, body[0], body[1]):
            name = _OBS_VARINTS.get(number)
            if name is not None:
                if wire != 0:
                    return None
                values[name] = a & 0xFFFFFFFF if number == 2 else a
                continue
            name = _OBS_BYTES.get(number)
            if name is not None:
                if wire != 2:
                    return None
                values[name] = buf[a:b]
            # other numbers: fields of a newer protocol, skipped as the runtime skips them
        return version, request_id, Observation(**values)
    except _Unreadable:
        return None
