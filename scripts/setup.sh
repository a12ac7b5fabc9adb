#!/bin/sh
# Installs what sweepdepth's commands and tests need, only where it is missing (Debian/Ubuntu):
# - a Vulkan driver for wgpu: on a machine with a GPU driver nothing; otherwise the Vulkan loader
#   and Mesa's lavapipe (a software Vulkan driver that runs the compute shaders on the CPU);
# - `ip` (iproute2) and `unshare` (util-linux), with which the DDS test moves itself into a
#   private network namespace so that no DDS traffic leaves the machine.
set -eu

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
if [ -z "$packages" ]; then
    exit 0
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
