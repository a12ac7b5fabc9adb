#!/bin/sh
# Prepares here, on the development machine, what `scripts/gpu_check.sh` needs on the device
# machine (which has no Rust and may have no Vulkan loader), so that a session lent a GPU spends
# its device time measuring: the release binary, the engine's and the library's test binaries
# (all stripped; the tests for the GPU-vs-CPU and fusion checks), the Vulkan loader's and
# libglvnd's `.deb`s (NVIDIA's driver needs both) and the 9-camera Teddy bag, in `.gl/`, then
# gzipped into `.glz/gl.tgz` (both git-ignored through .git/info/exclude): the working tree
# (about 16 MiB) and what is carried must stay under the device tool's 64 MiB together. Then,
# through the `device` tool:
#   carry: [".glz"]   command: sh scripts/gpu_check.sh
# and the report comes back in `$OUT/gpu_check.txt`. Takes a few minutes (the builds); the
# sizes are printed at the end.
set -eu
cd "$(dirname "$0")/.."
mkdir -p .gl
exclude=.git/info/exclude
for ignored in /.gl/ /.glz/; do
    if [ -d .git ] && ! grep -qx "$ignored" "$exclude" 2>/dev/null; then
        echo "$ignored" >>"$exclude"
    fi
done
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
strip -o .gl/sweepdepth target/release/sweepdepth
mkdir -p .glz
tar -czf .glz/gl.tgz .gl
echo "gpu_prepare: carried (.glz) and the working tree (at most 64 MiB together):"
du -h .glz/gl.tgz
git ls-files -z | du -ch --files0-from=- | tail -n 1
