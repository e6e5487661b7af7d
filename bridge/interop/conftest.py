"""Fixtures for the ROS 2 interop tests: Eclipse Cyclone DDS (the DDS under
rmw_cyclonedds_cpp, a tier-1 ROS 2 middleware) on one side, the `paddock` binary on the
other, talking over loopback only.

Discovery needs no network besides loopback: Cyclone is pinned to `lo` with multicast off
and 127.0.0.1 as its unicast peer, using the well-known per-participant ports (participant
index `auto`), so it sends its participant announcements to every same-host participant
slot; RustDDS (under `paddock`) announces itself to the same slots on 127.0.0.1 as well as
by multicast. Each test takes a DDS domain of its own (derived from the process id), so
parallel runs and the Rust tests (domains 61-64) do not hear each other.
"""

import os
import pathlib
import signal
import subprocess

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

# 120..215 in blocks of 24: one domain per test below, a block per concurrent pytest run
_DOMAIN_BLOCK = 24
_DOMAIN_BASE = 120 + (os.getpid() % 4) * _DOMAIN_BLOCK
_domains_taken = [0]


@pytest.fixture
def domain_id():
    """A DDS domain (ROS_DOMAIN_ID) no other test of this run uses."""
    k = _domains_taken[0]
    _domains_taken[0] += 1
    assert k < _DOMAIN_BLOCK, (
        f"more than {_DOMAIN_BLOCK} interop tests: widen the domain blocks in conftest.py"
    )
    return _DOMAIN_BASE + k


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

