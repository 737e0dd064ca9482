"""The unknown-launch-argument line (issue 39 item 5), as the launch files call it.

The real ``ros2 launch`` of both files: test_launch_interrupt's
test_an_unknown_launch_argument_gets_one_warning_naming_the_real_one.
"""

from __future__ import annotations

from diffdrive_odom.ros.launch_arguments import unknown_arguments_line

BASE = "/opt/ros/install/share/diffdrive_odom/launch/base.launch.py"
DECLARED = ["params_file", "use_sim", "use_sim_time", "enable_odom_tf", "use_imu"]
ROS2 = "/usr/bin/ros2"


def test_the_file_ros2_launch_ran_names_each_unknown_argument_once() -> None:
    for command in ([ROS2, "launch", "diffdrive_odom", "base.launch.py"],
                    [ROS2, "launch", BASE]):  # by package, or by path
        given = ["publish_tf:=false", "use_sim:=true", "publish_tf:=true", "use_imu_:=true"]
        line = unknown_arguments_line(BASE, given, DECLARED, [*command, *given])
        assert line is not None and "\n" not in line
        assert line.startswith("base.launch.py has no launch argument publish_tf:= (did you "
                               "mean enable_odom_tf? "), line
        assert line.count("publish_tf:=") == 1 and "use_imu_:= (did you mean use_imu?)" in line
        assert "use_sim:=" not in line
        assert line.endswith("; ignored (ros2 launch diffdrive_odom base.launch.py --show-args "
                             "lists them)"), line


def test_nothing_is_said_when_included_or_when_all_are_known() -> None:
    given = ["my_robot:=tb3", "use_sim:=true"]
    included = [ROS2, "launch", "my_robot", "bringup.launch.py", *given]
    assert unknown_arguments_line(BASE, given, DECLARED, included) is None
    top = [ROS2, "launch", "diffdrive_odom", "base.launch.py"]
    assert unknown_arguments_line(BASE, ["use_sim:=true"], DECLARED, top) is None
    # What ros2 launch adds for --launch-prefix is its own.
    assert unknown_arguments_line(BASE, ["launch-prefix:=gdb -ex run --args"], DECLARED,
                                  top) is None
