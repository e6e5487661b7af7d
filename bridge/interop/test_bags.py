"""Recordings from real life, read by `paddock bridge export-csv` and `paddock sysid`.

- A rosbag2 bag in SQLite3 storage (`.db3`, Humble's default), written by the third-party
  `rosbags` library (pure Python, the rosbag2 layout: bag folder with metadata.yaml),
  from a `paddock sysid synth` recording: export-csv gives back the same rows, from the
  folder and from the bare .db3, and `paddock sysid` analyses the bag.
- A recording cut off without finalising (the recorder killed with SIGKILL, as a power
  cut would): export-csv reads it up to its last complete chunk and says how much it
  recovered.
- Channels of a `paddock bridge record` MCAP carry rosbag2's `offered_qos_profiles`.
- A real car's MCAP bag (rosbags' MCAP storage), its pose and its speed on different
  topics: the pose from motion capture (`geometry_msgs/PoseStamped`), the speed from the
  VESC's odometry at its own times, whose lateral speed is never set and whose yaw rate
  is computed from the steering command. export-csv and sysid read the pose from
  `--pose-topic` and interpolate the speed; sysid fits only the pose and the speed
  (`--channels pose+speed`) and finds the steering gain hidden in the recording. The same
  with the pose only in the transforms (`/tf`: the localiser's `map -> odom` at 10 Hz,
  the odometry's `odom -> base_link`; `/tf_static` mounting the laser), chained and
  interpolated.
- Bags compressed by rosbag2 (rosbags' zstd `file` and `message` modes, in SQLite3 and
  MCAP storage) export the same rows as the plain bag.
"""

import csv
import math
import signal
import subprocess
import time

import pytest
from mcap.reader import make_reader
import json

from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.interfaces import QosDurability, QosHistory, QosReliability
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ros2_node import CycloneRosNode, default_qos, wait_until
from ros2_types import AckermannDriveStamped, LaserScan, Odometry
from test_cyclone_interop import corridor_scan, drive_cmd, failure, odometry, stamp_now

ACKERMANN_DRIVE = """float32 steering_angle
float32 steering_angle_velocity
float32 speed
float32 acceleration
float32 jerk
"""
ACKERMANN_DRIVE_STAMPED = """std_msgs/Header header
ackermann_msgs/AckermannDrive drive
"""


def humble_typestore():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(ACKERMANN_DRIVE, "ackermann_msgs/msg/AckermannDrive"))
    ts.register(
        get_types_from_msg(ACKERMANN_DRIVE_STAMPED, "ackermann_msgs/msg/AckermannDriveStamped")
    )
    return ts


def run(paddock_bin, *args, timeout=300):
    return subprocess.run(
        [paddock_bin, *args], capture_output=True, text=True, timeout=timeout, check=False
    )


def read_csv(path):
    """The rows as numbers; an empty field (a channel not measured) is NaN."""
    with open(path, newline="") as f:
        return [
            {k: float(v) if v else math.nan for k, v in row.items()} for row in csv.DictReader(f)
        ]


def write_db3_bag(rows, bag_dir, storage=StoragePlugin.SQLITE3, compression=None):
    """The rows of a reality-gap CSV as a rosbag2 bag (SQLite3 storage unless `storage`;
    rosbag2's zstd `compression` mode, if any): a drive command and an odometry message
    per row, stamped and logged at the row's time (from 1.7e9 s)."""
    ts = humble_typestore()
    t = ts.types
    Time = t["builtin_interfaces/msg/Time"]
    Header = t["std_msgs/msg/Header"]
    Odom = t["nav_msgs/msg/Odometry"]
    Drive = t["ackermann_msgs/msg/AckermannDrive"]
    DriveStamped = t["ackermann_msgs/msg/AckermannDriveStamped"]
    g = t
    base = 1_700_000_000_000_000_000
    writer = Writer(bag_dir, version=8, storage_plugin=storage)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer as w:
        drive_conn = w.add_connection("/drive", DriveStamped.__msgtype__, typestore=ts)
        odom_conn = w.add_connection("/odom", Odom.__msgtype__, typestore=ts)
        cov = __import__("numpy").zeros(36)
        for r in rows:
            ns = base + round(r["t"] * 1e9)
            stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
            cmd = DriveStamped(
                header=Header(stamp=stamp, frame_id="base_link"),
                drive=Drive(
                    steering_angle=r["steer_cmd"],
                    steering_angle_velocity=0.0,
                    speed=r["speed_cmd"],
                    acceleration=0.0,
                    jerk=0.0,
                ),
            )
            w.write(drive_conn, ns, ts.serialize_cdr(cmd, DriveStamped.__msgtype__))
            half = 0.5 * r["yaw"]
            odom = Odom(
                header=Header(stamp=stamp, frame_id="odom"),
                child_frame_id="base_link",
                pose=g["geometry_msgs/msg/PoseWithCovariance"](
                    pose=g["geometry_msgs/msg/Pose"](
                        position=g["geometry_msgs/msg/Point"](x=r["x"], y=r["y"], z=0.0),
                        orientation=g["geometry_msgs/msg/Quaternion"](
                            x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)
                        ),
                    ),
                    covariance=cov,
                ),
                twist=g["geometry_msgs/msg/TwistWithCovariance"](
                    twist=g["geometry_msgs/msg/Twist"](
                        linear=g["geometry_msgs/msg/Vector3"](x=r["vx"], y=r["vy"], z=0.0),
                        angular=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=r["yaw_rate"]),
                    ),
                    covariance=cov,
                ),
            )
            w.write(odom_conn, ns, ts.serialize_cdr(odom, Odom.__msgtype__))


def test_a_rosbags_db3_bag_is_read_by_export_csv_and_sysid(paddock_bin, tmp_path):
    synth = tmp_path / "synth.csv"
    r = run(paddock_bin, "sysid", "synth", "--out", str(synth), "--seconds", "40")
    assert r.returncode == 0, r.stderr
    rows = read_csv(synth)
    assert len(rows) > 500
    bag = tmp_path / "car_bag"
    write_db3_bag(rows, bag)
    (db3,) = bag.glob("*.db3")

    for source in (bag, db3):
        out = tmp_path / f"export-{source.name}.csv"
        r = run(paddock_bin, "bridge", "export-csv", str(source), "--out", str(out))
        assert r.returncode == 0, r.stderr
        got = read_csv(out)
        # rows from the first command on: here every row has its command
        assert len(got) == len(rows), (len(got), len(rows))
        for a, b in zip(got, rows):
            assert a["t"] == pytest.approx(b["t"], abs=1e-9)
            # commands travel as float32, the state as float64
            assert a["steer_cmd"] == pytest.approx(b["steer_cmd"], abs=1e-6)
            assert a["speed_cmd"] == pytest.approx(b["speed_cmd"], rel=1e-6)
            for k in ("x", "y", "vx", "vy", "yaw_rate"):
                assert a[k] == pytest.approx(b[k], abs=1e-9), k
            assert math.remainder(a["yaw"] - b["yaw"], math.tau) == pytest.approx(0.0, abs=1e-9)

    report = tmp_path / "sysid"
    r = run(
        paddock_bin, "sysid", "--recording", str(bag), "--out", str(report),
        "--no-plots", "--effects", "steering_offset", "--folds", "2",
    )
    assert r.returncode == 0, r.stderr
    assert (report / "report.json").is_file()


WHEELBASE_M = 0.3302  # the default vehicle's lf + lr, as the VESC's odometry node takes it


def write_car_mcap_bag(rows, bag_dir, pose_in_tf=False):
    """A real car's bag from the rows of a reality-gap CSV: `/drive` commands and the true
    pose from motion capture (`/mocap/pose`, PoseStamped) at the rows' times; the VESC's
    `/odom` half a period later at each, its speed interpolated, its lateral speed 0 (never
    set), its yaw rate the kinematic one of the steering command and its pose dead reckoned
    from those, as vesc_to_odom publishes them.

    With `pose_in_tf` the pose is in the transforms instead, as a car with slam_toolbox or
    Cartographer logs it: `/tf` carries the odometry's `odom -> base_link` at the rows'
    times and the localiser's correction `map -> odom` at every fourth (10 Hz), such that
    the chain gives the true pose there; `/tf_static` mounts the laser."""
    ts = humble_typestore()
    t = ts.types
    Time = t["builtin_interfaces/msg/Time"]
    Header = t["std_msgs/msg/Header"]
    Point, Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
    Pose, PoseStamped = t["geometry_msgs/msg/Pose"], t["geometry_msgs/msg/PoseStamped"]
    Odom = t["nav_msgs/msg/Odometry"]
    Drive = t["ackermann_msgs/msg/AckermannDrive"]
    DriveStamped = t["ackermann_msgs/msg/AckermannDriveStamped"]
    V3 = t["geometry_msgs/msg/Vector3"]
    cov = __import__("numpy").zeros(36)
    base = 1_700_000_000_000_000_000

    def stamp(ns):
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def pose(x, y, yaw):
        return Pose(
            position=Point(x=x, y=y, z=0.0),
            orientation=Quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        )

    dr = [0.0, 0.0, 0.0]  # the VESC's dead reckoning
    odometry_tf, sent = [], {}  # what /tf carries: (ns, odom -> base_link), {ns: map -> odom}
    with Writer(bag_dir, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        drive = w.add_connection("/drive", DriveStamped.__msgtype__, typestore=ts)
        if pose_in_tf:
            TF, TS = t["tf2_msgs/msg/TFMessage"], t["geometry_msgs/msg/TransformStamped"]
            Transform = t["geometry_msgs/msg/Transform"]
            tf = w.add_connection("/tf", TF.__msgtype__, typestore=ts)
            tf_static = w.add_connection("/tf_static", TF.__msgtype__, typestore=ts)

            def transform(ns, parent, child, x, y, yaw):
                return TS(
                    header=Header(stamp=stamp(ns), frame_id=parent),
                    child_frame_id=child,
                    transform=Transform(
                        translation=V3(x=x, y=y, z=0.0),
                        rotation=Quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                    ),
                )

            mount = TF(transforms=[transform(base, "base_link", "laser", 0.27, 0.0, 0.0)])
            w.write(tf_static, base, ts.serialize_cdr(mount, TF.__msgtype__))
        else:
            mocap = w.add_connection("/mocap/pose", PoseStamped.__msgtype__, typestore=ts)
        odom = w.add_connection("/odom", Odom.__msgtype__, typestore=ts)
        for i, (r, nxt) in enumerate(zip(rows, rows[1:])):
            ns = base + round(r["t"] * 1e9)
            cmd = DriveStamped(
                header=Header(stamp=stamp(ns), frame_id="base_link"),
                drive=Drive(
                    steering_angle=r["steer_cmd"], steering_angle_velocity=0.0,
                    speed=r["speed_cmd"], acceleration=0.0, jerk=0.0,
                ),
            )
            w.write(drive, ns, ts.serialize_cdr(cmd, DriveStamped.__msgtype__))
            if pose_in_tf:
                # odom -> base_link is the dead reckoning; map -> odom = truth * odom^-1
                ox, oy, oyaw = dr
                transforms = [transform(ns, "odom", "base_link", ox, oy, oyaw)]
                if i % 4 == 0:
                    cyaw = r["yaw"] - oyaw
                    c, s_ = math.cos(cyaw), math.sin(cyaw)
                    cx = r["x"] - (c * ox - s_ * oy)
                    cy = r["y"] - (s_ * ox + c * oy)
                    transforms.append(transform(ns, "map", "odom", cx, cy, cyaw))
                    sent[ns] = (cx, cy, cyaw)
                odometry_tf.append((ns, (ox, oy, oyaw)))
                msg = TF(transforms=transforms)
                w.write(tf, ns, ts.serialize_cdr(msg, TF.__msgtype__))
            else:
                p = PoseStamped(header=Header(stamp=stamp(ns), frame_id="map"),
                                pose=pose(r["x"], r["y"], r["yaw"]))
                w.write(mocap, ns, ts.serialize_cdr(p, PoseStamped.__msgtype__))
            # the VESC half a period later
            dt = nxt["t"] - r["t"]
            ns_v = base + round((r["t"] + dt / 2) * 1e9)
            vx = (r["vx"] + nxt["vx"]) / 2
            wz = vx * math.tan(r["steer_cmd"]) / WHEELBASE_M
            dr[2] += wz * dt
            dr[0] += vx * math.cos(dr[2]) * dt
            dr[1] += vx * math.sin(dr[2]) * dt
            o = Odom(
                header=Header(stamp=stamp(ns_v), frame_id="odom"),
                child_frame_id="base_link",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose(*dr), covariance=cov),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](
                        linear=V3(x=vx, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=wz)
                    ),
                    covariance=cov,
                ),
            )
            w.write(odom, ns_v, ts.serialize_cdr(o, Odom.__msgtype__))
    return odometry_tf, sent


def synth_gain_day(paddock_bin, tmp_path):
    """The rows of a 40-s `sysid synth` run with a steering gain of 0.85 hidden."""
    synth = tmp_path / "synth.csv"
    r = run(
        paddock_bin, "sysid", "synth", "--out", str(synth), "--seconds", "40",
        "--effect", "steering_gain:gain=0.85",
    )
    assert r.returncode == 0, r.stderr
    return read_csv(synth)


def sysid_finds_the_gain(paddock_bin, bag, report, pose_topic):
    """`paddock sysid` on the pose of `pose_topic` and the speed finds the hidden gain;
    returns its report."""
    r = run(
        paddock_bin, "sysid", "--recording", str(bag), "--out", str(report), "--no-plots",
        "--pose-topic", pose_topic, "--channels", "pose+speed",
        "--effects", "steering_gain", "--folds", "2",
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads((report / "report.json").read_text())
    (gain,) = [e for e in rep["effects"] if e["name"] == "steering_gain"]
    assert gain["significant"], gain
    assert gain["params"]["gain"] == pytest.approx(0.85, abs=0.03), gain
    return rep


def test_a_cars_bag_with_pose_and_speed_on_their_own_topics(paddock_bin, tmp_path):
    rows = synth_gain_day(paddock_bin, tmp_path)
    bag = tmp_path / "car_bag"
    write_car_mcap_bag(rows, bag)
    assert list(bag.glob("*.mcap")), list(bag.iterdir())

    out = tmp_path / "export.csv"
    r = run(
        paddock_bin, "bridge", "export-csv", str(bag), "--out", str(out),
        "--pose-topic", "/mocap/pose",
    )
    assert r.returncode == 0, r.stderr
    assert "vy exactly 0 in every /odom message" in r.stderr, r.stderr
    with open(out, newline="") as f:
        got = list(csv.DictReader(f))
    # a row per pose; the last pose has no VESC message after it
    assert len(got) == len(rows) - 1, (len(got), len(rows))
    # the VESC's messages as written: (log time in ns from the first row, speed)
    vesc = [
        (round((r["t"] + (n["t"] - r["t"]) / 2) * 1e9), (r["vx"] + n["vx"]) / 2)
        for r, n in zip(rows, rows[1:])
    ]
    # the first pose comes before the first VESC message: no speed there
    assert got[0]["vx"] == "" and got[0]["vy"] == ""
    errs = []
    for i, (a, b) in enumerate(zip(got, rows)):
        assert float(a["x"]) == pytest.approx(b["x"], abs=1e-9)
        assert a["vy"] == ""
        if i == 0:
            continue
        # the speed between the VESC messages around the pose, in log time
        (t0, v0), (t1, v1) = vesc[i - 1], vesc[i]
        t = round(b["t"] * 1e9)
        assert t0 < t < t1
        assert float(a["vx"]) == pytest.approx(v0 + (t - t0) / (t1 - t0) * (v1 - v0), abs=1e-9)
        errs.append(abs(float(a["vx"]) - b["vx"]))
    # and near the truth
    assert sorted(errs)[len(errs) // 2] < 0.05, sorted(errs)[len(errs) // 2]

    rep = sysid_finds_the_gain(paddock_bin, bag, tmp_path / "sysid", "/mocap/pose")
    warnings = rep["recording"]["warnings"]
    assert "measured but left out (--channels pose+speed): yaw_rate" in warnings, warnings
    assert set(rep["recording"]["channels_missing"]) == {"vy", "yaw_rate"}, rep["recording"]


def test_a_cars_bag_with_its_pose_only_in_the_transforms(paddock_bin, tmp_path):
    rows = synth_gain_day(paddock_bin, tmp_path)
    bag = tmp_path / "car_bag"
    odometry_tf, corrections = write_car_mcap_bag(rows, bag, pose_in_tf=True)

    out = tmp_path / "export.csv"
    r = run(paddock_bin, "bridge", "export-csv", str(bag), "--out", str(out), "--pose-topic", "/tf")
    assert r.returncode == 0, r.stderr
    got = read_csv(out)
    # a pose per odometry transform between the first and the last correction
    last = 4 * ((len(rows) - 2) // 4)
    assert len(got) == last + 1, (len(got), last + 1)
    # the correction where it was sent, interpolated in log time between (the yaw the
    # shorter way), then the odometry's transform
    times = sorted(corrections)
    for j, (a, (ns, (ox, oy, oyaw))) in enumerate(zip(got, odometry_tf)):
        k = min(max(0, (j // 4)), len(times) - 2)
        t0, t1 = times[k], times[k + 1]
        c0, c1 = corrections[t0], corrections[t1]
        u = (ns - t0) / (t1 - t0)
        dyaw = math.remainder(c1[2] - c0[2], math.tau)
        cx, cy = c0[0] + u * (c1[0] - c0[0]), c0[1] + u * (c1[1] - c0[1])
        cyaw = c0[2] + u * dyaw
        want_x = cx + math.cos(cyaw) * ox - math.sin(cyaw) * oy
        want_y = cy + math.sin(cyaw) * ox + math.cos(cyaw) * oy
        assert a["x"] == pytest.approx(want_x, abs=1e-9), j
        assert a["y"] == pytest.approx(want_y, abs=1e-9), j
        if j % 4 == 0:  # where the correction was sent: the truth itself
            assert a["x"] == pytest.approx(rows[j]["x"], abs=1e-9), j
            assert a["y"] == pytest.approx(rows[j]["y"], abs=1e-9), j
    # the laser's pose, through the static mount: 0.27 m ahead of the car
    laser = tmp_path / "laser.csv"
    r = run(
        paddock_bin, "bridge", "export-csv", str(bag), "--out", str(laser), "--pose-topic", "/tf",
        "--pose-frames", "map,laser",
    )
    assert r.returncode == 0, r.stderr
    a, b = read_csv(laser)[8], rows[8]
    assert a["x"] == pytest.approx(b["x"] + 0.27 * math.cos(b["yaw"]), abs=1e-9)
    # frames the transforms do not join are named with those recorded
    r = run(
        paddock_bin, "bridge", "export-csv", str(bag), "--out", str(laser), "--pose-topic", "/tf",
        "--pose-frames", "earth,base_link",
    )
    assert r.returncode != 0
    assert 'no chain of transforms from "earth" to "base_link"' in r.stderr, r.stderr
    assert "map -> odom" in r.stderr, r.stderr

    sysid_finds_the_gain(paddock_bin, bag, tmp_path / "sysid", "/tf")


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
@pytest.mark.parametrize("compression", [CompressionMode.FILE, CompressionMode.MESSAGE])
def test_compressed_bags_read_as_the_plain_one(paddock_bin, tmp_path, storage, compression):
    synth = tmp_path / "synth.csv"
    r = run(paddock_bin, "sysid", "synth", "--out", str(synth), "--seconds", "10")
    assert r.returncode == 0, r.stderr
    rows = read_csv(synth)
    plain, packed = tmp_path / "plain", tmp_path / "packed"
    write_db3_bag(rows, plain, storage)
    write_db3_bag(rows, packed, storage, compression)
    names = [p.name for p in packed.iterdir() if p.name != "metadata.yaml"]
    assert len(names) == 1 and names[0].endswith(".zstd") == (compression == CompressionMode.FILE)
    # the whole folder, and a file compressed whole given bare
    sources = [packed] + ([packed / names[0]] if compression == CompressionMode.FILE else [])
    r = run(paddock_bin, "bridge", "export-csv", str(plain), "--out", str(tmp_path / "a.csv"))
    assert r.returncode == 0, r.stderr
    want = (tmp_path / "a.csv").read_text()
    for source in sources:
        out = tmp_path / "b.csv"
        r = run(paddock_bin, "bridge", "export-csv", str(source), "--out", str(out))
        assert r.returncode == 0, r.stderr
        assert out.read_text() == want, source


def test_a_killed_recorder_leaves_a_recording_export_csv_recovers(paddock, domain_id, tmp_path):
    bag = tmp_path / "cut.mcap"
    proc = paddock("record", "--out", str(bag), "--domain-id", str(domain_id))
    car = CycloneRosNode(domain_id)
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    drive_pub = car.publisher("/drive", AckermannDriveStamped, default_qos(10))
    scan_pub = car.publisher("/scan", LaserScan, default_qos(20))
    x = 0.0
    end = time.monotonic() + 6.0
    while time.monotonic() < end and proc.alive():
        stamp = stamp_now()
        odom_pub.write(odometry(stamp, x, 1.0))
        drive_pub.write(drive_cmd(1.0, 0.1))
        scan_pub.write(corridor_scan(stamp, left=1.0, right=1.0))
        x += 0.01
        time.sleep(0.01)
    # the power cut: no chance to finalise
    proc.proc.send_signal(signal.SIGKILL)
    assert wait_until(lambda: not proc.alive(), 5.0)
    proc.stop()
    size = bag.stat().st_size
    assert size > 256 * 1024, failure(proc, f"only {size} bytes recorded")
    with open(bag, "rb") as f:
        with pytest.raises(Exception):
            make_reader(f).get_summary()  # the reference reader refuses it whole

    out = tmp_path / "cut.csv"
    r = subprocess.run(
        [proc.proc.args[0], "bridge", "export-csv", str(bag), "--out", str(out)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    assert r.returncode == 0, r.stderr
    assert "not finalised" in r.stderr and "recovered" in r.stderr, r.stderr
    rows = read_csv(out)
    assert len(rows) > 50, len(rows)
    assert all(row["speed_cmd"] == 1.0 for row in rows)


def test_recorded_channels_offer_their_qos_profiles(paddock, domain_id, tmp_path):
    bag = tmp_path / "qos.mcap"
    proc = paddock("record", "--out", str(bag), "--domain-id", str(domain_id), "--seconds", "3")
    car = CycloneRosNode(domain_id)
    odom_pub = car.publisher("/odom", Odometry, default_qos(10))
    while proc.alive():
        odom_pub.write(odometry(stamp_now(), 0.0, 1.0))
        time.sleep(0.02)
    assert proc.stop() == 0, failure(proc, "exit status")
    with open(bag, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) >= {"/scan", "/odom", "/drive"}, topics
    for topic, channel in topics.items():
        # parsed by rosbags' own reader of rosbag2's QoS YAML
        profiles = parse_qos(channel.metadata["offered_qos_profiles"])
        assert len(profiles) == 1, (topic, profiles)
        p = profiles[0]
        assert p.history == QosHistory.KEEP_LAST and p.depth >= 1, p
        assert p.reliability == QosReliability.RELIABLE, p
        assert p.durability == QosDurability.VOLATILE, p
        assert not p.avoid_ros_namespace_conventions
