#!/usr/bin/env bash
# What streaming to Rerun costs a replay of each real capture: `objloc fuse` with the
# recording saved (`-q --save`) against `--no-rerun`, replay time as fuse prints it, for one
# or two builds alternated (docs/scale.md, "Cheaper snapshots").
#
# Usage (from the repository root, after scripts/measure_realdata.py has built the sessions
# and models in target/measure-realdata/):
#   scripts/measure_stream.sh [RUNS] [BIN...]     # default: 2 runs of target/release/objloc
#   scripts/measure_stream.sh 2 old/objloc target/release/objloc
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-2}
shift || true
bins=("$@")
[ ${#bins[@]} -gt 0 ] || bins=(target/release/objloc)
R=target/measure-realdata
if [ ! -d "$R" ]; then
    echo "no $R: run scripts/measure_realdata.py first" >&2
    exit 1
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
replay_ms() { grep -o "replay [0-9.]*" | cut -d' ' -f2; }
for pair in "fruit apple" "fruit banana" "milk milk" "dtu-scan24 house"; do
    set -- $pair
    for _ in $(seq "$runs"); do
        for b in "${bins[@]}"; do
            with=$("$b" fuse "$R/$1/tour.mcap" --model "$R/$1/$2.json" -q --save "$tmp/r.rrd" \
                --report "$tmp/r1.json" | replay_ms)
            without=$("$b" fuse "$R/$1/tour.mcap" --model "$R/$1/$2.json" -q --no-rerun \
                --report "$tmp/r0.json" | replay_ms)
            echo "$2 $b: Rerun $with ms, none $without ms," \
                "$(python3 -c "print(f'{$with / $without:.2f}x')"), .rrd $(($(stat -c %s "$tmp/r.rrd") / 1000000)) MB"
        done
    done
done
