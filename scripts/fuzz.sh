#!/usr/bin/env bash
# Runs every cargo-fuzz target of fuzz/ for SECONDS seconds each (default 300), then prints one
# line per target: executions, corpus size, crashes. Exits non-zero if any target crashed (the
# input is in fuzz/artifacts/TARGET/). Only the stable toolchain is needed: RUSTC_BOOTSTRAP=1 lets
# cargo-fuzz use its nightly flags, and `-s none` builds without a sanitizer (libFuzzer's
# coverage guidance stays on). cargo-fuzz is installed from crates.io when missing.
#
#   scripts/fuzz.sh [SECONDS]            all targets
#   FUZZ_TARGETS="sync params" scripts/fuzz.sh 60
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-300}
targets=${FUZZ_TARGETS:-cdr_image cdr_camera_info cdr_tf tf_history compressed sync params bag_reader}
export RUSTC_BOOTSTRAP=1

if ! command -v c++ >/dev/null 2>&1; then
    echo "fuzz: libFuzzer needs a C++ compiler (apt-get install g++)" >&2
    exit 1
fi
if ! cargo fuzz --version >/dev/null 2>&1; then
    echo "fuzz: installing cargo-fuzz"
    cargo install cargo-fuzz --locked
fi

# Seed corpora from the test fixtures (only into empty corpora; libFuzzer adds to them).
seed() {
    local target=$1
    shift
    mkdir -p "fuzz/corpus/$target"
    if [ -z "$(ls -A "fuzz/corpus/$target")" ]; then
        for f in "$@"; do
            [ -f "$f" ] && cp "$f" "fuzz/corpus/$target/seed-$(basename "$f")"
        done
    fi
    return 0
}
seed cdr_image tests/fixtures/cdr/image.bin
seed cdr_camera_info tests/fixtures/cdr/camera_info.bin
seed cdr_tf tests/fixtures/cdr/tf_message.bin tests/fixtures/cdr/transform_stamped.bin
seed tf_history tests/fixtures/cdr/tf_message.bin tests/fixtures/cdr/transform_stamped.bin
seed compressed tests/fixtures/fuzz/seeds/compressed_jpeg.bin tests/fixtures/fuzz/seeds/compressed_png.bin \
    tests/fixtures/fuzz/compressed/jpeg_coefficient_overflow.bin
seed sync
seed params
mkdir -p fuzz/corpus/bag_reader
if [ -z "$(ls -A fuzz/corpus/bag_reader)" ] && [ -f tests/fixtures/bags/tsukuba_half.mcap ]; then
    # The start (header, schemas, channels, a chunk's beginning) and the end (summary, footer).
    head -c 16384 tests/fixtures/bags/tsukuba_half.mcap > fuzz/corpus/bag_reader/seed-head.mcap
    tail -c 8192 tests/fixtures/bags/tsukuba_half.mcap > fuzz/corpus/bag_reader/seed-tail.mcap
fi

# Short smoke runs (CI: 10 s per target) build without optimisations (`--dev`): a from-scratch
# build of every dependency with coverage instrumentation is most of a smoke run's time, and an
# unoptimised one compiles in a fraction of it (518 s CPU from a fresh clone); the inputs still
# run with overflow checks and debug assertions, as in cargo-fuzz's release build. Longer runs
# build optimised for more executions per second. FUZZ_PROFILE=dev|release overrides.
profile=${FUZZ_PROFILE:-}
if [ -z "$profile" ]; then
    if [ "$seconds" -le 60 ]; then profile=dev; else profile=release; fi
fi
case "$profile" in
dev) profile_flag=--dev ;;
release) profile_flag=--release ;;
*)
    echo "fuzz: FUZZ_PROFILE must be dev or release, not '$profile'" >&2
    exit 2
    ;;
esac
echo "fuzz: building the targets (cargo fuzz build -s none $profile_flag)"
cargo fuzz build -s none "$profile_flag"

mkdir -p fuzz/logs
failed=()
summary=()
for target in $targets; do
    max_len=4096
    [ "$target" = bag_reader ] && max_len=65536
    echo "fuzz: $target for ${seconds} s"
    log="fuzz/logs/$target.log"
    # FUZZ_SEED (CI sets 1) makes the input sequence reproducible.
    seed_arg=()
    [ -n "${FUZZ_SEED:-}" ] && seed_arg=(-seed="$FUZZ_SEED")
    if cargo fuzz run -s none "$profile_flag" "$target" "fuzz/corpus/$target" -- \
        -max_total_time="$seconds" -max_len="$max_len" -timeout=10 -rss_limit_mb=2048 \
        "${seed_arg[@]}" -print_final_stats=1 >"$log" 2>&1; then
        status=ok
    else
        status=CRASH
        failed+=("$target")
        tail -n 40 "$log"
    fi
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
    corpus=$(ls -A "fuzz/corpus/$target" | wc -l)
    crashes=$(ls -A "fuzz/artifacts/$target" 2>/dev/null | wc -l)
    summary+=("$(printf '%-16s %-5s %10s executions  %6s corpus files  %3s artifacts' \
        "$target" "$status" "${execs:-?}" "$corpus" "$crashes")")
done
echo "fuzz: ${seconds} s per target"
printf '  %s\n' "${summary[@]}"
if [ ${#failed[@]} -gt 0 ]; then
    echo "fuzz: crashed: ${failed[*]} (inputs in fuzz/artifacts/, logs in fuzz/logs/)" >&2
    exit 1
fi
