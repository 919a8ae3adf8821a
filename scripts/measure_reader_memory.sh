#!/usr/bin/env bash
# Peak memory (RSS) of `objloc inspect`, `objloc inspect --quick` and `objloc fuse` against the
# size of the session file: generates chair tours of about 100 MB, 500 MB, 1 GB and 2 GB under
# target/measure-scale/ (kept and reused: the simulator is byte-identical for a seed), trains
# the chair model once, and prints one markdown table row per (file, command) with
# `/usr/bin/time -f %M`'s peak resident set size.
# Usage: scripts/measure_reader_memory.sh [BINARY [LABEL]]   (from the repository root)
#   BINARY defaults to target/release/objloc; LABEL (default "after") names the result file
#   target/measure-scale/rss-LABEL.tsv. STOPS="1000 5000" limits the sizes measured.
#   A binary without `inspect --quick` (an older objloc) gets "-" in that column.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/release/objloc}
label=${2:-after}
[ -x "$bin" ] || cargo build --release
out=target/measure-scale
mkdir -p "$out"
stops=${STOPS:-"1000 5000 10000 20000"}
tsv="$out/rss-$label.tsv"
: >"$tsv"

# The sessions and the model come from the current binary's simulator, so every binary
# measured reads the same bytes.
gen=target/release/objloc
[ -x "$gen" ] || gen=$bin
model="$out/chair.json"
[ -f "$model" ] || "$gen" train recordings/chair-train.mcap -o "$model" -q --no-rerun >/dev/null

# Peak RSS of a command in MB (the command's own output is discarded; a failure is fatal).
peak_mb() {
  local log="$out/time.log"
  if ! /usr/bin/time -f %M -o "$log" "$@" >/dev/null 2>"$out/stderr.log"; then
    echo "failed: $* ($(tail -n 3 "$out/stderr.log"))" >&2
    return 1
  fi
  awk '{ printf "%.0f", $1 / 1024 }' "$log"
}

printf '| file | size (MB) | messages | inspect (MB) | inspect --quick (MB) | fuse --no-refine-poses (MB) | fuse wall (s) |\n'
printf '|---|---:|---:|---:|---:|---:|---:|\n'
for n in $stops; do
  f="$out/chair-tour-$n.mcap"
  if [ ! -f "$f" ]; then
    "$gen" record sim --scene chair --kind tour --seed 9 --stops "$n" -o "$f.tmp" >/dev/null
    mv "$f.tmp" "$f"
  fi
  size_mb=$(awk -v b="$(stat -c %s "$f")" 'BEGIN { printf "%.0f", b / 1e6 }')
  msgs=$("$gen" inspect --quick --json "$f" 2>/dev/null | python3 -c 'import json,sys; print(json.load(sys.stdin)["messages"])' 2>/dev/null || echo "?")
  full=$(peak_mb "$bin" inspect "$f")
  # (Not `| grep -q`: with pipefail, grep quitting early fails the pipeline.)
  if [[ "$("$bin" inspect --help)" == *--quick* ]]; then
    quick=$(peak_mb "$bin" inspect --quick "$f")
  else
    quick=-
  fi
  start=$(date +%s)
  fuse=$(peak_mb "$bin" fuse "$f" --model "$model" --no-rerun -q --no-refine-poses \
    --report "$out/report-$n.json")
  wall=$(($(date +%s) - start))
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$n" "$size_mb" "$msgs" "$full" "$quick" "$fuse" "$wall" >>"$tsv"
  printf '| chair tour, %s stops | %s | %s | %s | %s | %s | %s |\n' "$n" "$size_mb" "$msgs" "$full" "$quick" "$fuse" "$wall"
done
