"""Publishing TF without tf2_ros (not in the PyPI wheels): the QoS and message shapes tf2 uses.

``/tf`` carries moving frames (reliable, volatile, depth 100: tf2_ros's dynamic broadcaster);
``/tf_static`` fixed ones (reliable, transient local, depth 1: a late subscriber gets every static
publisher's last message, which holds that publisher's *whole* set, as tf2_ros's static broadcaster
sends it). Types are ``tf2_msgs/msg/TFMessage``, built in this workspace from its public definition.
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from stud_common import names
from stud_common.rotations import matrix_to_quaternion

#: /tf: as tf2_ros.TransformBroadcaster.
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                    history=HistoryPolicy.KEEP_LAST)
#: /tf_static: as tf2_ros.StaticTransformBroadcaster (latched).
TF_STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)


def transform_stamped(parent: str, child: str, T: np.ndarray, stamp: Time) -> TransformStamped:
    """``child`` in ``parent`` (4, 4, metres) -> TransformStamped."""
    T = np.asarray(T, dtype=np.float64)
    x, y, z, w = (float(v) for v in matrix_to_quaternion(T[:3, :3]))
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    msg.transform = Transform(translation=Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
                              rotation=Quaternion(x=x, y=y, z=z, w=w))
    return msg


class StaticFrames:
    """This node's static frames on ``/tf_static``: :meth:`set` adds or replaces one (by child
    frame) and republishes the whole set, so the latched message always holds all of them."""

    def __init__(self, node: Node):
        self._node = node
        self._pub = node.create_publisher(TFMessage, names.TF_STATIC, TF_STATIC_QOS)
        self._frames: dict[str, TransformStamped] = {}

    def set(self, transforms: list[TransformStamped]) -> None:
        for t in transforms:
            self._frames[t.child_frame_id] = t
        self._pub.publish(TFMessage(transforms=list(self._frames.values())))

    @property
    def children(self) -> list[str]:
        return list(self._frames)


class MovingFrames:
    """Publisher of ``/tf``."""

    def __init__(self, node: Node):
        self._pub = node.create_publisher(TFMessage, names.TF, TF_QOS)

    def publish(self, transforms: list[TransformStamped]) -> None:
        if transforms:
            self._pub.publish(TFMessage(transforms=transforms))
