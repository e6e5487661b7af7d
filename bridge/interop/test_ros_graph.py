"""The ROS graph record: what `ros2 node list` reads, in Humble's layout and in Iron's.

Every ROS 2 participant publishes `ros_discovery_info` (rmw_dds_common's
ParticipantEntitiesInfo: its nodes and their readers' and writers' gids), reliable and
transient local. A gid is 24 bytes on Humble and 16 from Iron on, and CDR carries fixed
arrays without a length, so each distribution reads only its own layout. `paddock bridge`
writes the layout of the distribution given by `--ros-distro` (or ROS_DISTRO); Cyclone DDS
decodes each with that distribution's IDL here and finds the drive node with its two
subscriptions and its publisher.
"""

import os
import subprocess
import time

import pytest
from cyclonedds.core import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_node import CycloneRosNode, take_all
from ros2_types import ParticipantEntitiesInfo16, ParticipantEntitiesInfo24
from test_cyclone_interop import DISCOVERY_S, failure

LAYOUTS = {
    # distribution: (record type as that distribution's rmw_dds_common defines it, gid bytes)
    "humble": (ParticipantEntitiesInfo24, 24),
    "jazzy": (ParticipantEntitiesInfo16, 16),
}
# how each distribution is chosen: Humble from ROS_DISTRO as a sourced Humble sets it;
# Jazzy by the flag, which wins over a ROS_DISTRO that says humble
CHOSEN_BY = {"humble": "env", "jazzy": "flag"}


def graph_reader(domain_id, record_type):
    node = CycloneRosNode(domain_id)
    topic = Topic(node.participant, "ros_discovery_info", record_type)
    return DataReader(
        node.participant,
        topic,
        Qos(
            Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(10),
            Policy.DataRepresentation(use_cdrv0_representation=True),
        ),
    )


def find_node(reader, proc, name, readers, writers):
    """The first record (and its node entry) listing node `name` in namespace `/` with at
    least `readers` readers and `writers` writers (the record is published again as the
    node creates each one), else the last record listing the node, else None."""
    last = None
    deadline = time.monotonic() + DISCOVERY_S
    while time.monotonic() < deadline and proc.alive():
        for info in take_all(reader):
            for n in info.node_entities_info_seq:
                if n.node_name == name and n.node_namespace == "/":
                    last = (info, n)
                    if len(n.reader_gid_seq) >= readers and len(n.writer_gid_seq) >= writers:
                        return last
        time.sleep(0.05)
    return last


@pytest.mark.parametrize("distro", sorted(LAYOUTS))
def test_the_drive_node_is_in_the_graph_record_in_its_distributions_layout(
    paddock, domain_id, distro, monkeypatch
):
    record_type, gid_bytes = LAYOUTS[distro]
    reader = graph_reader(domain_id, record_type)
    args = ["drive", "--driver", "follow-the-gap", "--domain-id", str(domain_id)]
    if CHOSEN_BY[distro] == "flag":
        monkeypatch.setenv("ROS_DISTRO", "jazzy" if distro == "humble" else "humble")
        args += ["--ros-distro", distro]
    else:
        monkeypatch.setenv("ROS_DISTRO", distro)
    proc = paddock(*args)
    # /scan and /odom subscriptions (and /tf_static's); the /drive publisher and the
    # graph writer itself
    found = find_node(reader, proc, "paddock_drive", readers=2, writers=2)
    assert found, failure(proc, f"no {distro} ros_discovery_info listing paddock_drive reached Cyclone")
    info, n = found
    assert len(info.gid.data) == gid_bytes
    assert any(info.gid.data), "the participant gid is set"
    assert len(n.reader_gid_seq) >= 2, n
    assert len(n.writer_gid_seq) >= 2, n
    # every entity gid shares the participant's 12-byte GUID prefix; Humble's 24-byte
    # gids end in eight zero bytes after the 16-byte GUID
    prefix = bytes(info.gid.data[:12])
    for g in [info.gid] + list(n.reader_gid_seq) + list(n.writer_gid_seq):
        assert bytes(g.data[:12]) == prefix, (g, info.gid)
        assert not any(g.data[16:]), g
        assert any(g.data[12:16]), g
    assert proc.stop() == 0, failure(proc, "exit status")
    assert "neither --ros-distro nor ROS_DISTRO" not in proc.output()


def test_an_unknown_distribution_is_refused_by_name(paddock_bin):

    env = dict(os.environ, ROS_DISTRO="foxy")
    r = subprocess.run(
        [paddock_bin, "bridge", "drive", "--driver", "follow-the-gap", "--seconds", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert r.returncode != 0
    assert "ROS_DISTRO" in r.stderr and '"foxy"' in r.stderr and "humble" in r.stderr, r.stderr
