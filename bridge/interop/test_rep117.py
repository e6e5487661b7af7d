"""REP 117 ranges from a third-party publisher: Cyclone DDS plays urg_node.

A Hokuyo UST-10LX scan (1081 beams over 270 degrees, range_min 0.06 m) in a corridor,
published by Cyclone as urg_node publishes it, with the beams within 15 degrees of straight
ahead replaced by what REP 117 and the Hokuyo driver put there when something is in the
way: `-inf` (closer than range_min), NaN (no valid reading) or an error code (a value
below range_min). Each used to read as open road (the node kept commanding speed); the
drive node must answer each with zero speed, and drive again when the scan sees ahead.
"""

import math
import re
import time

from ros2_node import CycloneRosNode, default_qos, take_all
from ros2_types import AckermannDriveStamped, LaserScan, Odometry
from test_cyclone_interop import DISCOVERY_S, corridor_scan, failure, odometry, stamp_now

AHEAD_DEG = 15.0
# what urg_node or REP 117 puts on a beam that sees something but gives no valid range
BLOCKED_AHEAD = {
    "too close (-inf)": -math.inf,
    "invalid (NaN)": math.nan,
    "Hokuyo error code (below range_min)": 0.005,
}


def with_ahead(scan: LaserScan, r: float) -> LaserScan:
    for k in range(len(scan.ranges)):
        if abs(scan.angle_min + k * scan.angle_increment) <= math.radians(AHEAD_DEG):
            scan.ranges[k] = r
    return scan


def test_blocked_or_invalid_returns_ahead_stop_the_car_and_clear_ones_release_it(
    paddock, domain_id
):
    car = CycloneRosNode(domain_id)
    scan_pub = car.publisher("/scan", LaserScan, default_qos(20))
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    drive_sub = car.subscription("/drive", AckermannDriveStamped, default_qos(10))
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2", "--domain-id", str(domain_id)
    )
    x, speed, period = 0.0, 1.5, 0.025

    def feed(seconds, ahead=None):
        """Sensors every 25 ms for `seconds`; the drive commands seen meanwhile."""
        nonlocal x
        got = []
        end = time.monotonic() + seconds
        while time.monotonic() < end and proc.alive():
            stamp = stamp_now()
            scan = corridor_scan(stamp, left=0.6, right=0.6)
            if ahead is not None:
                scan = with_ahead(scan, ahead)
            odom_pub.write(odometry(stamp, x, speed))
            scan_pub.write(scan)
            x += speed * period
            time.sleep(period)
            got.extend(take_all(drive_sub))
        return got

    moving = []
    deadline = time.monotonic() + DISCOVERY_S
    while not moving and time.monotonic() < deadline and proc.alive():
        moving = [c for c in feed(0.25) if c.drive.speed > 0.0]
    assert moving, failure(proc, "no /drive command with speed reached Cyclone")

    for what, r in BLOCKED_AHEAD.items():
        got = feed(1.0, ahead=r)
        assert got, failure(proc, f"{what}: no commands")
        # the stop comes with the first such scan; the last half second is all zero
        tail = [c.drive.speed for c in got[len(got) // 2 :]]
        assert tail and all(s == 0.0 for s in tail), failure(
            proc, f"{what} ahead: commanded {sorted(set(tail))} m/s"
        )
        # a clear scan releases the stop (the time-to-collision stop after 0.5 s clear)
        clear = feed(1.5)
        assert clear and clear[-1].drive.speed > 0.0, failure(
            proc, f"after {what}: still {clear[-3:]}"
        )
    assert proc.stop() == 0, failure(proc, "exit status")
    # the exit summary names the rules that acted: the time-to-collision stop for the
    # too-close returns, "blind ahead" for the invalid ones
    m = re.search(r"\((\d+) engagements, .*?\), (\d+) blind-ahead stops", proc.output())
    assert m, failure(proc, "no safety summary")
    assert int(m.group(1)) >= 1 and int(m.group(2)) >= 1, m.group(0)
