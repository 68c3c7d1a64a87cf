#!/usr/bin/env bash
# Build control_msgs' DynamicJointState and InterfaceValue (tools/control_msgs) with the ROS 2
# Jazzy wheels of a venv, for the identifier's input dynamic_joint_state (`make control-msgs`).
#
#   tools/build_control_msgs.sh VENV [INSTALL_PREFIX]
#
# VENV holds the wheels (rclpy, std_msgs) and the generators of requirements-control-msgs.txt;
# INSTALL_PREFIX (default VENV) receives the package: its Python module in
# lib/pythonX.Y/site-packages and its libraries in lib, where the wheels' start-up hook puts
# them on the library path when INSTALL_PREFIX is the venv. Another prefix needs PYTHONPATH and
# LD_LIBRARY_PATH set to those two directories. Exit code 2 with a message when a tool is
# missing. On a ROS machine, install ros-jazzy-control-msgs instead.
set -euo pipefail

if [ $# -lt 1 ] || [ $# -gt 2 ]; then
    echo "usage: $0 VENV [INSTALL_PREFIX]" >&2
    exit 2
fi
venv=$(cd "$1" && pwd)
prefix=${2:-$venv}
mkdir -p "$prefix"
prefix=$(cd "$prefix" && pwd)
python=$venv/bin/python
source_dir=$(cd "$(dirname "$0")/control_msgs" && pwd)

if ! command -v cmake >/dev/null 2>&1; then
    echo "cmake not found: install it (apt-get install cmake) and run again" >&2
    exit 2
fi
if ! command -v c++ >/dev/null 2>&1 && ! command -v g++ >/dev/null 2>&1; then
    echo "no C++ compiler found: install one (apt-get install g++) and run again" >&2
    exit 2
fi
if [ ! -x "$python" ]; then
    echo "$python not found: give the venv that holds the ROS wheels" >&2
    exit 2
fi
if [ ! -f "$venv/share/ament_cmake/cmake/ament_cmakeConfig.cmake" ] ||
   [ ! -d "$venv/share/rosidl_default_generators" ]; then
    echo "ament_cmake or rosidl_default_generators missing in $venv: install them with" \
         "$python -m pip install -r requirements-control-msgs.txt" >&2
    exit 2
fi

generator=()
if command -v ninja >/dev/null 2>&1; then
    generator=(-G Ninja)
fi
build=$(mktemp -d "${TMPDIR:-/tmp}/control_msgs_build.XXXXXX")
trap 'rm -rf "$build"' EXIT
log=$build/build.log
# ament finds the type supports through the ament index of AMENT_PREFIX_PATH; the generators
# run with the venv's interpreter
export AMENT_PREFIX_PATH=$venv PATH=$venv/bin:$PATH
echo "building control_msgs (DynamicJointState, InterfaceValue) into $prefix ..."
if ! { cmake -S "$source_dir" -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release \
           -DCMAKE_PREFIX_PATH="$venv" -DCMAKE_INSTALL_PREFIX="$prefix" \
           -DPython3_EXECUTABLE="$python" -DBUILD_TESTING=OFF &&
       cmake --build "$build" -j 2 && cmake --install "$build"; } >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "building control_msgs failed (the end of its log is above)" >&2
    exit 1
fi
echo "control_msgs installed into $prefix"
