#!/usr/bin/env bash
# Measures the paper's fuser (`--no-refine-poses`: every frame at its /odom pose) on every
# shipped tour: trains the chair and bottle models, fuses each tour with each motion-blur mode
# (and with ground-truth poses, to separate odometry error from classifier error), scores with
# `objloc eval --json` and prints one table row per run. (Refined replays skip the blur of a
# localised frame, so the blur modes are compared without refinement.)
# Usage: scripts/measure_fuser.sh [extra fuse flags...]   (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/objloc
extra=("$@")
[ -x "$bin" ] || cargo build --release
out=target/measure
mkdir -p "$out"
"$bin" train recordings/chair-train.mcap -o "$out/chair.json" --save "$out/chair-train.rrd" >/dev/null
"$bin" train recordings/bottle-train.mcap -o "$out/bottle.json" --save "$out/bottle-train.rrd" >/dev/null
printf '%-17s %-12s %-9s %7s %6s %8s %-18s %6s %8s\n' tour blur poses objects missed spurious "errors (m)" IoU "time ms"
for tour in chair-tour two-chairs-tour bottle-tour chair-tour-drift; do
  model="$out/chair.json"; [ "$tour" = bottle-tour ] && model="$out/bottle.json"
  for run in "log-odds odometry" "probability odometry" "observation odometry" "log-odds ground-truth"; do
    set -- $run
    rep="$out/$tour-$1-$2.json"
    "$bin" fuse "recordings/$tour.mcap" --model "$model" --blur "$1" --poses "$2" --no-refine-poses ${extra[@]+"${extra[@]}"} \
      --report "$rep" --save "$out/$tour-$1-$2.rrd" >/dev/null
    "$bin" eval "recordings/$tour.mcap" --report "$rep" --json | python3 -c '
import json, sys
e = json.load(sys.stdin)[0]
r = json.load(open(sys.argv[1]))
errs = ",".join("%.3f" % m["error_m"] for m in e["matches"]) or "-"
print("%-17s %-12s %-9s %7d %6d %8d %-18s %6.3f %8.1f" % (sys.argv[2], sys.argv[3], sys.argv[4],
      len(r["objects"]), len(e["missed"]), len(e["spurious"]), errs, e["voxel_iou"], r["timing_ms"]["replay"]))
' "$rep" "$tour" "$1" "$2"
  done
done
