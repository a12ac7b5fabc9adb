#!/usr/bin/env bash
# The vendored crates are the published ones plus their recorded patches, nothing else:
# vendor/rustdds is RustDDS 0.15.1 + vendor/rustdds/upstream.patch, vendor/ros2-client is
# ros2-client 0.12.1 + vendor/ros2-client/upstream.patch (each folder's SWEEPDEPTH.md says why).
# For each: downloads the published crate (its sha256 recorded below), applies the patch, and
# compares the trees. Files the vendored copy adds (SWEEPDEPTH.md, upstream.patch) and the files
# the crate's own .gitignore keeps out of this repository (RustDDS's examples'
# logging-config.yaml) are the only differences allowed. Without network it says so and exits 0
# (a check that cannot run is not a failure of the code).
set -euo pipefail
cd "$(dirname "$0")/.."
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# check NAME VERSION SHA256 STRIP [ALLOWED-ONLY-IN-UPSTREAM-REGEX]
check() {
    local name=$1 version=$2 sha256=$3 strip=$4 ignored=${5:-'^$'}
    if ! curl -sSfL --max-time 60 -o "$work/$name.crate" \
        "https://static.crates.io/crates/$name/$name-$version.crate"; then
        echo "check_vendor: could not download $name $version from crates.io; not checked"
        return 0
    fi
    echo "$sha256  $work/$name.crate" | sha256sum -c --quiet -
    tar xzf "$work/$name.crate" -C "$work"
    local upstream="$work/$name-$version"
    (cd "$upstream" && patch "-p$strip" --quiet --no-backup-if-mismatch < "$OLDPWD/vendor/$name/upstream.patch")
    local differences
    differences=$(diff -rq "$upstream" "vendor/$name" \
        | grep -v -e "^Only in vendor/$name: SWEEPDEPTH.md$" \
            -e "^Only in vendor/$name: upstream.patch$" \
        | grep -v -E "$ignored" || true)
    if [ -n "$differences" ]; then
        echo "check_vendor: vendor/$name is not $name $version + upstream.patch:" >&2
        echo "$differences" >&2
        exit 1
    fi
    echo "check_vendor: vendor/$name = $name $version + upstream.patch"
}

check rustdds 0.15.1 42683a88b9dc025d7d45771b88d20846443b4901ec4b045ca78b8dd316ab616f 3 \
    "^Only in $work/rustdds-0.15.1/examples/[a-z_0-9]*: logging-config.yaml$"
check ros2-client 0.12.1 1fe08f96d441e37bffbfa487f3feebbdc5952ee6db2edc7861592913328f7031 1
