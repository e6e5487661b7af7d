"""The ROS graph record: what `ros2 node list` reads.

Every ROS 2 participant publishes `ros_discovery_info` (rmw_dds_common's
ParticipantEntitiesInfo: its nodes and their readers' and writers' gids), reliable and
transient local. `paddock bridge` writes it in the layout of Iron and later (16-byte
gids), which Cyclone DDS decodes here with that IDL: the drive node is listed with its
two subscriptions and its publisher. (Humble's layout, 24-byte gids, is not written yet:
docs/bridge.md, "ROS distributions".)
"""

import time

from cyclonedds.core import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_node import CycloneRosNode, take_all
from ros2_types import ParticipantEntitiesInfo16
from test_cyclone_interop import DISCOVERY_S, failure


def test_the_drive_node_is_in_the_graph_record_in_the_iron_and_later_layout(paddock, domain_id):
    node = CycloneRosNode(domain_id)
    topic = Topic(node.participant, "ros_discovery_info", ParticipantEntitiesInfo16)
    reader = DataReader(
        node.participant,
        topic,
        Qos(
            Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(10),
            Policy.DataRepresentation(use_cdrv0_representation=True),
        ),
    )
    proc = paddock("drive", "--driver", "follow-the-gap", "--domain-id", str(domain_id))
    found = None
    deadline = time.monotonic() + DISCOVERY_S
    while found is None and time.monotonic() < deadline and proc.alive():
        for info in take_all(reader):
            for n in info.node_entities_info_seq:
                if n.node_name == "paddock_drive" and n.node_namespace == "/":
                    found = (info, n)
        time.sleep(0.05)
    assert found, failure(proc, "no ros_discovery_info listing paddock_drive reached Cyclone")
    info, n = found
    assert any(info.gid.data), "the participant gid is set"
    # /scan and /odom subscriptions; the /drive publisher (and the graph writer itself)
    assert len(n.reader_gid_seq) >= 2, n
    assert len(n.writer_gid_seq) >= 1, n
    # every entity gid shares the participant's 12-byte GUID prefix
    prefix = bytes(info.gid.data[:12])
    for g in list(n.reader_gid_seq) + list(n.writer_gid_seq):
        assert bytes(g.data[:12]) == prefix, (g, info.gid)
    assert proc.stop() == 0, failure(proc, "exit status")
