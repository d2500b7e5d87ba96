"""Static transforms on /tf_static (tf2_msgs/msg/TFMessage), as tf2_ros's static broadcaster sends them,
and the input-frame -> gravity-aligned-frame Alignment as a TransformStamped.

/tf_static is latched with depth 1, so every message carries all of this node's static transforms:
a new one replaces the old transform of the same child frame and the whole set is sent again.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Quaternion, TransformStamped, Vector3
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from perch_common.frames import Alignment
from perch_common.transforms import matrix_from_quaternion, quaternion_from_matrix
from tf2_msgs.msg import TFMessage

# Relative, as nav2 remaps tf for multi-robot graphs: /tf_static in the root namespace, /N/tf_static in namespace N,
# so two graphs side by side never mix their frames.
TF_STATIC_TOPIC = "tf_static"
# tf2_ros's StaticBroadcasterQoS: reliable, transient local, depth 1.
TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


def transform_msg(parent_frame: str, child_frame: str, matrix: np.ndarray, stamp=None) -> TransformStamped:
    """The TransformStamped of a 4x4 (or 3x3) matrix taking child-frame coordinates to the parent frame."""
    if not parent_frame or not child_frame or parent_frame == child_frame:
        raise ValueError(f"a transform needs two different frame names (got '{parent_frame}' and '{child_frame}')")
    m = np.eye(4)
    given = np.asarray(matrix, np.float64)
    m[:given.shape[0], :given.shape[1]] = given
    q = quaternion_from_matrix(m[:3, :3])
    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = parent_frame, child_frame
    if stamp is not None:
        msg.header.stamp = stamp
    msg.transform.translation = Vector3(x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3]))
    msg.transform.rotation = Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
    return msg


def matrix_from_transform(msg: TransformStamped) -> np.ndarray:
    """4x4 matrix of a TransformStamped (child-frame coordinates to the parent frame)."""
    t, r = msg.transform.translation, msg.transform.rotation
    out = np.eye(4)
    out[:3, :3] = matrix_from_quaternion(np.array([r.x, r.y, r.z, r.w], np.float64))
    out[:3, 3] = [t.x, t.y, t.z]
    return out


class StaticTransformPublisher:
    """Publishes a node's static transforms on /tf_static, keyed by child frame."""

    def __init__(self, node) -> None:
        self._node = node
        self._publisher = node.create_publisher(TFMessage, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self._by_child: dict[str, TransformStamped] = {}

    def send(self, *transforms: TransformStamped) -> None:
        """Add or replace these transforms (by child frame) and publish the node's whole set."""
        for transform in transforms:
            if not transform.header.stamp.sec and not transform.header.stamp.nanosec:
                transform.header.stamp = self._node.get_clock().now().to_msg()
            self._by_child[transform.child_frame_id] = transform
        self._publisher.publish(TFMessage(transforms=list(self._by_child.values())))

    def transforms(self) -> list[TransformStamped]:
        """The transforms sent so far (one per child frame)."""
        return list(self._by_child.values())


def alignment_to_msg(alignment: Alignment, stamp=None) -> TransformStamped:
    """The alignment as a transform: the gravity-aligned frame (child) in the input frame (parent).

    An input already in a gravity-aligned frame (a mission cleans its mesh after aligning it) gives
    the same name twice: a correction within that frame, never sent on /tf_static.
    """
    if alignment.aligned_frame != alignment.input_frame:
        return transform_msg(alignment.input_frame, alignment.aligned_frame, alignment.to_input(), stamp)
    msg = transform_msg(alignment.input_frame, alignment.input_frame + "_", alignment.to_input(), stamp)
    msg.child_frame_id = alignment.input_frame
    return msg


def alignment_from_msg(msg: TransformStamped, up_source: str = "given", up_confidence: float = 1.0) -> Alignment:
    """The Alignment a transform from alignment_to_msg describes (rotation only, as alignments are)."""
    if not msg.header.frame_id:
        raise ValueError("alignment transform has no input frame (header.frame_id is empty)")
    return Alignment(msg.header.frame_id, matrix_from_transform(msg)[:3, :3].T, up_source, up_confidence)
