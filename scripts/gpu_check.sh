#!/bin/sh
# The one-command GPU check (issue 30, item 3): what a session lent a GPU runs at once, through
# the `device` tool, in about 8 minutes of device time. It prints the adapter, then runs `bench`
# (both engines, every configuration, the OpenCV SGBM peer when the machine has cv2), `demo` and
# `eval` on the built-in Tsukuba with the WGSL engine and with the CPU engine, and writes one
# report, `$OUT/gpu_check.txt` (the device tool's folder that comes back; `target/gpu-check`
# here).
#
# Prepare here, once (the device machine has no Rust and may have no Vulkan loader):
#   cargo build --release
#   echo /.gl/ >> .git/info/exclude; mkdir -p .gl /tmp/amd64/partial
#   o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
#   apt-get $o update; (cd .gl && apt-get $o download libvulkan1)
# then run it with `carry: [".gl", "target/release/sweepdepth"]` and the command
#   sh scripts/gpu_check.sh
# (the device tool's README: the loader's .deb unpacked into / and ldconfig; the NVIDIA ICD
# named by VK_DRIVER_FILES when the loader finds none).
#
# Rehearse here on lavapipe: `GPU_CHECK_QUICK=1 sh scripts/gpu_check.sh` (bench --quick).
set -u
cd "$(dirname "$0")/.."
out=${OUT:-target/gpu-check}
mkdir -p "$out"
report="$out/gpu_check.txt"
bin=${SWEEPDEPTH_BIN:-target/release/sweepdepth}
: >"$report"

say() { echo "$*" | tee -a "$report"; }
# step NAME SECONDS COMMAND...: runs COMMAND under a limit, its output into the report.
step() {
    name=$1
    limit=$2
    shift 2
    say "== $name ($(date -u +%H:%M:%S), limit ${limit} s): $*"
    start=$(date +%s)
    timeout "$limit" "$@" >>"$report" 2>&1
    status=$?
    say "-- $name: exit $status after $(($(date +%s) - start)) s"
}

if [ -d .gl ] && ! ldconfig -p 2>/dev/null | grep -q libvulkan; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
if [ ! -x "$bin" ]; then
    say "no sweepdepth binary at $bin: build it with cargo build --release and carry it"
    exit 1
fi

say "gpu_check: $(date -u +%Y-%m-%dT%H:%M:%SZ), $(uname -m), $(nproc) cores"
command -v nvidia-smi >/dev/null 2>&1 &&
    step nvidia-smi 30 nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
# The adapter wgpu picks, and the WGSL engine working at all, on the paper's configuration.
step adapter 120 "$bin" bench --device gpu --config paper --repeats 1
if [ -n "${GPU_CHECK_QUICK:-}" ]; then
    step bench 600 "$bin" bench --quick
else
    step bench 330 "$bin" bench --repeats 5
fi
step demo-gpu 60 "$bin" demo --device gpu --out "$out/demo-gpu"
step demo-cpu 60 "$bin" demo --device cpu --out "$out/demo-cpu"
step eval-gpu 60 "$bin" eval --device gpu data/tsukuba
step eval-cpu 60 "$bin" eval --device cpu data/tsukuba
say "gpu_check: done; the report is $report"
