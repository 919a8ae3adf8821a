#!/usr/bin/env bash
# The pipeline on ../shared/foreign (sessions of three rooms written by an independent renderer,
# see its README): trains each scene/seed on its own training session, fuses each tour with the
# manifest's room as --bounds and otherwise default options, with --no-floor and with
# --no-refine-poses, and prints per run: object errors against the manifest's centroids,
# missed/spurious counts, ATE of /odom and of the fused poses, and the refinement's frame
# outcomes. Usage: scripts/measure_foreign.sh [extra fuse flags...]   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${FOREIGN_DIR:-../shared/foreign/sessions}
[ -d "$dir" ] || { echo "no $dir: the foreign sessions are not on this machine" >&2; exit 1; }
bin=target/release/objloc
[ -x "$bin" ] || cargo build --release
out=target/measure-foreign
mkdir -p "$out"
extra=("$@")
printf '%-28s %-8s %-22s %8s %8s %s\n' tour refine "errors (m)" "odom ATE" ATE frames
for train in "$dir"/*-train-s*.mcap; do
  base=$(basename "$train" .mcap)
  model="$out/$base.json"
  "$bin" train "$train" -o "$model" --no-rerun >/dev/null
  scene=${base%-train-s*}; seed=${base##*-s}
  for tour in "$dir/$scene-tour-s$seed.mcap" "$dir/$scene-tour-s$seed-n0.2.mcap"; do
    name=$(basename "$tour" .mcap)
    bounds=$(python3 -c 'import json,sys; m=json.load(open(sys.argv[1]))
e=[s for s in m["sessions"] if s["file"]==sys.argv[2]][0]["room_bounds"]
print(",".join(str(v) for v in e["min"]+e["max"]))' "$dir/manifest.json" "$name.mcap")
    for refine in default objects no; do
      case $refine in no) r="--no-refine-poses";; objects) r="--no-floor";; default) r="";; esac
      rep="$out/$name-$refine.json"
      "$bin" fuse "$tour" --model "$model" --bounds="$bounds" $r ${extra[@]+"${extra[@]}"} --report "$rep" --no-rerun >/dev/null
      "$bin" eval "$tour" --report "$rep" --json | python3 scripts/foreign_row.py "$dir/manifest.json" "$name" "$refine" "$rep"
    done
  done
done
