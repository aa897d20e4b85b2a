"""rosbag2 bags (``metadata.yaml`` + MCAP files) read and written without a running ROS graph.

The library ``ros2 bag`` here, the offline planner, the demo and the tests use::

    from stud_bag import open_bag, BagWriter, Qos
    for topic, type_name, log_time_ns, cdr in open_bag("bags/run1"):   # .message() deserialises
        ...
    with BagWriter("bags/run2") as bag:
        bag.add_topic("/drawing/layout", "stud_welding_msgs/msg/StudLayout",
                      offered_qos_profiles=[Qos(durability="transient_local", depth=1)])
        bag.write("/drawing/layout", layout_msg, stamp_ns)

Modules, as rosbags splits them: ``reader`` (BagReader, open_bag, read_messages), ``writer``
(BagWriter), ``metadata`` (metadata.yaml and QoS profiles), ``msgdef`` (full message definitions for
MCAP schemas), ``core`` (errors, BagMessage, (de)serialisation).
"""
from stud_bag.core import BagError, BagMessage, TopicSummary, deserialize, message_class, serialize, type_name_of
from stud_bag.metadata import BagMetadata, Qos
from stud_bag.reader import MESSAGES_MISSING, BagReader, open_bag, read_messages
from stud_bag.writer import BagWriter

__all__ = ["BagError", "BagMessage", "BagMetadata", "BagReader", "BagWriter", "MESSAGES_MISSING", "Qos",
           "TopicSummary", "deserialize", "message_class", "open_bag", "read_messages", "serialize", "type_name_of"]
