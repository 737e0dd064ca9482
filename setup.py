"""ament_python package: builds with colcon on a robot and installs with pip anywhere."""

from glob import glob
from pathlib import Path
from xml.etree import ElementTree

from setuptools import find_packages, setup

PACKAGE = "diffdrive_odom"
# package.xml is the one place the version is written (rosdep, bloom and colcon read it).
VERSION = ElementTree.parse(Path(__file__).resolve().parent / "package.xml").findtext("version")
# The bag tools (replay, eval, calibrate, play, reindex) and the demo's report and plot.
# rosbags to the minor version tested: the bulk writer and the recovery of torn
# recordings lean on its internals (diffdrive_odom/tools/bags/rosbagsinternals.py).
TOOLS = ["rosbags>=0.11.9,<0.12", "orjson", "matplotlib", "scipy", "threadpoolctl"]

setup(
    name=PACKAGE,
    version=(VERSION or "").strip(),
    # diffdrive_odom/data holds files, no module: listed as a package of its own (setuptools
    # deprecates installing a directory it did not list as a package as data, and colcon
    # then ends with "1 package had stderr output").
    packages=[*find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
              f"{PACKAGE}.data"],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
    ],
    package_data={f"{PACKAGE}.data": ["*"]},
    include_package_data=True,
    # What the nodes import besides ROS (package.xml's python3-numpy and python3-yaml):
    # rclpy and the messages come from ROS (apt, or the ros-jazzy-* wheels), tf2_msgs
    # too (scripts/build_tf2_msgs.sh where no apt): not PyPI requirements. setuptools
    # builds the package (pip and colcon bring it); nothing imports it at run time.
    install_requires=["numpy", "pyyaml"],
    extras_require={
        "tools": TOOLS,
        # The test suite (`colcon test` runs it as pytest): the tools plus the test tools.
        "test": ["pytest", "pytest-timeout", "hypothesis", "mcap", "mcap-ros2-support",
                 *TOOLS],
        "fleet": ["distributed"],  # replay / eval --dask ADDRESS (dask.distributed, with dask)
    },
    zip_safe=True,
    maintainer="diffdrive_odom maintainers",
    maintainer_email="maintainers@diffdrive-odom.invalid",
    description="Exact CIR wheel odometry and cmd_vel kinematics for differential-drive robots",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "odometry_node = diffdrive_odom.ros.odometry_node:main",
            "odometry_lifecycle_node = diffdrive_odom.ros.odometry_lifecycle_node:main",
            "cmd_vel_node = diffdrive_odom.ros.cmd_vel_node:main",
            "sim_node = diffdrive_odom.ros.sim_node:main",
            "path_follower_node = diffdrive_odom.ros.path_follower_node:main",
            "diffdrive-odom = diffdrive_odom.tools.cli:main",
        ],
    },
)
