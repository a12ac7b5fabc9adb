#!/bin/sh
# Overload soak of the node (a benchmark, not part of `cargo test`): tests/soak.rs publishes a
# synthetic 4-camera 320x240 rig at twice the rate the node sustains for MINUTES (default 10)
# and samples the node's resident memory every 10 s; it fails if the node dies or its memory
# grows by more than 10 % after the first minute. The test moves itself into a private network
# namespace with only loopback, so no DDS packet leaves the machine. Run from the repository root.
set -eu
SWEEPDEPTH_SOAK_MINUTES="${1:-10}" exec cargo test --release --test soak -- --ignored --nocapture
