#!/bin/sh
# Soaks (benchmarks, not part of `cargo test`), on a release build, run from the repository root.
#
#   sh scripts/soak.sh [MINUTES]          the node's overload soak (tests/node/soak.rs, the
#       test soak::soak of the `node` test binary): a synthetic 4-camera 320x240 rig published
#       at twice the rate the node sustains for MINUTES (default 10), the node's resident memory
#       sampled every 10 s; fails if the node dies or its memory grows by more than 10 % after
#       the first minute. The test moves itself into a private network namespace with only
#       loopback, so no DDS packet leaves the machine.
#   sh scripts/soak.sh fusion [MINUTES]   fusion's memory soak (tests/engine/fusion_soak.rs, in
#       the `engine` test binary, run alone: it measures its own process's resident memory): a
#       camera moving down an endless corridor, fused with max_blocks far below what it needs,
#       the mesh's markers taken as the node does; fails if resident memory grows after the
#       first minute or the grid outgrows max_blocks. No DDS.
set -eu
if [ "${1:-}" = fusion ]; then
    SWEEPDEPTH_SOAK_SECONDS=$(( ${2:-10} * 60 )) exec cargo test --release --test engine -- \
        --ignored --exact fusion_soak::fusion_memory_stays_flat_on_an_endless_corridor --nocapture
fi
SWEEPDEPTH_SOAK_MINUTES="${1:-10}" exec cargo test --release --test node -- --ignored --exact soak::soak --nocapture
