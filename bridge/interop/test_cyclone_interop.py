"""`paddock bridge` against Eclipse Cyclone DDS posing as ROS 2 nodes (rmw_cyclonedds_cpp).

The Cyclone side uses exactly what a ROS 2 node on rmw_cyclonedds_cpp puts on the wire
(see ros2_node.py and ros2_types.py) with the QoS of the F1TENTH stack: urg_node
publishing /scan, VESC odometry and ackermann_mux's /drive subscription with the default
profile (reliable), a driver subscribing /scan with the sensor-data profile (best effort),
tf2's static profile for /tf_static. Every test fails if messages do not flow.
"""

import math
import re
import time

import pytest

from ros2_node import (
    CycloneRosNode,
    default_qos,
    sensor_data_qos,
    static_tf_qos,
    take_all,
    wait_until,
)
from ros2_types import (
    AckermannDrive,
    AckermannDriveStamped,
    Header,
    LaserScan,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    PoseWithCovarianceStamped,
    Quaternion,
    TFMessage,
    Time,
    Twist,
    TwistWithCovariance,
    Vector3,
)

MAX_STEER = 0.4189
# a shipped map (maps/harbour): the SIL car starts on its centerline
MAP = "harbour"
DISCOVERY_S = 10.0


def stamp_now():
    t = time.time()
    return Time(sec=int(t), nanosec=int((t - int(t)) * 1e9))


def stamp_secs(t: Time) -> float:
    return t.sec + t.nanosec * 1e-9


def yaw_of(q: Quaternion) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def quaternion_from_yaw(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))


def corridor_scan(stamp: Time, left: float, right: float) -> LaserScan:
    """A Hokuyo UST-10LX scan (1081 beams over 270 degrees, with intensities, as
    urg_node publishes it) in a straight corridor: walls `left` and `right` metres to the
    sides, open ahead up to the 30 m range limit."""
    n, fov, range_max = 1081, math.radians(270.0), 30.0
    angle_min, inc = -0.5 * fov, fov / (n - 1)
    ranges = []
    for k in range(n):
        s = math.sin(angle_min + k * inc)
        r = left / s if s > 1e-9 else (right / -s if s < -1e-9 else range_max)
        ranges.append(min(r, range_max))
    return LaserScan(
        header=Header(stamp=stamp, frame_id="laser"),
        angle_min=angle_min,
        angle_max=-angle_min,
        angle_increment=inc,
        time_increment=1.0 / 40.0 / n,
        scan_time=1.0 / 40.0,
        range_min=0.06,
        range_max=range_max,
        ranges=ranges,
        intensities=[1000.0] * n,
    )


def odometry(stamp: Time, x: float, speed: float) -> Odometry:
    """VESC odometry (vesc_to_odom): `odom` -> `base_link`, driving along +x."""
    return Odometry(
        header=Header(stamp=stamp, frame_id="odom"),
        child_frame_id="base_link",
        pose=PoseWithCovariance(pose=Pose(position=Point(x=x, y=0.0, z=0.0))),
        twist=TwistWithCovariance(twist=Twist(linear=Vector3(x=speed, y=0.0, z=0.0))),
    )


def drive_cmd(speed: float, steer: float = 0.0) -> AckermannDriveStamped:
    return AckermannDriveStamped(
        header=Header(stamp=stamp_now(), frame_id="base_link"),
        drive=AckermannDrive(steering_angle=steer, speed=speed),
    )


def failure(proc, what):
    return f"{what}\n--- paddock output ---\n{proc.output()[-4000:]}"


def test_drive_node_answers_cyclone_sensors_and_stops_when_they_fall_silent(paddock, domain_id):
    """(a) A follow-the-gap `paddock bridge drive` node driven by Cyclone's /scan + /odom."""
    car = CycloneRosNode(domain_id)
    # urg_node (f1tenth_system's LIDAR driver) publishes with rclcpp's default QoS, depth 20
    scan_pub = car.publisher("/scan", LaserScan, default_qos(20))
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    drive_sub = car.subscription("/drive", AckermannDriveStamped, default_qos(10))
    proc = paddock(
        "drive", "--driver", "follow-the-gap", "--max-speed", "2", "--domain-id", str(domain_id)
    )
    x, speed, period = 0.0, 1.5, 0.025
    sent_stamps = []

    def feed(seconds, sensors=True):
        nonlocal x
        got = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if sensors:
                stamp = stamp_now()
                sent_stamps.append(stamp_secs(stamp))
                odom_pub.write(odometry(stamp, x, speed))
                scan_pub.write(corridor_scan(stamp, left=0.8, right=1.2))
                x += speed * period
            time.sleep(period)
            got.extend(take_all(drive_sub))
        return got

    # discovery and start-up: commands with speed arrive once the sensors are seen
    moving = []
    deadline = time.monotonic() + DISCOVERY_S
    while not moving and time.monotonic() < deadline and proc.alive():
        moving = [c for c in feed(0.25) if c.drive.speed > 0.0]
    assert moving, failure(proc, "no /drive command with speed reached Cyclone")

    # fresh sensors: every command is a sane, clamped drive command on the sensors' clock
    driving = feed(1.5)
    assert len(driving) >= 20, failure(proc, f"only {len(driving)} commands in 1.5 s")
    for c in driving:
        d = c.drive
        assert math.isfinite(d.steering_angle) and abs(d.steering_angle) <= MAX_STEER + 1e-6, c
        assert 0.0 < d.speed <= 2.0 + 1e-6, c
        assert c.header.frame_id == "base_link", c
        # commands are stamped on the newest sensor stamp plus the time since it arrived
        t = stamp_secs(c.header.stamp)
        assert min(sent_stamps) - 0.5 < t < time.time() + 0.5, (t, sent_stamps[-1])
    # the straight corridor is open ahead: the gap follower drives on
    assert max(c.drive.speed for c in driving) >= 1.0, driving[-5:]

    # the LIDAR and the VESC fall silent: keep-alive commands turn to a stop within the
    # sensor timeout (0.25 s) and stay there
    silent = feed(1.0, sensors=False)
    assert len(silent) >= 10, failure(proc, f"only {len(silent)} keep-alive commands in 1 s")
    tail = silent[len(silent) // 2 :]
    assert all(c.drive.speed == 0.0 and c.drive.steering_angle == 0.0 for c in tail), tail

    rc = proc.stop()
    out = proc.output()
    assert rc == 0, failure(proc, f"exit status {rc}")
    m = re.search(r"safety: (\d+) stale-sensor stops", out)
    assert m and int(m.group(1)) > 0, failure(proc, "no stale-sensor stop counted")
    # the clean stop: zero speed sent on exit reaches Cyclone as well
    last = wait_until(lambda: take_all(drive_sub), 1.0)
    assert last and last[-1].drive.speed == 0.0, last


def test_sil_car_talks_to_cyclone_scan_odom_tf_and_drive(paddock, domain_id):
    """(b) `paddock bridge sil`: Cyclone reads /scan, /odom, /tf, /tf_static and drives."""
    proc = paddock("sil", "--map", MAP, "--domain-id", str(domain_id))
    node = CycloneRosNode(domain_id)
    scan_sub = node.subscription("/scan", LaserScan, sensor_data_qos())
    odom_sub = node.subscription("/odom", Odometry, default_qos(10))
    tf_sub = node.subscription("/tf", TFMessage, default_qos(100))
    drive_pub = node.publisher("/drive", AckermannDriveStamped, default_qos(10))

    scans, odoms, tfs = [], [], []

    def collect(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            drive_pub.write(drive_cmd(1.0))
            time.sleep(0.02)
            scans.extend(take_all(scan_sub))
            odoms.extend(take_all(odom_sub))
            tfs.extend(take_all(tf_sub))

    deadline = time.monotonic() + DISCOVERY_S
    while not (scans and odoms) and time.monotonic() < deadline and proc.alive():
        collect(0.1)
    assert scans and odoms, failure(proc, "no /scan or /odom from the SIL car reached Cyclone")
    collect(3.0)

    # scans: the simulator's LIDAR, 1080 beams over 4.7 rad, in the laser frame
    assert len(scans) >= 40, failure(proc, f"{len(scans)} scans in about 3 s (40 Hz)")
    for s in scans:
        assert s.header.frame_id == "ego_racecar/laser"
        assert len(s.ranges) == 1080
        assert all(math.isfinite(r) and 0.0 < r <= s.range_max for r in s.ranges)
        assert s.angle_min == pytest.approx(-2.35, abs=1e-6)
        assert s.angle_increment * 1079 == pytest.approx(s.angle_max - s.angle_min, abs=1e-5)
    scan_stamps = [stamp_secs(s.header.stamp) for s in scans]
    assert all(b > a for a, b in zip(scan_stamps, scan_stamps[1:])), "scan stamps advance"

    # odometry: map frame, stamps advancing, the car moving at the commanded 1 m/s
    assert len(odoms) >= 150, failure(proc, f"{len(odoms)} odometry messages in about 3 s")
    assert all(o.header.frame_id == "map" for o in odoms)
    assert all(o.child_frame_id == "ego_racecar/base_link" for o in odoms)
    stamps = [stamp_secs(o.header.stamp) for o in odoms]
    assert all(b > a for a, b in zip(stamps, stamps[1:])), "odometry stamps advance"
    first, last = odoms[0].pose.pose, odoms[-1].pose.pose
    yaw0 = yaw_of(first.orientation)
    ahead = (last.position.x - first.position.x) * math.cos(yaw0) + (
        last.position.y - first.position.y
    ) * math.sin(yaw0)
    assert ahead > 1.5, f"the SIL car drove {ahead:.2f} m ahead in about 3 s at 1 m/s"
    assert odoms[-1].twist.twist.linear.x == pytest.approx(1.0, abs=0.1)

    # /tf: map -> ego_racecar/base_link with every odometry message, the same pose
    by_stamp = {(o.header.stamp.sec, o.header.stamp.nanosec): o.pose.pose for o in odoms}
    matched = 0
    for msg in tfs:
        assert len(msg.transforms) == 1
        tr = msg.transforms[0]
        assert tr.header.frame_id == "map" and tr.child_frame_id == "ego_racecar/base_link"
        pose = by_stamp.get((tr.header.stamp.sec, tr.header.stamp.nanosec))
        if pose is None:
            continue
        matched += 1
        t = tr.transform
        assert (t.translation.x, t.translation.y) == (pose.position.x, pose.position.y)
        assert t.rotation == pose.orientation
    assert matched >= 100, failure(proc, f"{len(tfs)} /tf messages, {matched} match odometry")

    # /tf_static, joined late: transient local still delivers base_link -> laser
    static_sub = node.subscription("/tf_static", TFMessage, static_tf_qos())
    static = wait_until(lambda: take_all(static_sub), 5.0)
    assert static, failure(proc, "no /tf_static for a late-joining transient-local reader")
    (laser,) = static[-1].transforms
    assert laser.header.frame_id == "ego_racecar/base_link"
    assert laser.child_frame_id == "ego_racecar/laser"
    assert laser.transform.rotation == Quaternion()
    assert math.isfinite(laser.transform.translation.x)

    rc = proc.stop()
    assert rc == 0, failure(proc, f"exit status {rc}")
    m = re.search(r"(\d+) drive messages", proc.output())
    assert m and int(m.group(1)) > 50, failure(proc, "the SIL car counted no drive messages")


def test_initialpose_from_cyclone_moves_the_sil_car(paddock, domain_id):
    """(c) RViz's "2D Pose Estimate": /initialpose puts the SIL car there."""
    proc = paddock("sil", "--map", MAP, "--domain-id", str(domain_id))
    node = CycloneRosNode(domain_id)
    odom_sub = node.subscription("/odom", Odometry, default_qos(10))
    drive_pub = node.publisher("/drive", AckermannDriveStamped, default_qos(10))
    pose_pub = node.publisher("/initialpose", PoseWithCovarianceStamped, default_qos(1))
    odoms = []

    def drive(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            drive_pub.write(drive_cmd(1.0))
            time.sleep(0.02)
            odoms.extend(take_all(odom_sub))

    deadline = time.monotonic() + DISCOVERY_S
    while not odoms and time.monotonic() < deadline and proc.alive():
        drive(0.1)
    assert odoms, failure(proc, "no /odom from the SIL car reached Cyclone")
    drive(1.5)
    # a pose on the track that is neither the start nor where the car will be
    target = odoms[-1].pose.pose
    drive(1.5)
    here = odoms[-1].pose.pose.position
    away = math.hypot(here.x - target.position.x, here.y - target.position.y)
    assert away > 0.5, f"the car must have left the target pose first ({away:.2f} m)"

    n_before = len(odoms)
    pose_pub.write(
        PoseWithCovarianceStamped(
            header=Header(stamp=stamp_now(), frame_id="map"),
            pose=PoseWithCovariance(
                pose=Pose(
                    position=Point(x=target.position.x, y=target.position.y, z=0.0),
                    orientation=quaternion_from_yaw(yaw_of(target.orientation)),
                )
            ),
        )
    )

    def teleported():
        drive(0.05)
        for o in odoms[n_before:]:
            p = o.pose.pose
            dx, dy = p.position.x - target.position.x, p.position.y - target.position.y
            if math.hypot(dx, dy) < 0.05:
                return o
        return None

    o = wait_until(teleported, 5.0, poll=0.0)
    assert o is not None, failure(proc, "the SIL car never appeared at /initialpose")
    assert yaw_of(o.pose.pose.orientation) == pytest.approx(yaw_of(target.orientation), abs=1e-6)
    # the restarted episode keeps the header clock going forward (tf2 drops old stamps)
    stamps = [stamp_secs(m.header.stamp) for m in odoms]
    assert all(b > a for a, b in zip(stamps, stamps[1:])), "stamps advance across the restart"
    assert proc.stop() == 0, failure(proc, "exit status")
