"""The laser's mount on the car, from a tf2 static broadcaster on Cyclone DDS.

f1tenth_system publishes `base_link -> laser` on /tf_static (tf2's static QoS:
reliable, transient local, so a node started later still gets it). Here the Hokuyo sits
0.27 m ahead of base_link, upside down (rolled by 180 degrees): its beams sweep
clockwise, so an opening on the car's right appears at positive scan angles. The drive
node must take the mount from /tf_static (or from flags) and steer the gap follower
into the opening, not into the wall the unmirrored scan would show there.
"""

import math
import time

from ros2_node import CycloneRosNode, default_qos, static_tf_qos, take_all
from ros2_types import (
    AckermannDriveStamped,
    Header,
    LaserScan,
    Odometry,
    Quaternion,
    TFMessage,
    Transform,
    TransformStamped,
    Vector3,
)
from test_cyclone_interop import DISCOVERY_S, failure, odometry, stamp_now

LASER_X = 0.27
UPSIDE_DOWN = Quaternion(x=1.0, y=0.0, z=0.0, w=0.0)


def flipped_scan(stamp, left, right):
    """What an upside-down Hokuyo at LASER_X sees in a corridor with walls `left` and
    `right` metres beside base_link's axis: beam angle a points to the car's -a."""
    n, fov, range_max = 1081, math.radians(270.0), 30.0
    angle_min, inc = -0.5 * fov, fov / (n - 1)
    ranges = []
    for k in range(n):
        b = -(angle_min + k * inc)  # direction in base_link
        s = math.sin(b)
        r = left / s if s > 1e-9 else (right / -s if s < -1e-9 else math.inf)
        ranges.append(r if r <= range_max else math.inf)
    return LaserScan(
        header=Header(stamp=stamp, frame_id="laser"),
        angle_min=angle_min,
        angle_max=-angle_min,
        angle_increment=inc,
        scan_time=1.0 / 40.0,
        range_min=0.06,
        range_max=range_max,
        ranges=ranges,
        intensities=[],
    )


def drive_and_collect(paddock, domain_id, *flags, broadcast_tf):
    car = CycloneRosNode(domain_id)
    if broadcast_tf:
        tf_pub = car.publisher("/tf_static", TFMessage, static_tf_qos())
        tf_pub.write(
            TFMessage(
                transforms=[
                    TransformStamped(
                        header=Header(stamp=stamp_now(), frame_id="base_link"),
                        child_frame_id="laser",
                        transform=Transform(
                            translation=Vector3(x=LASER_X, y=0.0, z=0.1), rotation=UPSIDE_DOWN
                        ),
                    )
                ]
            )
        )
    scan_pub = car.publisher("/scan", LaserScan, default_qos(20))
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    drive_sub = car.subscription("/drive", AckermannDriveStamped, default_qos(10))
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2",
        "--domain-id", str(domain_id), *flags,
    )
    moving = []
    deadline = time.monotonic() + DISCOVERY_S + 3.0
    while len(moving) < 40 and time.monotonic() < deadline and proc.alive():
        stamp = stamp_now()
        odom_pub.write(odometry(stamp, 0.0, 1.0))
        # an opening to the right: wall 0.5 m on the left, 3 m on the right
        scan_pub.write(flipped_scan(stamp, left=0.5, right=3.0))
        time.sleep(0.025)
        moving.extend(c for c in take_all(drive_sub) if c.drive.speed > 0.0)
    assert proc.stop() == 0, failure(proc, "exit status")
    return proc, moving


def test_mount_from_tf_static_turns_the_driver_into_the_opening(paddock, domain_id):
    proc, moving = drive_and_collect(paddock, domain_id, broadcast_tf=True)
    assert len(moving) >= 40, failure(proc, f"{len(moving)} commands with speed")
    out = proc.output()
    assert "laser mount (/tf_static): x 0.270 m, y 0.000 m, yaw 0.000 rad, flipped" in out, (
        failure(proc, "mount not taken from /tf_static")
    )
    # once the mount is known (the first commands may precede it), the car turns right
    late = moving[len(moving) // 2 :]
    assert all(c.drive.steering_angle < -0.01 for c in late), [
        round(c.drive.steering_angle, 3) for c in late
    ]


def test_mount_from_flags_does_the_same(paddock, domain_id):
    proc, moving = drive_and_collect(
        paddock, domain_id, "--laser-x", "0.27", "--laser-flipped", broadcast_tf=False
    )
    assert len(moving) >= 40, failure(proc, f"{len(moving)} commands with speed")
    assert "laser mount (flags): x 0.270 m, y 0.000 m, yaw 0.000 rad, flipped" in proc.output()
    assert all(c.drive.steering_angle < -0.01 for c in moving), [
        round(c.drive.steering_angle, 3) for c in moving
    ]
