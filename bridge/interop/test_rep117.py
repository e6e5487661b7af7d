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

from fake_car import FakeCar
from ros2_types import LaserScan
from test_cyclone_interop import corridor_scan, failure

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
    car = FakeCar(domain_id)
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2", "--domain-id", str(domain_id)
    )
    assert car.wait_moving(proc), failure(proc, "no /drive command with speed reached Cyclone")

    def corridor(stamp, ahead=None):
        scan = corridor_scan(stamp, left=0.6, right=0.6)
        return scan if ahead is None else with_ahead(scan, ahead)

    for what, r in BLOCKED_AHEAD.items():
        got = car.feed(1.0, scan=lambda stamp: corridor(stamp, r))
        assert got, failure(proc, f"{what}: no commands")
        # the stop comes with the first such scan; the last half second is all zero
        tail = [c.drive.speed for c in got[len(got) // 2 :]]
        assert tail and all(s == 0.0 for s in tail), failure(
            proc, f"{what} ahead: commanded {sorted(set(tail))} m/s"
        )
        # a clear scan releases the stop (the time-to-collision stop after 0.5 s clear)
        clear = car.feed(1.5, scan=corridor)
        assert clear and clear[-1].drive.speed > 0.0, failure(
            proc, f"after {what}: still {clear[-3:]}"
        )
    assert proc.stop() == 0, failure(proc, "exit status")
    # the exit summary names the rules that acted: the time-to-collision stop for the
    # too-close returns, "blind ahead" for the invalid ones
    m = re.search(r"\((\d+) engagements, .*?\), (\d+) blind-ahead stops", proc.output())
    assert m, failure(proc, "no safety summary")
    assert int(m.group(1)) >= 1 and int(m.group(2)) >= 1, m.group(0)
