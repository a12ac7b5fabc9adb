#!/bin/sh
# Installs what sweepdepth's commands and tests need, only where it is missing (Debian/Ubuntu):
# - a Vulkan driver for wgpu: on a machine with a GPU driver nothing; otherwise the Vulkan loader
#   and Mesa's lavapipe (a software Vulkan driver that runs the compute shaders on the CPU);
# - `ip` (iproute2) and `unshare` (util-linux), with which the DDS tests move themselves into a
#   private network namespace so that no DDS traffic leaves the machine;
# - Debian's Chromium (package `chromium`), the headless browser in which tests/live/viewer_page.rs
#   loads the built-in live-view page (no browser download: the distribution's package);
# - Python 3 with the test tools of tools/requirements-test.txt (`cyclonedds`, the independent DDS
#   peer of tests/node/node_cyclone.rs; `rosbags` and `mcap`, the independent bag reader/writer of
#   tests/bags/bag.rs; `opencv-python-headless`, the camera-model reference of
#   tests/formats/camera_conventions.rs), the real ROS 2 Jazzy stack of tools/requirements-ros.txt (rclpy over
#   rcl + rmw_fastrtps_cpp, the rcl peer of tests/node/node_rclpy.rs, run through tools/ros_python;
#   ament_index_python) and colcon with colcon-ros-cargo and cargo-ament-build of
#   tools/requirements-colcon.txt (the workspace build of tests/house/colcon.rs):
#   the system Python when it already has them all, else a virtual environment made from a
#   Python 3.11, the only version the ROS wheels are built for (Debian's Python refuses global pip
#   installs), kept in a cache outside the clone (~/.cache/sweepdepth, one per set of pins) and
#   linked as target/test-venv. Pinned versions; nothing is installed when all is present.
# Run it from the repository root.
#
# `sh scripts/setup.sh --demo` installs only what `sweepdepth demo` needs: on a machine without
# a GPU the demo runs on the CPU engine and needs nothing beyond Rust, so this checks and
# installs nothing (no Vulkan, browser, Python tools or ROS wheels: the tests' needs).
set -eu

if [ "${1:-}" = "--demo" ]; then
    echo "setup: the demo needs nothing beyond Rust here (the CPU engine without a GPU; a GPU's own Vulkan driver when there is one)" >&2
    exit 0
fi

have_icd() {
    for dir in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
        ls "$dir"/*.json >/dev/null 2>&1 && return 0
    done
    return 1
}
have_loader() {
    ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1' || ls /usr/lib/*/libvulkan.so.1 >/dev/null 2>&1
}

packages=""
if ! (have_loader && have_icd); then
    packages="$packages mesa-vulkan-drivers libvulkan1"
fi
command -v ip >/dev/null 2>&1 || packages="$packages iproute2"
command -v unshare >/dev/null 2>&1 || packages="$packages util-linux"
command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 ||
    packages="$packages chromium"
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || packages="$packages python3 python3-venv"

PY_CHECK='import cyclonedds, rosbags, mcap, cv2, rclpy, sensor_msgs.msg, std_msgs.msg, rcl_interfaces.srv, diagnostic_msgs.msg, visualization_msgs.msg, std_srvs.srv, ament_index_python, colcon_core, colcon_ros, colcon_cargo, colcon_ros_cargo'
# The ROS wheels are cp311 only: the venv needs a Python 3.11.
python311() {
    for py in python3.11 python3; do
        command -v "$py" >/dev/null 2>&1 &&
            "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null &&
            { echo "$py"; return 0; }
    done
    return 1
}
# The venv lives in a cache outside the clone, one per set of pinned requirements (a fresh clone on
# the same machine reuses it; a changed pin makes a new one), and target/test-venv links to it.
# SWEEPDEPTH_CACHE_DIR moves the cache (default ${XDG_CACHE_HOME:-~/.cache}/sweepdepth).
REQUIREMENTS="tools/requirements-test.txt tools/requirements-ros.txt tools/requirements-colcon.txt"
venv_dir() {
    # shellcheck disable=SC2086
    key=$(cat $REQUIREMENTS | sha256sum | cut -c1-16)
    echo "${SWEEPDEPTH_CACHE_DIR:-${XDG_CACHE_HOME:-${HOME:-/nonexistent}/.cache}/sweepdepth}/test-venv-py311-$key"
}
venv_ready() {
    [ -f "$1/.complete" ] && [ -x "$1/bin/python3" ] && [ -x "$1/bin/cargo-ament-build" ] &&
        "$1/bin/python3" -c "$PY_CHECK" >/dev/null 2>&1
}
make_venv() {
    venv=$1
    venv_ready "$venv" && return 0
    echo "setup: installing the Python test tools (cyclonedds, rosbags, mcap, opencv-python-headless; rclpy and the ROS 2 Jazzy messages; colcon, colcon-ros-cargo, cargo-ament-build) into $venv ..." >&2
    if [ -x "$venv/bin/python3" ] &&
        ! "$venv/bin/python3" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
        echo "setup: $venv is not Python 3.11; making it anew" >&2
        rm -rf "$venv"
    fi
    [ -x "$venv/bin/python3" ] || "$py" -m venv "$venv"
    # shellcheck disable=SC2086
    "$venv/bin/python3" -m pip install -q $(printf -- '-r %s ' $REQUIREMENTS) &&
        touch "$venv/.complete"
}
install_python_tools() {
    # cargo-ament-build is a program (its wheel puts it beside the venv's python): `cargo
    # ament-build` finds it on PATH.
    python3 -c "$PY_CHECK" >/dev/null 2>&1 && command -v cargo-ament-build >/dev/null 2>&1 &&
        return 0
    if ! py=$(python311); then
        echo "setup: the ROS 2 wheels (tools/requirements-ros.txt) need Python 3.11 (python3.11 or a python3 of that version); none found" >&2
        return 1
    fi
    mkdir -p target
    venv=$(venv_dir)
    if ! mkdir -p "$(dirname "$venv")" 2>/dev/null; then
        echo "setup: cannot create the cache $(dirname "$venv"); the venv goes into target/test-venv" >&2
        [ -L target/test-venv ] && rm -f target/test-venv
        make_venv target/test-venv
        return $?
    fi
    if ! venv_ready "$venv"; then
        # One installer at a time per cache entry (two clones set up at once wait for each other).
        if command -v flock >/dev/null 2>&1; then
            (flock 9 && make_venv "$venv") 9>"$venv.lock" || return 1
        else
            make_venv "$venv" || return 1
        fi
    fi
    # A venv of the old layout (a directory in target/) gives way to the link.
    [ -d target/test-venv ] && [ ! -L target/test-venv ] && rm -rf target/test-venv
    ln -sfn "$venv" target/test-venv
    echo "setup: target/test-venv -> $venv" >&2
}

if [ -z "$packages" ]; then
    install_python_tools
    exit $?
fi

if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: missing$packages and no apt-get to install them." >&2
    echo "Install your GPU's Vulkan driver (or Mesa's lavapipe: mesa-vulkan-drivers, and the Vulkan loader libvulkan1), iproute2 and util-linux." >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "setup: need root (or sudo) to install$packages" >&2
        exit 1
    fi
fi
echo "setup: installing$packages ..." >&2
$SUDO apt-get update -qq
# shellcheck disable=SC2086
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $packages >/dev/null
if ! have_icd; then
    echo "setup: installed, but still no Vulkan ICD found" >&2
    exit 1
fi
install_python_tools
