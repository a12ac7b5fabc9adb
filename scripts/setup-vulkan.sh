#!/bin/sh
# Makes sure a Vulkan driver is present for wgpu. On a machine with a GPU driver already
# installed it does nothing; otherwise it installs the Vulkan loader and Mesa's lavapipe
# (a software Vulkan driver that runs the compute shaders on the CPU). Debian/Ubuntu only.
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

if have_loader && have_icd; then
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    echo "setup-vulkan: no Vulkan driver found and no apt-get to install one." >&2
    echo "Install your GPU's Vulkan driver, or Mesa's lavapipe (package mesa-vulkan-drivers) and the Vulkan loader (libvulkan1)." >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "setup-vulkan: need root (or sudo) to install mesa-vulkan-drivers libvulkan1" >&2
        exit 1
    fi
fi
echo "setup-vulkan: installing the Vulkan loader and Mesa lavapipe (software Vulkan)..." >&2
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
have_icd || { echo "setup-vulkan: installed, but still no Vulkan ICD found" >&2; exit 1; }
