"""Start ``odometry_node``: ``ros2 launch diffdrive_odom odometry.launch.py``.

One params file configures every node (its parameters sit under ``/**``), so the same
file works in any namespace; ``extra_params_file`` is layered after it (a robot's own
values over the shipped defaults). The node gets the fully qualified name
``<namespace>/odometry_node``; the ``use_sim_time`` given here, and ``use_imu`` /
``enable_odom_tf`` when given, are written to that node's own section and so beat the
files. With a namespace the frames are prefixed with it (``robot1/odom``) unless the
file sets ``tf_frame_prefix``; ``/tf`` stays global, as tf2 expects. ``rviz:=true``
also starts RViz2 with the package's view of the odometry (its covariance), the TF tree
and the follower's path; without RViz2 installed, launch stops with one line saying so
before it starts anything (the node used to start, then stay after launch failed).

The package's nodes are told launch's pid (``lifetime.child_env``) and stop by themselves
once launch has ended, however it ended (SIGKILL, SIGHUP of a closed ssh session).
"""

# ruff: noqa: I001 (ruff takes ./launch for first-party; this is ROS 2 launch)
import launch.logging
from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from diffdrive_odom.ros.launch_arguments import unknown_arguments_line
from diffdrive_odom.ros.lifetime import child_env

PACKAGE = "diffdrive_odom"
# The switches users flip most, as launch arguments; empty: the params files decide.
SWITCHES = ("use_imu", "enable_odom_tf")
_BOOLS = {"true": True, "false": False}


def _switches(context: LaunchContext) -> dict[str, bool]:
    """The switches given on the command line, as booleans (an empty one is left out)."""
    out = {}
    for name in SWITCHES:
        text = LaunchConfiguration(name).perform(context).strip().lower()
        if text:
            if text not in _BOOLS:
                raise ValueError(f"{name}:={text}: give true or false (or leave it out)")
            out[name] = _BOOLS[text]
    return out


def require_rviz(context: LaunchContext) -> None:
    """With rviz:=true, RViz2 must be installed: say so before anything starts.

    launch_ros looks a node's package up only when it starts that node, after the nodes
    before it: the odometry node was up when launch failed on rviz2 (and stayed up).
    Called first by :func:`_nodes`; base.launch.py includes this file before its nodes.
    """
    if not IfCondition(LaunchConfiguration("rviz")).evaluate(context):
        return
    try:
        get_package_prefix("rviz2")
    except PackageNotFoundError:
        raise RuntimeError(
            "rviz:=true needs RViz2, which is not installed (no package 'rviz2'): "
            "sudo apt install ros-jazzy-rviz2, or launch without rviz:=true") from None


def warn_unknown_arguments(context: LaunchContext, launch_file: str,
                           declared: list[str]) -> None:
    """One warning line for arguments given to ``ros2 launch`` that ``declared`` lacks.

    Not refused (an including file passes its own on); said only where ``launch_file`` is
    the file ros2 launch ran (base.launch.py, which declares this file's arguments too,
    says it for both).
    """
    line = unknown_arguments_line(launch_file, context.argv, declared)
    if line:
        launch.logging.get_logger("launch").warning(line)


def _nodes(context: LaunchContext, declared: list[str]) -> list[Node]:
    """odometry_node with the switches given, and RViz2 with rviz:=true."""
    warn_unknown_arguments(context, __file__, declared)
    require_rviz(context)
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    namespace = LaunchConfiguration("namespace").perform(context).strip("/")
    odom = Node(
        package=PACKAGE,
        executable="odometry_node",
        name="odometry_node",
        namespace=LaunchConfiguration("namespace"),
        parameters=[LaunchConfiguration("params_file"), LaunchConfiguration("extra_params_file"),
                    {"use_sim_time": use_sim_time, **_switches(context)}],
        remappings=[
            ("joint_states", LaunchConfiguration("joint_states_topic")),
            ("odom", LaunchConfiguration("odom_topic")),
        ],
        additional_env=child_env({}),  # launch's pid: the node ends with it
        output="screen",
    )
    # The config names the root-namespace topics; in a namespace they are remapped into
    # it (/tf stays global) and the fixed frame takes the frame prefix the node uses.
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        namespace=LaunchConfiguration("namespace"),
        condition=IfCondition(LaunchConfiguration("rviz")),
        arguments=["-d", PathJoinSubstitution(
            [FindPackageShare(PACKAGE), "rviz", "diffdrive_odom.rviz"]),
            "-f", f"{namespace}/odom" if namespace else "odom"],
        parameters=[{"use_sim_time": use_sim_time}],
        remappings=[("/odom", LaunchConfiguration("odom_topic")), ("/path", "path")],
        output="screen",
    )
    return [odom, rviz]


def generate_launch_description() -> LaunchDescription:
    """The arguments, the node and the optional RViz2."""
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), "config", "diffdrive_odom.yaml"]),
            description="ROS 2 params YAML for the nodes (parameters under /**)"),
        DeclareLaunchArgument(
            "extra_params_file", default_value=LaunchConfiguration("params_file"),
            description="A second params YAML applied after params_file (its values win)"),
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
        DeclareLaunchArgument(
            "use_imu", default_value="",
            description="Gyrodometry on the imu topic: true or false (empty: the params file's)"),
        DeclareLaunchArgument(
            "enable_odom_tf", default_value="",
            description="Publish odom -> base_link on /tf: true or false (empty: the file's)"),
        DeclareLaunchArgument(
            "rviz", default_value="false",
            description="Also start RViz2 with the odometry, its covariance, TF and the path"),
    ]
    declared = [a.name for a in arguments]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes, args=[declared])])
