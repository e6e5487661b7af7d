"""A ROS 2 node as rmw_cyclonedds_cpp puts it on the wire, written with plain Cyclone DDS.

rmw_cyclonedds_cpp maps a ROS 2 topic `/scan` to the DDS topic `rt/scan`, the message
type to `pkg::msg::dds_::Type_` (see ros2_types.py), encodes samples as plain CDR
(XCDR1: it sets the DataRepresentation QoS to XCDR1 only) and translates rclcpp's QoS
profiles one to one into DDS QoS. The profiles the F1TENTH stack uses are below.
"""

import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.internal import InvalidSample
from cyclonedds.topic import Topic
from cyclonedds.util import duration

_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)


def sensor_data_qos():
    """rclcpp::SensorDataQoS (what most scan subscribers and some LIDAR drivers use):
    best effort, keep last 5."""
    return Qos(
        Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(5),
        _XCDR1,
    )


def default_qos(depth=10):
    """rclcpp::QoS(depth), the default profile (urg_node's /scan, VESC odometry,
    ackermann_mux's /drive subscription, f1tenth_gym_ros, RViz's /initialpose):
    reliable, volatile."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        _XCDR1,
    )


def static_tf_qos():
    """tf2_ros::StaticListenerQoS / StaticBroadcasterQoS: reliable, transient local, 1."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        _XCDR1,
    )


class CycloneRosNode:
    """Publishers and subscriptions on ROS 2 topic names, in one DDS participant."""

    def __init__(self, domain_id):
        self.participant = DomainParticipant(domain_id)
        self._topics = {}

    def _topic(self, name, msg_type):
        assert name.startswith("/"), name
        key = (name, msg_type)
        if key not in self._topics:
            self._topics[key] = Topic(self.participant, "rt" + name, msg_type)
        return self._topics[key]

    def publisher(self, name, msg_type, qos):
        return DataWriter(self.participant, self._topic(name, msg_type), qos)

    def subscription(self, name, msg_type, qos):
        return DataReader(self.participant, self._topic(name, msg_type), qos)


def take_all(reader):
    """Every data sample waiting in `reader`, oldest first (a writer going away shows up
    as an invalid sample, which carries no data and is dropped)."""
    out = []
    while True:
        batch = reader.take(N=256)
        if not batch:
            return out
        out.extend(s for s in batch if not isinstance(s, InvalidSample))


def wait_until(predicate, timeout, poll=0.01):
    """Poll `predicate` until it is true or `timeout` seconds pass; returns its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(poll)
