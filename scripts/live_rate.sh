#!/bin/sh
# The live node's rate (issue 11, item 5): a 9-camera 450x375 rig with 57 planes played at 2 Hz
# into `sweepdepth node` (CPU engine when there is no GPU), on a release build. Runs the test
# tests/node/node_live_rate.rs (alone, from the test binary `node`) with more sets (SETS,
# default 30), which plays inside its own private network namespace (no DDS packet leaves the
# machine) and prints the share of sets answered, the sets dropped for newer ones and the
# node's mean processing time per set.
# Several references per set (issue 27): SWEEPDEPTH_LIVE_REFERENCES=cam1,cam4,cam7 (and
# SWEEPDEPTH_LIVE_MAX_NEIGHBOURS=N) in the environment; live fusion beside the engine (issue 28):
# SWEEPDEPTH_LIVE_FUSION=<voxel size in m>, e.g. 0.02.
# Usage: sh scripts/live_rate.sh [SETS]
set -eu
cd "$(dirname "$0")/.."
SETS="${1:-30}"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
SWEEPDEPTH_LIVE_SETS="$SETS" RUST_LOG="${RUST_LOG:-warn}" \
    cargo test --release --test node -- node_live_rate:: --nocapture 2>&1 |
    grep -E "live rate|test result|panicked|error"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
