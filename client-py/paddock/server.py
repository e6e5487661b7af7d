"""A local `paddock serve` (broker and workers in one process) that a learner on one
machine connects to; started and stopped by the env or the tests. On Linux it listens on
a Unix domain socket in the abstract namespace (``ipc://@paddock-...``: no file to
clean up, and cheaper per message than loopback TCP: 5-12 % more env-steps per second
for a 64-env vector env on one core, docs/performance-vecenv.md); elsewhere on a free
loopback TCP port.

The server is given this process's id (``--parent-pid``) and stops by itself once this
process is no longer its parent, so a learner that crashes or is killed (SIGKILL
included) leaves no server behind. It watches its parent process rather than relying on
Linux's parent-death signal, which fires when the *thread* that started it ends."""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
from pathlib import Path

import zmq

from . import errors
from .transport import Connection


def find_paddock() -> str:
    """The `paddock` binary: ``$PADDOCK_BIN``; the one the wheel installed beside this
    interpreter's scripts (a venv's ``bin/``, found without the venv being activated, or
    the user scripts folder); PATH; then the source tree's cargo target folder
    (``$CARGO_TARGET_DIR`` or ``target/``, release before debug)."""
    env = os.environ.get("PADDOCK_BIN")
    if env:
        return env
    schemes = [sysconfig.get_default_scheme(), sysconfig.get_preferred_scheme("user")]
    for scheme in schemes:
        p = Path(sysconfig.get_path("scripts", scheme)) / "paddock"
        if p.is_file() and os.access(p, os.X_OK):
            return str(p)
    found = shutil.which("paddock")
    if found:
        return found
    repo = Path(__file__).resolve().parents[2]
    roots = [Path(os.environ["CARGO_TARGET_DIR"])] if os.environ.get("CARGO_TARGET_DIR") else []
    roots.append(repo / "target")
    for root in roots:
        for profile in ("release", "debug"):
            p = root / profile / "paddock"
            if p.is_file() and os.access(p, os.X_OK):
                return str(p)
    raise errors.ServerStartError(
        "no `paddock` binary: set PADDOCK_BIN, put it on PATH, or build it with "
        "`cargo build --release -p paddock`"
    )


TRANSPORTS = ("auto", "ipc", "tcp")


def _check_transport(transport: str) -> None:
    if transport not in TRANSPORTS:
        raise ValueError(f"transport = {transport!r} is not one of {', '.join(TRANSPORTS)}")


def local_endpoint(transport: str = "auto") -> str:
    """A fresh endpoint for a local server: ``ipc://@paddock-<pid>-<random>`` (a Unix
    domain socket in Linux's abstract namespace) for ``"ipc"``, and for ``"auto"`` where
    that is available; else ``tcp://127.0.0.1:<free port>``."""
    _check_transport(transport)
    abstract = sys.platform.startswith("linux") and zmq.has("ipc")
    if transport == "ipc" and not abstract:
        raise ValueError(f"transport = 'ipc' needs Linux (abstract Unix domain sockets); "
                         f"this is {sys.platform}: use 'tcp' or 'auto'")
    if transport != "tcp" and abstract:
        return f"ipc://@paddock-{os.getpid()}-{secrets.token_hex(8)}"
    return f"tcp://127.0.0.1:{free_port()}"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process(p: subprocess.Popen) -> None:
    """Stops a `paddock` process as Ctrl-C does (SIGINT: `serve` stops its workers and
    removes its temporary state directory; a worker says bye), killing it after 10 s."""
    if p.poll() is not None:
        return
    p.send_signal(signal.SIGINT)
    try:
        p.wait(timeout=10)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


class LocalServer:
    """`paddock serve` for this machine's learners; ``endpoint`` is where clients connect
    (see :func:`local_endpoint` for ``transport``)."""

    def __init__(self, threads: int = 0, binary: str | None = None,
                 start_timeout: float = 60.0, extra_args: list[str] | None = None,
                 transport: str = "auto") -> None:
        # first: `__del__` stops the process, also of a server refused below
        self.process: subprocess.Popen[bytes] | None = None
        # the process that started it: a forked child's copy of this object leaves the
        # server alone (stopping it would stop its parent's)
        self._owner = os.getpid()
        _check_transport(transport)
        self.transport = transport
        self.binary = binary or find_paddock()
        self.threads = threads
        self.start_timeout = start_timeout
        self.extra_args = list(extra_args or [])
        self.endpoint = ""
        # a file, not a pipe: a chatty server must never block on a full pipe
        self._log = tempfile.TemporaryFile()

    def start(self) -> "LocalServer":
        last = ""
        self._owner = os.getpid()
        for _ in range(3):  # a port taken between probing and binding: try another
            self.endpoint = local_endpoint(self.transport)
            # the server stops when this process is gone, even killed: no orphans
            args = [self.binary, "serve", "--bind", self.endpoint,
                    "--parent-pid", str(os.getpid())]
            if self.threads:
                args += ["--threads", str(self.threads)]
            self._log.seek(0)
            self._log.truncate()
            self.process = subprocess.Popen(args + self.extra_args, stdout=subprocess.DEVNULL,
                                            stderr=self._log)
            try:
                self._wait_ready()
                return self
            except errors.ServerStartError as e:
                last = str(e)
                self.stop()
        raise errors.ServerStartError(last)

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + self.start_timeout
        with Connection(self.endpoint, timeout=1.0) as c:
            while time.monotonic() < deadline:
                assert self.process is not None
                if self.process.poll() is not None:
                    err = self.log()
                    raise errors.ServerStartError(
                        f"`paddock serve --bind {self.endpoint}` exited with {self.process.returncode}: {err.strip()[-2000:]}"
                    )
                try:
                    st = c.status(timeout=1.0)
                    if len(st.workers) > 0:
                        return
                except errors.BrokerUnavailable:
                    pass
                time.sleep(0.1)
        raise errors.ServerStartError(
            f"`paddock serve` at {self.endpoint} had no worker after {self.start_timeout:g} s"
        )

    def stop(self) -> None:
        p = self.process
        self.process = None
        if p is not None and self._owner == os.getpid():
            stop_process(p)

    def running(self) -> bool:
        """Whether this process started the server and it has not exited."""
        return (self.process is not None and self._owner == os.getpid()
                and self.process.poll() is None)

    def log(self) -> str:
        """What the server wrote to stderr so far."""
        self._log.seek(0)
        return self._log.read().decode(errors="replace")

    def __enter__(self) -> "LocalServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __del__(self) -> None:
        self.stop()


# The local servers of the envs made with ``endpoint=None``, one per worker thread count:
# the first such env starts it, each holds it, the last one closed stops it. Sixteen envs
# of a gymnasium SyncVectorEnv started sixteen servers (339 MB, 208 threads, 2.7 s).
_SHARED: dict[int, tuple[LocalServer, int]] = {}
_SHARED_LOCK = threading.Lock()


def _forget_shared() -> None:
    # a forked child: the parent's servers are not the child's to share or stop
    global _SHARED_LOCK
    _SHARED.clear()
    _SHARED_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_shared)


def hold_shared(threads: int = 0) -> LocalServer:
    """This process's shared local server for ``threads`` worker threads (0: one per
    core), started if there is none or it has ended; give it back with
    :func:`release_shared`."""
    with _SHARED_LOCK:
        held = _SHARED.get(threads)
        if held is not None and held[0].running():
            _SHARED[threads] = (held[0], held[1] + 1)
            return held[0]
        server = LocalServer(threads=threads).start()
        _SHARED[threads] = (server, 1)
        return server


def release_shared(server: LocalServer) -> None:
    """Gives back a server of :func:`hold_shared`; the last holder stops it. (A server
    that ended and was replaced meanwhile is stopped by its last holder too.)"""
    with _SHARED_LOCK:
        held = _SHARED.get(server.threads)
        if held is not None and held[0] is server:
            if held[1] > 1:
                _SHARED[server.threads] = (server, held[1] - 1)
                return
            del _SHARED[server.threads]
    server.stop()
