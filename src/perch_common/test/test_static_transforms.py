"""Static transforms on /tf_static: tf2_msgs/TFMessage, latched, one message with every child frame."""

import numpy as np
import pytest

pytestmark = pytest.mark.ros


def test_transform_message_round_trips_a_rigid_matrix():
    from scipy.spatial.transform import Rotation

    from perch_common.ros.static_transforms import matrix_from_transform, transform_msg

    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_rotvec([0.3, -0.5, 1.1]).as_matrix()
    matrix[:3, 3] = [1.0, -2.0, 0.5]
    msg = transform_msg("map", "map_gravity_aligned", matrix)
    assert msg.header.frame_id == "map" and msg.child_frame_id == "map_gravity_aligned"
    assert np.allclose(matrix_from_transform(msg), matrix, atol=1e-12)
    with pytest.raises(ValueError, match="two different frame names"):
        transform_msg("map", "map", np.eye(4))


# ROS 2 Jazzy's tf2_msgs/msg/TFMessage type hash (as `ros2 topic info -v /tf_static` shows it).
JAZZY_TF_MESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


def test_tf2_msgs_type_is_the_ros_one():
    from tf2_msgs.msg import TFMessage

    fields = TFMessage.get_fields_and_field_types()
    assert fields == {"transforms": "sequence<geometry_msgs/TransformStamped>"}


def test_late_subscriber_gets_every_static_transform():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.static_transforms import TF_STATIC_QOS, StaticTransformPublisher, transform_msg
    from perch_common.ros.testing import use_isolated_ros_env
    from tf2_msgs.msg import TFMessage

    use_isolated_ros_env()
    with ros_context():
        node = rclpy.create_node("test_static_transforms")
        try:
            publisher = StaticTransformPublisher(node)
            info = node.get_publishers_info_by_topic("/tf_static")
            assert info[0].topic_type == "tf2_msgs/msg/TFMessage"
            assert str(info[0].topic_type_hash) == JAZZY_TF_MESSAGE_HASH  # wire-compatible with real tf2
            first = np.eye(4)
            first[:3, 3] = [1, 2, 3]
            publisher.send(transform_msg("map", "a", first))
            publisher.send(transform_msg("map", "b", np.eye(4)), transform_msg("map", "a", np.eye(4)))
            received = []
            node.create_subscription(TFMessage, "/tf_static", received.append, TF_STATIC_QOS)  # joins late
            for _ in range(100):
                rclpy.spin_once(node, timeout_sec=0.05)
                if received:
                    break
            assert len(received) == 1, "a late subscriber gets the latched message"
            by_child = {t.child_frame_id: t for t in received[0].transforms}
            assert set(by_child) == {"a", "b"}
            assert by_child["a"].transform.translation.x == 0.0  # replaced, not appended
            assert by_child["a"].header.stamp.sec > 0  # stamped when sent
        finally:
            node.destroy_node()
