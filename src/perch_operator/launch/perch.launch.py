"""`ros2 launch perch_operator perch.launch.py [namespace:=N] [params_file:=FILE]`: the whole Perch graph.

Starts the same nodes as `perch launch` (those listed in the parameter file and installed), each
with the parameter file, in the namespace given (Perch's names are relative: /N/perch/...).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    """One launch_ros Node per graph node of the parameter file."""
    from perch_common.launch import graph_nodes

    params_file = LaunchConfiguration("params_file").perform(context)
    namespace = LaunchConfiguration("namespace").perform(context)
    return [Node(package=n.package, executable=n.executable, name=n.name, namespace=namespace,
                 parameters=[params_file], output="screen", emulate_tty=True)
            for n in graph_nodes(params_file)]


def generate_launch_description():
    """The launch arguments, the Fast DDS liveliness profile and the graph's nodes."""
    share = get_package_share_directory("perch_operator")
    # Perch's profile frees each message's buffers with it once rmw_fastrtps takes the profile's QoS;
    # a user's own profile (FASTRTPS_DEFAULT_PROFILES_FILE set) is used as rmw_fastrtps always does.
    own_profile = "FASTRTPS_DEFAULT_PROFILES_FILE" in os.environ
    memory_policy = [] if own_profile else [
        SetEnvironmentVariable("RMW_FASTRTPS_USE_QOS_FROM_XML",
                               EnvironmentVariable("RMW_FASTRTPS_USE_QOS_FROM_XML", default_value="1"))]
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "perch.yaml"),
                              description="ROS parameter file (node_name: ros__parameters: ...)"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="namespace of the graph; two graphs in two namespaces share a domain"),
        # A node that dies unannounced leaves the graph in ~3 s (a user's own profile wins).
        SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                               EnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE",
                                                   default_value=os.path.join(share, "config", "fastdds.xml"))),
        *memory_policy,
        OpaqueFunction(function=_nodes),
    ])
