#!/bin/sh
# The one-command GPU check (issue 30, item 3): what a session lent a GPU runs at once, through
# the `device` tool, in about 9 minutes of device time. It prints the adapter, then runs `bench`
# (both engines, every configuration, the OpenCV SGBM peer when the machine has cv2), `demo` and
# `eval` on the built-in Tsukuba with the WGSL engine and with the CPU engine, and writes one
# report, `$OUT/gpu_check.txt` (the device tool's folder that comes back; `target/gpu-check`
# here).
#
# Prepare here first: `sh scripts/gpu_prepare.sh` (in `.gl/` the stripped release binary, engine
# and library test binaries, the Vulkan loader's and libglvnd's .debs and the packed 9-camera
# Teddy bag, gzipped into `.glz/gl.tgz`, about 28 MiB to carry).
# (NVIDIA's Vulkan driver, libGLX_nvidia, needs libglvnd: with the loader alone it answers
# "Could not get 'vkCreateInstance'" and wgpu finds no adapter). Then run it with
# `carry: [".glz"]` and the command
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
# The carried archive (scripts/gpu_prepare.sh) unpacked into .gl/, its binary preferred.
if [ -f .glz/gl.tgz ]; then
    tar -xzf .glz/gl.tgz
fi
if [ -z "${SWEEPDEPTH_BIN:-}" ] && [ -x .gl/sweepdepth ]; then
    SWEEPDEPTH_BIN=.gl/sweepdepth
fi
bin=${SWEEPDEPTH_BIN:-target/release/sweepdepth}
: >"$report"

say() { echo "$*" | tee -a "$report"; }
# The GPU's clocks, power state and temperature in one line (issue 56: the clock-state noise
# visible beside each column's figures); nothing without nvidia-smi.
clocks() {
    command -v nvidia-smi >/dev/null 2>&1 || return 0
    say "   clocks $1: $(nvidia-smi --query-gpu=clocks.sm,clocks.mem,clocks.max.sm,pstate,temperature.gpu,power.draw --format=csv,noheader 2>&1 | head -1)"
}
# step NAME SECONDS COMMAND...: runs COMMAND under a limit, its output into the report, the
# clocks before and after.
step() {
    name=$1
    limit=$2
    shift 2
    say "== $name ($(date -u +%H:%M:%S), limit ${limit} s): $*"
    clocks before
    start=$(date +%s)
    timeout "$limit" "$@" >>"$report" 2>&1
    status=$?
    clocks after
    say "-- $name: exit $status after $(($(date +%s) - start)) s"
}

if [ -d .gl ] && ls .gl/*.deb >/dev/null 2>&1; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
if [ -z "${VK_DRIVER_FILES:-}" ]; then
    for icd in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json \
        /etc/vulkan/icd.d/nvidia_icd.json $(find / -xdev -name 'nvidia_icd*.json' 2>/dev/null | head -1); do
        [ -f "$icd" ] && export VK_DRIVER_FILES="$icd" && break
    done
fi
if [ ! -x "$bin" ]; then
    say "no sweepdepth binary at $bin: build it with cargo build --release and carry it"
    exit 1
fi

say "gpu_check: $(date -u +%Y-%m-%dT%H:%M:%SZ), $(uname -m), $(nproc) cores, VK_DRIVER_FILES=${VK_DRIVER_FILES:-unset}, loader: $(ldconfig -p | grep -c libvulkan)"
command -v nvidia-smi >/dev/null 2>&1 &&
    step nvidia-smi 30 nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv &&
    step nvidia-smi-clocks 30 nvidia-smi -q -d CLOCK
# GPU_CHECK_PART=quality: only the quality and fine-sweep steps below (a second call, after a
# full check in the same session).
# The GPU-vs-CPU equality tests on the real adapter (the tolerances were set on lavapipe), and
# the fused cost and row sums (the default on a GPU) against the two passes, then fusion's GPU
# twins (integration, marching cubes, the fusion thread on a GPU): carried as stripped test
# binaries, `.gl/engine-tests` and `.gl/lib-tests`.
equality_tests() {
    if [ -x .gl/engine-tests ]; then
        export SWEEPDEPTH_GPU_TEST_STATS=1
        step gpu-tests 150 .gl/engine-tests gpu_vs_cpu cost_rows --test-threads 4
    fi
    if [ -x .gl/lib-tests ]; then
        step gpu-fusion-tests 120 .gl/lib-tests fusion::gpu fusion::mapper pipeline::fuser_thread --test-threads 2
    fi
}
if [ "${GPU_CHECK_PART:-}" != quality ]; then
# The adapter wgpu picks, and the WGSL engine working at all, on the paper's configuration.
step adapter 120 "$bin" bench --device gpu --config paper --repeats 1
# Issue 56's bars first (a check that runs out of time loses comparisons, not bars). Fusion:
# one 640x480 depth map integrated, copied to the host and meshed at 2 cm,
# on the GPU (`GpuTsdf`) beside the CPU integrator and Open3D's VoxelBlockGrid (when the machine's python3
# has open3d; the synthetic pair otherwise).
step bench-fusion 120 "$bin" bench --fusion --device gpu --repeats 5
if [ -n "${GPU_CHECK_QUICK:-}" ]; then
    step bench 600 "$bin" bench --quick
    equality_tests
else
    # The WGSL engine on every configuration first (the figures the README needs), then both
    # engines beside the peer.
    step bench-gpu 150 "$bin" bench --device gpu --repeats 5
    # The equality tests after the bars' figures (a lease is short).
    equality_tests
    # Depth and confidence read back alone (the node while nobody subscribes to cost and
    # selection): half the readback.
    step bench-gpu-depth-only 120 "$bin" bench --device gpu --config sxga --repeats 5 --depth-only
    # SGM's selection reading each pixel's words through workgroup memory in chunks (the
    # default on a GPU) against each invocation reading its own in place (the only way before
    # 2026-12-04: its sxga selection 4.2-9.9 ms), alternated twice: the `sgm_select` and
    # `coarse/sgm_select` ms of the ring and of the 1-megapixel rig.
    step bench-gpu-select-reads 150 sh -c "for r in 1 2; do for m in chunked in-place; do echo \"select-reads \$m\"; \"$bin\" bench --device gpu --config ring --config sxga --repeats 5 --select-reads \$m; done; done"
    # A 1-MP set's depth and confidence to their messages: copied out of the readback first
    # (the node with fusion) against lent out of it (without), alternated; with the copies
    # split over threads (auto, on this host) and on one thread, twice.
    step bench-gpu-maps-out 90 sh -c "for r in 1 2; do \"$bin\" bench --maps-out --repeats 15; \"$bin\" bench --maps-out --repeats 15 --host-copies serial; done"
    # Window sums (the defaults' centred 5x5): the costs summed along rows in the stage that
    # makes them (`cost_rows.wgsl`, the default on a GPU: no cost slab, one dispatch fewer per
    # batch, 1.5x the planes per batch) against the cost slab and a row-sum pass of its own,
    # alternated twice: the `sweep` and `coarse/sweep` ms of the ring and of the 1-megapixel
    # rig with centred 5x5 windows (lavapipe: fused 1.7x slower, hence apart on CPU adapters).
    step bench-gpu-cost-rows 180 sh -c "for r in 1 2; do for m in fused apart; do echo \"cost-rows \$m\"; \"$bin\" bench --device gpu --config ring --config sxga --repeats 5 --window-mode centred --window 5x5 --cost-rows \$m; done; done"
    # Batches of planes: the GPU's 512 MiB per batch (the default) against the CPU adapters'
    # 192 MiB, alternated twice (`sweep_dispatches` in the JSON: fewer batches, fewer
    # dispatches and fewer passes over each pixel's winner-take-all state).
    step bench-gpu-slab 150 sh -c "for r in 1 2; do for m in 512 192; do echo \"slab-mib \$m\"; \"$bin\" bench --device gpu --config ring --config sxga --repeats 5 --slab-mib \$m; done; done"
    # bench-gpu again as JSON beside the report: every stage, the coarse levels' own
    # (`coarse/sgm`, ...), the WTA columns' and the host counts.
    step bench-gpu-json 120 sh -c "\"$bin\" bench --device gpu --repeats 5 --json >\"$out/bench-gpu.json\""
    # SGM with one path line per workgroup, against the default above (several lines per
    # workgroup where the subgroups have one size: NVIDIA's 32): the 1-megapixel rig and the ring.
    step bench-gpu-sgm-lines-1 120 "$bin" bench --device gpu --config ring --config sxga --repeats 5 --sgm-lines 1
    # SGM's directions: all in one dispatch (the default on a GPU, after the sums are cleared)
    # against the first apart and the rest together (the walks before 2026-12-01) and one
    # dispatch per direction, alternated twice: the `sgm` ms and the SGM stages of the ring and
    # the 1-megapixel rig (`sgm_dispatches` per set in the JSON: levels x 1, 2 or 8).
    step bench-gpu-sgm-walks 180 sh -c "for r in 1 2; do for w in together first-apart one-by-one; do echo \"sgm-walks \$w\"; \"$bin\" bench --device gpu --config ring --config sxga --repeats 5 --sgm-walks \$w; done; done"
    # The host copies (images in, maps out) on one thread, against the default above (split
    # over rayon's threads on a host of 8 or more: `host ms` of sxga is issue 56's <= 2 ms bar;
    # every bench ends with the `messages:` line, the node's own host work per set at 1 MP).
    step bench-gpu-host-copies-serial 120 "$bin" bench --device gpu --config ring --config sxga --repeats 5 --host-copies serial
    # A set's references read back one by one (`--serial-references`) against the default
    # (every reference submitted before the first is read back), alternated twice: the 9-camera
    # rig with three references (`most_in_flight` 1 against 3 in the JSON).
    step bench-gpu-refs 120 sh -c "for r in 1 2; do \"$bin\" bench --device gpu --config 9-camera-3refs --repeats 5; \"$bin\" bench --device gpu --config 9-camera-3refs --repeats 5 --serial-references; done"
    # Sets back to back with the next on the device while one is read back (`bag` and the
    # node under load) against each set alone, alternated twice: ms per set of the stream
    # (the host's share hidden behind the device's) against one set's start to end.
    step bench-gpu-sets-ahead 150 sh -c "for r in 1 2; do \"$bin\" bench --device gpu --config ring --config sxga --repeats 9 --sets-ahead 1; \"$bin\" bench --device gpu --config ring --config sxga --repeats 9; done"
fi
# A stereo camera (issue 52): the rectified and the raw pair on both engines, beside
# rectification + SGBM 3-way (cv2 from the machine's python3, when it has it).
step bench-stereo 120 "$bin" bench --config stereo-rect --config stereo-raw --repeats 5 --python python3
# The node's pipeline with fusion on, on the 9-camera rig (issue 56, item 4): the packed
# Teddy bag (compressed images, as recorded) through `bag --mesh` on the WGSL engine, its ms
# per set with every depth map fused (the live node itself needs DDS peers the device machine
# has not).
if [ -f .gl/teddy9.mcap ]; then
    step bag-9-cameras-fusion 90 "$bin" bag .gl/teddy9.mcap /tmp/gpu-check-bag9 --force \
        --params-file .gl/teddy9.params.yaml -p device:=gpu --mesh /tmp/gpu-check-bag9.ply --voxel-size 0.2
    # The next set on the device while the host reads one back and writes it (the default)
    # against each set read back before the next is submitted, alternated twice: the
    # summary's ms per set.
    step bag-sets-ahead 120 sh -c "for r in 1 2; do for a in 1 0; do \"$bin\" bag .gl/teddy9.mcap /tmp/gpu-check-bag-ahead --force --params-file .gl/teddy9.params.yaml -p device:=gpu --sets-ahead \$a 2>&1 | grep 'frame sets found'; done; done"
fi
step demo-gpu 40 "$bin" demo --device gpu --out /tmp/gpu-check-demo-gpu
step demo-cpu 40 "$bin" demo --device cpu --out /tmp/gpu-check-demo-cpu
# The fine sweep (`subpixel_refine`) on the WGSL engine: its cost on a real GPU (lavapipe: the
# demo 1072 -> 1228 ms) and its results against the CPU engine's (bad>1 4.65 % on both).
step demo-gpu-refine 40 "$bin" demo --device gpu --subpixel-refine true --out /tmp/gpu-check-demo-refine
step eval-gpu 40 "$bin" eval --device gpu data/tsukuba
step eval-cpu 40 "$bin" eval --device cpu data/tsukuba
# Both engines beside the SGBM peer (cv2 from the machine's python3), last: it may run out of time.
[ -z "${GPU_CHECK_QUICK:-}" ] && step bench 170 "$bin" bench --repeats 3 --python python3
fi
# The public sets on both engines, with and without the fine sweep, when they are carried:
# GPU_CHECK_DATA names a folder of dataset folders (copies of ../shared/data/* in a carried,
# git-ignored folder; the device tool carries 64 MiB in all).
if [ -n "${GPU_CHECK_DATA:-}" ] && [ -d "$GPU_CHECK_DATA" ]; then
    step eval-data-gpu 150 "$bin" eval --device gpu "$GPU_CHECK_DATA"/*
    step eval-data-gpu-refine 150 "$bin" eval --device gpu --subpixel-refine true "$GPU_CHECK_DATA"/*
    step eval-data-cpu 150 "$bin" eval --device cpu "$GPU_CHECK_DATA"/*
fi
# The fine sweep's cost on the WGSL engine (issue 29's bar: the demo's time grows by at most
# 25 %), defaults and refined alternated twice in one call.
if [ "${GPU_CHECK_PART:-}" = quality ]; then
    for round in 1 2; do
        step "bench-defaults-$round" 60 "$bin" bench --device gpu --config demo --config ring --repeats 9
        step "bench-refined-$round" 60 "$bin" bench --device gpu --config demo --config ring --repeats 9 --subpixel-refine true
    done
fi
say "gpu_check: done; the report is $report"
