#!/usr/bin/env bash
# vendor/rustdds is RustDDS 0.15.1 as published on crates.io plus vendor/rustdds/upstream.patch,
# nothing else (vendor/rustdds/SWEEPDEPTH.md). This checks it: downloads the published crate
# (its sha256 recorded below), applies the patch, and compares the trees. Files the vendored
# copy adds (SWEEPDEPTH.md, upstream.patch) and the examples' logging-config.yaml (ignored by
# the crate's own .gitignore, so not in this repository) are the only differences allowed.
# Without network it says so and exits 0 (a check that cannot run is not a failure of the code).
set -euo pipefail
cd "$(dirname "$0")/.."
version=0.15.1
sha256=42683a88b9dc025d7d45771b88d20846443b4901ec4b045ca78b8dd316ab616f
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
if ! curl -sSfL --max-time 60 -o "$work/rustdds.crate" \
    "https://static.crates.io/crates/rustdds/rustdds-$version.crate"; then
    echo "check_vendor: could not download rustdds $version from crates.io; not checked"
    exit 0
fi
echo "$sha256  $work/rustdds.crate" | sha256sum -c --quiet -
tar xzf "$work/rustdds.crate" -C "$work"
upstream="$work/rustdds-$version"
(cd "$upstream" && patch -p3 --quiet --no-backup-if-mismatch < "$OLDPWD/vendor/rustdds/upstream.patch")
differences=$(diff -rq "$upstream" vendor/rustdds \
    | grep -v -e "^Only in vendor/rustdds: SWEEPDEPTH.md$" \
        -e "^Only in vendor/rustdds: upstream.patch$" \
        -e "^Only in $upstream/examples/[a-z_0-9]*: logging-config.yaml$" || true)
if [ -n "$differences" ]; then
    echo "check_vendor: vendor/rustdds is not rustdds $version + upstream.patch:" >&2
    echo "$differences" >&2
    exit 1
fi
echo "check_vendor: vendor/rustdds = rustdds $version + upstream.patch"
