"""A real car's exits and recordings, against Eclipse Cyclone DDS and third-party readers.

- Every signal that ends `paddock bridge drive` (SIGINT from Ctrl-C, SIGTERM from
  systemd / `docker stop` / ros2 launch, SIGHUP from a closed terminal or SSH session)
  leaves the car stopped: the last command a Cyclone subscriber sees on /drive (with
  ackermann_mux's QoS) is zero speed, though the sensors are still fresh and the driver
  was commanding speed.
- A sensor that keeps publishing on time but re-sends old data (its stamps stand still)
  stops the car: staleness is judged by header stamp as well as arrival.
- `paddock bridge record` ended by any of those signals writes a finalised MCAP that the
  `mcap` Python library (Foxglove's reference reader) opens, summary and all.
"""

import math
import signal
import time

import pytest
from mcap.reader import make_reader

from fake_car import FakeCar
from ros2_node import CycloneRosNode, default_qos, take_all, wait_until
from ros2_types import AckermannDriveStamped, LaserScan, Odometry
from test_cyclone_interop import corridor_scan, drive_cmd, failure, odometry, stamp_now

SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: s.name)
def test_every_signal_stops_the_car(paddock, domain_id, sig):
    car = FakeCar(domain_id)
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2", "--domain-id", str(domain_id)
    )
    assert car.wait_moving(proc), failure(proc, "no /drive command with speed reached Cyclone")
    before = car.feed(0.5)
    assert before and before[-1].drive.speed > 0.0, before[-3:]

    # the signal arrives while the sensors are fresh and the driver wants to go on
    proc.proc.send_signal(sig)
    after = car.feed(5.0, until=lambda: not proc.alive())
    assert not proc.alive(), failure(proc, f"still running 5 s after {sig.name}")
    after.extend(wait_until(lambda: take_all(car.drive_sub), 1.0) or [])
    rc = proc.stop()
    assert rc == 0, failure(proc, f"exit status {rc} after {sig.name}")
    assert f"stopped by {sig.name}" in proc.output(), failure(proc, "signal not reported")
    assert after, failure(proc, f"no command after {sig.name}: the zero-speed stop is missing")
    last = after[-1].drive
    assert last.speed == 0.0 and last.steering_angle == 0.0, after[-5:]


def test_a_sensor_resending_old_data_stops_the_car(paddock, domain_id):
    car = FakeCar(domain_id)
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2", "--domain-id", str(domain_id)
    )
    assert car.wait_moving(proc), failure(proc, "no /drive command with speed reached Cyclone")
    assert car.feed(0.5)[-1].drive.speed > 0.0
    # the drivers hang, re-sending their last message at the usual rate
    resent = car.feed(1.0, stamp=stamp_now())
    assert len(resent) >= 20, failure(proc, f"{len(resent)} commands in 1 s")
    tail = resent[len(resent) // 2 :]
    assert all(c.drive.speed == 0.0 for c in tail), failure(proc, f"still driving: {tail[-3:]}")
    # fresh data again: the car drives on
    again = car.feed(1.0)
    assert again and again[-1].drive.speed > 0.0, again[-3:]
    assert proc.stop() == 0, failure(proc, "exit status")


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: s.name)
def test_record_finalises_the_mcap_on_every_signal(paddock, domain_id, sig, tmp_path):
    bag = tmp_path / "run.mcap"
    proc = paddock("record", "--out", str(bag), "--domain-id", str(domain_id))
    car = CycloneRosNode(domain_id)
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    drive_pub = car.publisher("/drive", AckermannDriveStamped, default_qos(10))
    scan_pub = car.publisher("/scan", LaserScan, default_qos(20))
    # discovery: keep publishing for a while, then long enough for a few hundred messages
    x = 0.0
    end = time.monotonic() + 4.0
    while time.monotonic() < end and proc.alive():
        stamp = stamp_now()
        odom_pub.write(odometry(stamp, x, 1.0))
        drive_pub.write(drive_cmd(1.0, 0.1))
        scan_pub.write(corridor_scan(stamp, left=1.0, right=1.0))
        x += 0.01
        time.sleep(0.01)
    proc.proc.send_signal(sig)
    assert wait_until(lambda: not proc.alive(), 10.0), failure(proc, f"alive after {sig.name}")
    rc = proc.stop()
    assert rc == 0, failure(proc, f"exit status {rc} after {sig.name}")
    assert f"stopped by {sig.name}" in proc.output(), failure(proc, "signal not reported")

    with open(bag, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary: the recording was not finalised"
        counts = {
            summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
        }
        assert counts.get("/odom", 0) > 50 and counts.get("/drive", 0) > 50, counts
        assert counts.get("/scan", 0) > 20, counts
        odoms = [
            m for _, ch, m in reader.iter_messages(topics=["/odom"]) if ch.topic == "/odom"
        ]
    assert len(odoms) == counts["/odom"]
    assert all(math.isfinite(m.log_time) for m in odoms)
