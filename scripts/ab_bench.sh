#!/bin/sh
# Two builds of sweepdepth timed against each other in one sitting: `bench --json` of each,
# alternated ROUNDS times (A B A B ...), so that both see the same machine (a 2-core machine's
# speed drifts by 10 % within minutes). Prints, per configuration, each round's `wta` and `sgm`
# ms per set and the per-stage times of `sgm` (medians over the rounds), and B's medians as a
# share of A's. The SGBM peer's time beside each run shows how steady the machine was.
#
#   cp target/release/sweepdepth /tmp/sd-before     # the build before a change
#   cargo build --release                           # the change
#   sh scripts/ab_bench.sh /tmp/sd-before target/release/sweepdepth 3 \
#       --device cpu --config stereo-rect --config demo --repeats 7
#
# Timing only: nothing here asserts a speed (docs/tests.md: no test depends on the machine).
set -eu
if [ $# -lt 3 ]; then
    echo "usage: sh scripts/ab_bench.sh A_BINARY B_BINARY ROUNDS [bench options...]" >&2
    exit 2
fi
a=$1
b=$2
rounds=$3
shift 3
for bin in "$a" "$b"; do
    if [ ! -x "$bin" ]; then
        echo "ab_bench: $bin is not an executable sweepdepth" >&2
        exit 2
    fi
done
case $rounds in
'' | *[!0-9]*)
    echo "ab_bench: ROUNDS must be a whole number, not '$rounds'" >&2
    exit 2
    ;;
esac
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
i=1
while [ "$i" -le "$rounds" ]; do
    for side in A B; do
        if [ $side = A ]; then bin=$a; else bin=$b; fi
        echo "ab_bench: round $i of $rounds, $side ($bin)" >&2
        "$bin" bench --json "$@" 2>/dev/null >"$out/$side.$i.json" || {
            echo "ab_bench: $bin bench failed (its output: $out/$side.$i.json)" >&2
            trap - EXIT
            exit 1
        }
    done
    i=$((i + 1))
done
python3 - "$out" "$rounds" <<'EOF'
import json, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
runs = {"A": [], "B": []}
for side in runs:
    for i in range(1, rounds + 1):
        with open(f"{out}/{side}.{i}.json") as f:
            rows = [json.loads(line) for line in f if line.strip().startswith("{")]
        runs[side].append({r["config"]: r for r in rows if "config" in r and "sgm_ms" in r})
configs = [c for c in runs["A"][0] if all(c in r for side in runs for r in runs[side])]
if not configs:
    sys.exit("ab_bench: no configuration with timings in both builds' output")
med = statistics.median
for c in configs:
    print(f"{c}")
    sides = {}
    for side in ("A", "B"):
        rows = [r[c] for r in runs[side]]
        wta = [r["wta_ms"] for r in rows]
        sgm = [r["sgm_ms"] for r in rows]
        peer = [r.get("peer_ms", float("nan")) for r in rows]
        sides[side] = (med(wta), med(sgm))
        print(f"  {side}: wta {' / '.join(f'{v:.1f}' for v in wta)}  "
              f"sgm {' / '.join(f'{v:.1f}' for v in sgm)}  "
              f"(peer {' / '.join(f'{v:.1f}' for v in peer)} ms)")
        stages = {}
        for r in rows:
            for k, v in (r.get("sgm_stage_ms") or {}).items():
                stages.setdefault(k, []).append(v)
        if stages:
            print("     sgm stages (median): "
                  + ", ".join(f"{k} {med(v):.1f}" for k, v in sorted(stages.items())))
    (aw, asg), (bw, bsg) = sides["A"], sides["B"]
    print(f"  B / A: wta {bw / aw:.3f}, sgm {bsg / asg:.3f} (medians of {rounds})")
EOF
