#!/usr/bin/env bash
# Builds the ROS 2 interface packages in interfaces/ (grid_map_msgs, roadbev_msgs) with CMake +
# Ninja and installs them straight into a virtual environment's prefix, so that nothing needs
# sourcing: `import grid_map_msgs.msg` works in that venv's python.
#
#   scripts/build_interfaces.sh VENV
#
# VENV must already hold the ROS 2 Jazzy wheels of requirements.txt (rosidl generators, ament).
# Idempotent: re-running re-uses the build folders under VENV/var/roadbev-interfaces/ and only
# rebuilds what changed. Any failure stops the script with a non-zero exit and says where.
# The flags: the packages install into the venv's own prefix with its python (the wheels carry no
# setup scripts to source), without tests, and scripts/ros_wheels_fix.cmake drops the include
# paths of the wheels' build container from their exported targets.
set -euo pipefail

die() { echo "[build_interfaces] ERROR: $*" >&2; exit 1; }

[[ $# -eq 1 ]] || die "usage: $0 VENV"
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$(cd "$1" 2>/dev/null && pwd)" || die "venv '$1' does not exist"
python="$venv/bin/python"
[[ -x "$python" ]] || die "$python is not an executable python"
for tool in cmake ninja c++; do
  command -v "$tool" >/dev/null || die "'$tool' not found on PATH (needed to build the interfaces)"
done
[[ -d "$venv/share/rosidl_default_generators" ]] \
  || die "rosidl_default_generators is not installed in $venv (pip install -r requirements.txt first)"

packages=(grid_map_msgs roadbev_msgs tf2_msgs)
build_root="$venv/var/roadbev-interfaces"
fix="$root/scripts/ros_wheels_fix.cmake"
jobs="${ROADBEV_BUILD_JOBS:-2}"
export VIRTUAL_ENV="$venv"
export PATH="$venv/bin:$PATH"
export CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"

for pkg in "${packages[@]}"; do
  src="$root/interfaces/$pkg"
  build="$build_root/$pkg"
  log="$build_root/$pkg.log"
  [[ -f "$src/CMakeLists.txt" && -f "$src/package.xml" ]] || die "$src is not an ament_cmake package"
  # A build folder configured for another source tree (the checkout moved) cannot be reused.
  if [[ -f "$build/CMakeCache.txt" ]] && ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$src" "$build/CMakeCache.txt"; then
    rm -rf "$build"
  fi
  mkdir -p "$build"
  echo "[build_interfaces] $pkg: configure, build, install into $venv (log: $log)" >&2
  {
    cmake -S "$src" -B "$build" -G Ninja \
      -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_INSTALL_PREFIX="$venv" \
      -DCMAKE_PREFIX_PATH="$venv" \
      -DCMAKE_PROJECT_INCLUDE="$fix" \
      -DPython3_EXECUTABLE="$python" \
      -DBUILD_TESTING=OFF \
    && cmake --build "$build" -j "$jobs" \
    && cmake --install "$build"
  } >"$log" 2>&1 || { tail -n 40 "$log" >&2; die "$pkg failed to build (full log: $log)"; }
done

# The proof that it worked: both packages import and their message classes load their C type
# support (which is what rclpy needs to publish them).
"$python" - <<'PY' || die "the built interface packages do not import in $python"
import grid_map_msgs.msg
import grid_map_msgs.srv
import roadbev_msgs.msg
from rclpy.type_support import check_for_type_support

for cls in (grid_map_msgs.msg.GridMap, grid_map_msgs.srv.GetGridMap, roadbev_msgs.msg.RoadPreview):
    check_for_type_support(cls)
PY
echo "[build_interfaces] done: ${packages[*]}" >&2
