"""The car's sensor drivers, played by Cyclone DDS, for a `paddock bridge drive` node.

urg_node's `/scan` (Hokuyo scans in a corridor, rclcpp's default QoS, depth 20), VESC
odometry on `/odom` (driving along +x at a steady speed) and a `/drive` subscription with
ackermann_mux's QoS, in one participant: what the drive tests feed the node and read back.
"""

import time

from ros2_node import CycloneRosNode, default_qos, take_all
from ros2_types import AckermannDriveStamped, LaserScan, Odometry
from test_cyclone_interop import DISCOVERY_S, corridor_scan, odometry, stamp_now


class FakeCar:
    def __init__(self, domain_id, speed=1.5, period=0.025):
        node = CycloneRosNode(domain_id)
        self.scan_pub = node.publisher("/scan", LaserScan, default_qos(20))
        self.odom_pub = node.publisher("/odom", Odometry, default_qos(10))
        self.drive_sub = node.subscription("/drive", AckermannDriveStamped, default_qos(10))
        self.speed, self.period, self.x = speed, period, 0.0
        self.sent_stamps = []

    def scan(self, stamp):
        """The default scene: a straight corridor, walls 0.8 m left and 1.2 m right."""
        return corridor_scan(stamp, left=0.8, right=1.2)

    def feed(self, seconds, scan=None, stamp=None, sensors=True, until=None):
        """Sensors every period for `seconds` (or until `until()` holds): the scan from
        `scan(stamp)` (default [`FakeCar.scan`]), all stamped `stamp` when given (a hung
        driver re-sending its old message), none when `sensors` is false. Returns the
        drive commands seen meanwhile."""
        got = []
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (until and until()):
            if sensors:
                s = stamp or stamp_now()
                self.sent_stamps.append(s)
                self.odom_pub.write(odometry(s, self.x, self.speed))
                self.scan_pub.write((scan or self.scan)(s))
                self.x += self.speed * self.period
            time.sleep(self.period)
            got.extend(take_all(self.drive_sub))
        return got

    def wait_moving(self, proc):
        """Feed until a command with speed arrives (discovery and start-up); those seen."""
        moving = []
        deadline = time.monotonic() + DISCOVERY_S
        while not moving and time.monotonic() < deadline and proc.alive():
            moving = [c for c in self.feed(0.25) if c.drive.speed > 0.0]
        return moving
