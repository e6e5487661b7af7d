"""Fixtures for the ROS 2 interop tests: Eclipse Cyclone DDS (the DDS under
rmw_cyclonedds_cpp, a tier-1 ROS 2 middleware) on one side, the `paddock` binary on the
other, talking over loopback only.

Discovery needs no network besides loopback: Cyclone is pinned to `lo` with multicast off
and 127.0.0.1 as its unicast peer, using the well-known per-participant ports (participant
index `auto`), so it sends its participant announcements to every same-host participant
slot; RustDDS (under `paddock`) announces itself to the same slots on 127.0.0.1 as well as
by multicast. Each test takes a DDS domain of its own, from a block of domains the run
holds a lock on, so parallel runs and the Rust tests (domains 61-69) do not hear each other.
"""

import fcntl
import os
import pathlib
import signal
import subprocess
import tempfile
import time

import pytest

CYCLONE_LOOPBACK = (
    "<CycloneDDS><Domain id='any'>"
    "<General><Interfaces><NetworkInterface name='lo'/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>"
    "<Peers><Peer address='127.0.0.1'/></Peers></Discovery>"
    "</Domain></CycloneDDS>"
)
# Read by the Cyclone C library when the first participant of a domain is created.
os.environ["CYCLONEDDS_URI"] = CYCLONE_LOOPBACK

# Domains 120..215 in four blocks of 24: one domain per test below, a block per pytest
# run. A run claims its block with an exclusive lock on a file, so concurrent runs on one
# host (two checkouts testing at once) never share a domain: a drive node of one run
# would otherwise answer the other run's sensors.
_DOMAIN_FIRST, _DOMAIN_BLOCK, _DOMAIN_BLOCKS = 120, 24, 4
_domains_taken = [0]


@pytest.fixture(scope="session")
def _domain_block():
    """The first domain of a block no other run on this host holds (waits for one)."""
    deadline = time.monotonic() + 600.0
    start = os.getpid() % _DOMAIN_BLOCKS
    while True:
        for i in range(_DOMAIN_BLOCKS):
            block = (start + i) % _DOMAIN_BLOCKS
            path = pathlib.Path(tempfile.gettempdir()) / f"paddock-interop-domains-{block}.lock"
            f = open(path, "a")
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.close()
                continue
            yield _DOMAIN_FIRST + block * _DOMAIN_BLOCK
            f.close()  # releases the lock
            return
        assert time.monotonic() < deadline, "no free block of DDS domains for 10 minutes"
        time.sleep(1.0)


@pytest.fixture
def domain_id(_domain_block):
    """A DDS domain (ROS_DOMAIN_ID) no other test of this run, nor another run, uses."""
    k = _domains_taken[0]
    _domains_taken[0] += 1
    assert k < _DOMAIN_BLOCK, (
        f"more than {_DOMAIN_BLOCK} interop tests: widen the domain blocks in conftest.py"
    )
    return _domain_block + k


@pytest.fixture(scope="session")
def paddock_bin():
    path = os.environ.get("PADDOCK_BIN")
    if not path:
        pytest.fail("PADDOCK_BIN is not set: run scripts/python.sh or point it at a paddock binary")
    if not os.access(path, os.X_OK):
        pytest.fail(f"PADDOCK_BIN={path} is not an executable file")
    return path


class PaddockProcess:
    """A `paddock bridge ...` subprocess; its output goes to a log file shown on failure."""

    def __init__(self, argv, log_path: pathlib.Path):
        self.log_path = log_path
        self._log = open(log_path, "wb")
        env = dict(os.environ)
        # RustDDS warns about every datagram above 1500 bytes (each scan): keep errors only
        env.setdefault("RUST_LOG", "warn,rustdds=error")
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT, env=env)

    def output(self) -> str:
        # the child writes to the file itself: nothing of ours to flush
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout=10.0) -> int:
        """Ctrl-C (the nodes stop cleanly on SIGINT), then a kill if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if not self._log.closed:
            self._log.close()
        return self.proc.returncode


@pytest.fixture
def paddock(paddock_bin, tmp_path):
    """Start `paddock bridge <args>`; every process started is stopped at teardown."""
    started = []

    def start(*args):
        p = PaddockProcess([paddock_bin, "bridge", *args], tmp_path / f"paddock-{len(started)}.log")
        started.append(p)
        return p

    yield start
    for p in started:
        p.stop()

