"""Start ``odometry_node``: ``ros2 launch diffdrive_odom odometry.launch.py``.

One params file configures every node (its parameters sit under ``/**``), so the same
file works in any namespace. The node gets the fully qualified name
``<namespace>/odometry_node``; the ``use_sim_time`` given here is written to that
node's own section and so beats a ``use_sim_time`` in the file. With a namespace the
frames are prefixed with it (``robot1/odom``) unless the file sets ``tf_frame_prefix``;
``/tf`` stays global, as tf2 expects.
"""

# ruff: noqa: I001 (ruff takes ./launch for first-party; this is ROS 2 launch)
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

PACKAGE = "diffdrive_odom"


def generate_launch_description() -> LaunchDescription:
    """The arguments and the node."""
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    return LaunchDescription([
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), "config", "diffdrive_odom.yaml"]),
            description="ROS 2 params YAML for the nodes (parameters under /**)"),
        DeclareLaunchArgument(
            "namespace", default_value="",
            description="Namespace of the nodes and their relative topics, e.g. robot1"),
        DeclareLaunchArgument(
            "use_sim_time", default_value="false",
            description="Follow /clock (a simulator or a bag played with --clock)"),
        DeclareLaunchArgument(
            "joint_states_topic", default_value="joint_states",
            description="sensor_msgs/JointState input (relative = inside the namespace)"),
        DeclareLaunchArgument(
            "odom_topic", default_value="odom",
            description="nav_msgs/Odometry output (relative = inside the namespace)"),
        Node(
            package=PACKAGE,
            executable="odometry_node",
            name="odometry_node",
            namespace=LaunchConfiguration("namespace"),
            parameters=[LaunchConfiguration("params_file"), {"use_sim_time": use_sim_time}],
            remappings=[
                ("joint_states", LaunchConfiguration("joint_states_topic")),
                ("odom", LaunchConfiguration("odom_topic")),
            ],
            output="screen",
        ),
    ])
