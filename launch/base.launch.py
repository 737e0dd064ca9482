"""Start a base: ``ros2 launch diffdrive_odom base.launch.py [use_sim:=true]``.

``odometry_node`` (through ``odometry.launch.py``, which takes the same arguments:
``use_imu``, ``enable_odom_tf``, ``rviz``) and ``cmd_vel_node``, all from one params
file and the ``extra_params_file`` layered after it; with ``use_sim:=true`` also ``sim_node``, a
simulated base in place of the hardware driver; with ``use_follower:=true`` also
``path_follower_node`` (odom in, cmd_vel out, path from the params file's
``follower.*`` or the ``path`` topic). The simulation moves with the params
file's geometry (its ``true_*`` parameters are left at 0 = nominal), a 50 ms motor lag
and a 0.5 s command timeout, publishing at 50 Hz; with ``use_imu:=true`` also its gyro on
``imu`` at 100 Hz (``imu_rate``), which the odometry then reads. It publishes ``/clock``
only with ``use_sim_time:=true``; it never follows ``/clock`` itself, since it is the clock.
Every node ends with launch, however launch ends (see odometry.launch.py).
"""

# ruff: noqa: I001 (ruff takes ./launch for first-party; this is ROS 2 launch)
import launch.logging
from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.conditions import IfCondition
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, ThisLaunchFileDir
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from diffdrive_odom.ros.launch_arguments import unknown_arguments_line
from diffdrive_odom.ros.lifetime import child_env

PACKAGE = "diffdrive_odom"

# sim_node's own settings (the geometry comes from the params file's /** section).
SIM_PARAMETERS = {
    "motor_time_constant": 0.05,  # [s] first-order motor response
    "command_timeout": 0.5,  # [s] no wheel command -> the wheels stop
}
# [Hz] the simulated gyro with use_imu:=true: 2 samples per 50 Hz reading (the sim
# publishes a whole number per reading), each stamped at the middle of its own period,
# so none shares a wheel reading's stamp. Without it the odometry would say "IMU silent".
SIM_IMU_RATE = 100.0


def _sim_gyro(context: LaunchContext) -> dict[str, float]:
    """sim_node's gyro when use_imu:=true is given (else the params files' imu_rate)."""
    given = LaunchConfiguration("use_imu").perform(context).strip().lower()
    return {"imu_rate": SIM_IMU_RATE} if given == "true" else {}


def _sim_node(context: LaunchContext) -> list[Node]:
    """sim_node with use_sim:=true: the simulated base, and its gyro with use_imu:=true."""
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    return [Node(
        package=PACKAGE,
        executable="sim_node",
        name="sim_node",
        namespace=LaunchConfiguration("namespace"),
        condition=IfCondition(LaunchConfiguration("use_sim")),
        parameters=[LaunchConfiguration("params_file"), LaunchConfiguration("extra_params_file"),
                    {**SIM_PARAMETERS, **_sim_gyro(context),
                     "publish_clock": use_sim_time, "use_sim_time": False}],
        remappings=[("joint_states", LaunchConfiguration("joint_states_topic")),
                    ("wheel_commands", LaunchConfiguration("wheel_commands_topic"))],
        additional_env=child_env({}),  # launch's pid: the node ends with it
        output="screen",
    )]


def _warn_unknown_arguments(context: LaunchContext, declared: list[str]) -> None:
    """One warning line for arguments given to ``ros2 launch`` that no file here declares.

    odometry.launch.py's are among ``declared``; it says nothing when included.
    """
    line = unknown_arguments_line(__file__, context.argv, declared)
    if line:
        launch.logging.get_logger("launch").warning(line)


def generate_launch_description() -> LaunchDescription:
    """The arguments, odometry.launch.py, cmd_vel_node, the optional sim_node and follower."""
    namespace = LaunchConfiguration("namespace")
    params_file = LaunchConfiguration("params_file")
    extra_params_file = LaunchConfiguration("extra_params_file")
    sim_time = LaunchConfiguration("use_sim_time")
    use_sim_time = ParameterValue(sim_time, value_type=bool)
    wheel_commands = ("wheel_commands", LaunchConfiguration("wheel_commands_topic"))
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
            description="Follow /clock; with use_sim:=true the simulation publishes it"),
        DeclareLaunchArgument(
            "use_sim", default_value="false",
            description="Also start sim_node, a simulated base, instead of the hardware"),
        DeclareLaunchArgument(
            "use_follower", default_value="false",
            description="Also start path_follower_node (Kumar's law: odom in, cmd_vel out)"),
        DeclareLaunchArgument(
            "joint_states_topic", default_value="joint_states",
            description="sensor_msgs/JointState encoder readings (relative = in the namespace)"),
        DeclareLaunchArgument(
            "odom_topic", default_value="odom",
            description="nav_msgs/Odometry output of odometry_node"),
        DeclareLaunchArgument(
            "cmd_vel_topic", default_value="cmd_vel",
            description="Velocity command input of cmd_vel_node"),
        DeclareLaunchArgument(
            "wheel_commands_topic", default_value="wheel_commands",
            description="Wheel velocity commands out of cmd_vel_node (into the driver)"),
        DeclareLaunchArgument(
            "use_imu", default_value="",
            description="Gyrodometry on the imu topic: true or false (empty: the params "
            "file's); true with use_sim also starts the sim's gyro (imu_rate 100 Hz)"),
        DeclareLaunchArgument(
            "enable_odom_tf", default_value="",
            description="Publish odom -> base_link on /tf: true or false (empty: the file's)"),
        DeclareLaunchArgument(
            "rviz", default_value="false",
            description="Also start RViz2 with the odometry, its covariance, TF and the path"),
    ]
    return LaunchDescription([
        *arguments,
        OpaqueFunction(function=_warn_unknown_arguments, args=[[a.name for a in arguments]]),
        # First of the nodes: it checks rviz:=true's RViz2 before any node starts.
        IncludeLaunchDescription(PythonLaunchDescriptionSource(
            PathJoinSubstitution([ThisLaunchFileDir(), "odometry.launch.py"]))),
        Node(
            package=PACKAGE,
            executable="cmd_vel_node",
            name="cmd_vel_node",
            namespace=namespace,
            parameters=[params_file, extra_params_file, {"use_sim_time": use_sim_time}],
            remappings=[("cmd_vel", LaunchConfiguration("cmd_vel_topic")), wheel_commands],
            additional_env=child_env({}),  # launch's pid: the node ends with it
            output="screen",
        ),
        OpaqueFunction(function=_sim_node),
        Node(
            package=PACKAGE,
            executable="path_follower_node",
            name="path_follower_node",
            namespace=namespace,
            condition=IfCondition(LaunchConfiguration("use_follower")),
            parameters=[params_file, extra_params_file, {"use_sim_time": use_sim_time}],
            remappings=[("odom", LaunchConfiguration("odom_topic")),
                        ("cmd_vel", LaunchConfiguration("cmd_vel_topic"))],
            additional_env=child_env({}),  # launch's pid: the node ends with it
            output="screen",
        ),
    ])
