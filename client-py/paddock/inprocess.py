"""The simulator inside this process: env sessions without a server.

``paddock.make_vec(64, paddock.IN_PROCESS, map="lakeside")`` (and ``F110Env``,
``gymnasium.make(..., endpoint=paddock.IN_PROCESS)``, the PettingZoo and SB3 envs) runs
the env sessions that a local ``paddock serve`` worker would host inside the learner's own
process, through the ``paddock_embed`` library: the wheel ships it beside this package;
``$PADDOCK_EMBED_LIB`` names another; in a source checkout it is found beside
``$PADDOCK_BIN`` or in cargo's target folder (``cargo build --release -p paddock-embed``).

Requests and replies are the wire's own protobuf messages and frames, handled by the
worker's own code, so an in-process session checks its arguments, refuses bad ones and
produces observations bit for bit as a server session with the same seeds does. What it
saves is the way there: no broker hop, no socket threads, no other processes taking turns
on the CPU, no fingerprint of every reply (nothing rebuilds an in-process session
elsewhere); the scans of a step are written by the simulator straight into the array the
learner gets (a new, read-only array per step, as from a server), and only the small
frames are copied. The library is called with the GIL released (``ctypes``), so the
learner's other threads run during a step. (Scans under 64 KiB, a few envs' worth, are
copied out instead: at that size the copy costs less.)
A bug in the simulator that would end a worker's session (a panic) ends it here too, as
an error; the process keeps running.

A vector env's copies step on the library's thread pool, as a worker's sessions do: one
thread per core this process may run on (``RAYON_NUM_THREADS`` sets another count; a
process pinned to one core steps on the calling thread alone); ``threads=`` applies to a
local server only. A forked child (``multiprocessing``'s and gymnasium's
``AsyncVectorEnv``'s default start method on Linux, which also made an env in the parent
first to read its spaces) makes the pool again for the envs it makes itself; an env
made before the fork stays the parent's, and the child is told so if it steps it.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf.message import Message

from . import errors
from ._proto import paddock_pb2 as pb
from .maps import MapBundle
from .transport import DEFAULT_TIMEOUT, IN_PROCESS, MapsAndModels, check_timeout

ABI_VERSION = 2
_ENV, _PUT_MAP, _PUT_BLOB, _SHIPPED = 1, 2, 3, 4
# Scans of at least this many bytes are written into an array handed to the library;
# fewer are copied out of its frame, which costs less than making and handing an array
# (about a microsecond) at that size.
_IN_PLACE_MIN = 64 << 10
# Room for this many frames' addresses (a reply's header and two payload frames).
_FRAMES = 4


def _library_name() -> str:
    if sys.platform == "darwin":
        return "libpaddock_embed.dylib"
    if sys.platform == "win32":
        return "paddock_embed.dll"
    return "libpaddock_embed.so"


def find_library() -> str:
    """The ``paddock_embed`` library: ``$PADDOCK_EMBED_LIB``; the wheel's copy in this
    package's ``_native/``; beside ``$PADDOCK_BIN``; then the source tree's cargo target
    folder (``$CARGO_TARGET_DIR`` or ``target/``, release before debug)."""
    env = os.environ.get("PADDOCK_EMBED_LIB")
    if env:
        return env
    name = _library_name()
    candidates = [Path(__file__).resolve().parent / "_native" / name]
    if os.environ.get("PADDOCK_BIN"):
        candidates.append(Path(os.environ["PADDOCK_BIN"]).resolve().parent / name)
    repo = Path(__file__).resolve().parents[2]
    roots = [Path(os.environ["CARGO_TARGET_DIR"])] if os.environ.get("CARGO_TARGET_DIR") else []
    roots.append(repo / "target")
    candidates += [root / profile / name for root in roots for profile in ("release", "debug")]
    for p in candidates:
        if p.is_file():
            return str(p)
    raise errors.ServerStartError(
        f"no {name} for the in-process simulator: set PADDOCK_EMBED_LIB, install the paddock "
        "wheel, or build it with `cargo build --release -p paddock-embed`"
    )


# the libraries loaded so far, by path: one per file (each its own copy of the simulator)
_LIBS: dict[str, ctypes.CDLL] = {}
_LIB_LOCK = threading.Lock()
def _library() -> ctypes.CDLL:
    """The library :func:`find_library` names now, loaded once per file (a session made
    after ``$PADDOCK_EMBED_LIB`` names another file runs that one), its ABI version
    checked."""
    path = find_library()
    with _LIB_LOCK:
        if path not in _LIBS:
            try:
                lib = ctypes.CDLL(path)
            except OSError as e:
                raise errors.ServerStartError(f"cannot load {path}: {e}") from e
            lib.paddock_embed_abi_version.restype = ctypes.c_uint32
            lib.paddock_embed_abi_version.argtypes = []
            got = lib.paddock_embed_abi_version()
            if got != ABI_VERSION:
                raise errors.ServerStartError(
                    f"{path} speaks ABI version {got}, this package {ABI_VERSION}: "
                    "install the library and the package from one build")
            lib.paddock_embed_new.restype = ctypes.c_void_p
            lib.paddock_embed_new.argtypes = []
            lib.paddock_embed_free.restype = None
            lib.paddock_embed_free.argtypes = [ctypes.c_void_p]
            lib.paddock_embed_call.restype = ctypes.c_int64
            lib.paddock_embed_call.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint64,
                                               ctypes.c_int32, ctypes.c_char_p, ctypes.c_size_t,
                                               ctypes.c_void_p, ctypes.c_size_t]
            lib.paddock_embed_frames.restype = ctypes.c_size_t
            lib.paddock_embed_frames.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p),
                                                 ctypes.POINTER(ctypes.c_size_t), ctypes.c_size_t]
            _LIBS[path] = lib
        return _LIBS[path]


class Frame:
    """One reply frame: its bytes (``.bytes``, as a ``zmq.Frame``; for scans the
    simulator wrote in place, the read-only uint8 array that holds them), read in place
    by numpy through ``.buffer``."""

    __slots__ = ("bytes",)

    def __init__(self, data: bytes | np.ndarray) -> None:
        self.bytes = data

    @property
    def buffer(self) -> memoryview:
        return memoryview(self.bytes)


class InProcess(MapsAndModels):
    """Env sessions inside this process, with the methods of
    :class:`paddock.transport.Connection` that envs use (``env``, ``map_ref``,
    ``driver_name``, ``status``, ``close``); ``endpoint`` is :data:`IN_PROCESS`. Maps
    given as paths go to a temporary map cache that :meth:`close` removes; ONNX models
    are registered with this process."""

    endpoint = IN_PROCESS

    def __init__(self, timeout: float = DEFAULT_TIMEOUT) -> None:
        check_timeout(timeout)
        super().__init__()
        self.timeout = float(timeout)
        self._lib = _library()
        self._lock = threading.Lock()
        # where the library writes the last reply's frames' addresses and lengths (room
        # for four; a reply with more is read again with room for all)
        self._data = (ctypes.c_void_p * _FRAMES)()
        self._lens = (ctypes.c_size_t * _FRAMES)()
        # session id -> the bytes of its step's scans (num_envs x learners x beams x f32)
        self._scan_bytes: dict[int, int] = {}
        self._handle = self._lib.paddock_embed_new()
        if not self._handle:
            raise errors.ServerStartError("the in-process simulator could not start (a bug)")

    def _call(self, kind: int, payload: bytes = b"", session: int = 0,
              op: int = 0, scans: np.ndarray | None = None) -> list[Frame]:
        with self._lock:
            if not self._handle:
                raise errors.PaddockError("the in-process simulator is closed")
            # the array's address (cheaper than `scans.ctypes.data`)
            into, size = (None, 0) if scans is None else (
                ctypes.addressof(ctypes.c_char.from_buffer(scans)), scans.nbytes)
            n = self._lib.paddock_embed_call(self._handle, kind, session, op, payload, len(payload),
                                             into, size)
            if n < -1:
                raise errors.ServerStartError(f"the in-process simulator answered {n}")
            # every frame's address and length in one call; a refusal (-1) is one frame,
            # the encoded Error
            count = self._lib.paddock_embed_frames(self._handle, self._data, self._lens, _FRAMES)
            if count > _FRAMES:
                self._data = (ctypes.c_void_p * count)()
                self._lens = (ctypes.c_size_t * count)()
                self._lib.paddock_embed_frames(self._handle, self._data, self._lens, count)
            data, lens = self._data, self._lens
            frames = [Frame(ctypes.string_at(data[i], lens[i]) if lens[i] else b"")
                      for i in range(count)]
        if n == -1:
            e = pb.Error.FromString(frames[0].bytes)
            raise errors.from_reply(e.code, e.field, e.message)
        return frames

    def env(self, session_id: int, op: int, msg: Message | None = None,
            timeout: float | None = None) -> tuple[pb.EnvReply, list[Frame]]:
        """A request on env session ``session_id`` (0 to open one), as
        :meth:`paddock.transport.Connection.env`: the reply's header and payload frames; a
        refusal is raised. ``timeout`` is accepted for the same signature (the call returns
        when the step is done)."""
        payload = b"" if msg is None else msg.SerializeToString()
        # a step's or reset's scans go straight into a new array of theirs
        size = self._scan_bytes.get(session_id, 0) if op in (pb.ENV_STEP, pb.ENV_RESET) else 0
        scans = np.empty(size, dtype=np.uint8) if size >= _IN_PLACE_MIN else None
        frames = self._call(_ENV, payload, session_id, op, scans)
        header = pb.EnvReply.FromString(frames[0].bytes)
        if header.HasField("error"):
            e = header.error
            raise errors.from_reply(e.code, e.field, e.message)
        if op == pb.ENV_OPEN and len(frames) == 2:
            o = pb.EnvOpened.FromString(frames[1].bytes)
            self._scan_bytes[header.session_id] = o.num_envs * o.num_learners * o.num_beams * 4
        elif op == pb.ENV_CLOSE:
            self._scan_bytes.pop(session_id, None)
        elif scans is not None and len(frames) == 3 and not frames[2].bytes:
            scans.flags.writeable = False
            frames[2] = Frame(scans)
        return header, frames[1:]

    def _put_map(self, bundle: MapBundle) -> pb.MapRef:
        """Checks a map bundle and keeps it in the library's temporary map cache."""
        return pb.MapRef.FromString(self._call(_PUT_MAP, bundle.to_proto().SerializeToString())[0].bytes)

    def _put_model(self, path: str, data: bytes) -> str:
        """Registers a model with this process; its ``onnx:<sha256>`` name."""
        return self._call(_PUT_BLOB, data)[0].bytes.decode()

    def status(self, timeout: float | None = None) -> pb.BrokerStatus:
        """What a broker's status says of its maps: the maps the library ships."""
        return pb.BrokerStatus.FromString(self._call(_SHIPPED)[0].bytes)

    def close(self) -> None:
        """Ends every session and frees the library's handle (and its map cache)."""
        with self._lock:
            if self._handle:
                self._lib.paddock_embed_free(self._handle)
                self._handle = None
            self._scan_bytes.clear()

    def __enter__(self) -> "InProcess":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
