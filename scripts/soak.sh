#!/bin/sh
# Overload soak of the node (a benchmark, not a test): examples/soak.rs publishes a synthetic
# 4-camera 320x240 rig at twice the rate the node sustains for MINUTES (default 10) and samples
# the node's resident memory every 10 s. Everything runs in a private network namespace with only
# loopback, so no DDS packet leaves the machine. Run from the repository root (as root, or with
# user namespaces: unshare -rn).
set -eu
MINUTES="${1:-10}"
cargo build --release --bin sweepdepth --example soak
FLAGS="-n"
[ "$(id -u)" = "0" ] || FLAGS="-rn"
exec unshare $FLAGS sh -c 'ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo && exec target/release/examples/soak "$0"' "$MINUTES"
