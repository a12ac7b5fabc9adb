#!/bin/sh
# Prepares here, on the development machine, what `scripts/gpu_check.sh` needs on the device
# machine (which has no Rust and may have no Vulkan loader), so that a session lent a GPU spends
# its device time measuring: the release binary, the engine's and the library's test binaries
# (stripped, for the GPU-vs-CPU and fusion tests), the Vulkan loader's and libglvnd's `.deb`s
# (NVIDIA's driver needs both) and the 9-camera Teddy bag. Everything but the binary goes into
# `.gl/` (git-ignored through .git/info/exclude). Then, through the `device` tool:
#   carry: [".gl", "target/release/sweepdepth"]   command: sh scripts/gpu_check.sh
# and the report comes back in `$OUT/gpu_check.txt`. Takes a few minutes (the builds); the
# carried files must stay under the tool's 64 MiB: the sizes are printed at the end.
set -eu
cd "$(dirname "$0")/.."
mkdir -p .gl
exclude=.git/info/exclude
if [ -d .git ] && ! grep -qx '/.gl/' "$exclude" 2>/dev/null; then
    echo /.gl/ >>"$exclude"
fi
echo "gpu_prepare: the release binary"
cargo build --release
# A test target's binary, as cargo names it ("Executable ... (target/debug/deps/NAME-HASH)").
test_binary() {
    cargo test --no-run "$@" 2>&1 | sed -n 's/.*Executable .*(\(target\/debug\/deps\/[^)]*\)).*/\1/p' | tail -1
}
echo "gpu_prepare: the test binaries"
engine=$(test_binary --test engine)
lib=$(test_binary --lib)
[ -n "$engine" ] && [ -n "$lib" ] || {
    echo "gpu_prepare: no test binary found (cargo test --no-run)"
    exit 1
}
strip -o .gl/engine-tests "$engine"
strip -o .gl/lib-tests "$lib"
if ! ls .gl/libvulkan1_*.deb >/dev/null 2>&1; then
    echo "gpu_prepare: the Vulkan loader's and libglvnd's .debs"
    lists=$(mktemp -d)
    mkdir -p "$lists/partial"
    o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists"
    # shellcheck disable=SC2086
    apt-get $o update >/dev/null
    # shellcheck disable=SC2086
    (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
    rm -rf "$lists"
fi
teddy=../shared/data/middlebury2003_teddy_9view
if [ ! -f .gl/teddy9.mcap ] && [ -d "$teddy" ]; then
    echo "gpu_prepare: the 9-camera Teddy bag"
    target/release/sweepdepth pack "$teddy" .gl/teddy9.mcap --frames 20 --compressed
fi
echo "gpu_prepare: carried sizes (at most 64 MiB in all):"
du -ch .gl target/release/sweepdepth | tail -n 20
