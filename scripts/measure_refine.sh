#!/usr/bin/env bash
# Measures pose refinement on every shipped tour and on turn-biased variants of the chair
# tour: fuses each with --no-refine-poses (odometry), with --no-floor (objects only), with the
# default refinement (objects and floor), and (simulated truth) with ground-truth poses
# refined (what refinement does to exact poses); prints one row per run:
# object errors, spurious objects, and the ATE of /odom and of the poses fused with.
# Usage: scripts/measure_refine.sh [SIGMA]   (from the repository root; SIGMA sets both
# --sigma-v and --sigma-w, default 0.01)
set -euo pipefail
cd "$(dirname "$0")/.."
sigma=${1:-0.01}
bin=target/release/objloc
[ -x "$bin" ] || cargo build --release
out=target/measure-refine
mkdir -p "$out"
"$bin" train recordings/chair-train.mcap -o "$out/chair.json" --save "$out/chair-train.rrd" >/dev/null
"$bin" train recordings/bottle-train.mcap -o "$out/bottle.json" --save "$out/bottle-train.rrd" >/dev/null
# The chair tour again with no random noise and a systematic turn error (and none), and a
# 200-stop chair tour at the default noise (does refinement stay put over a long session?).
for bias in 0 0.02 0.03 -0.03; do
  [ -f "$out/bias$bias.mcap" ] || "$bin" record sim --scene chair --kind tour --seed 2 \
    --speed-noise 0,0 --turn-bias "$bias" -o "$out/bias$bias.mcap" >/dev/null 2>&1
done
[ -f "$out/long200.mcap" ] || "$bin" record sim --scene chair --kind tour --seed 9 --stops 200 \
  -o "$out/long200.mcap" >/dev/null 2>&1
printf '%-22s %-10s %-14s %8s %-14s %9s %9s %8s\n' session poses refine spurious "errors (m)" "odom ATE" "ATE" "time ms"
for s in recordings/chair-tour recordings/two-chairs-tour recordings/bottle-tour recordings/chair-tour-drift \
         "$out/bias0" "$out/bias0.02" "$out/bias0.03" "$out/bias-0.03" "$out/long200"; do
  model="$out/chair.json"; [ "$(basename "$s")" = bottle-tour ] && model="$out/bottle.json"
  for run in "odometry no" "odometry objects" "odometry default" "ground-truth default"; do
    set -- $run
    case $2 in no) flag="--no-refine-poses";; objects) flag="--no-floor";; default) flag="";; esac
    rep="$out/$(basename "$s")-$1-$2.json"
    "$bin" fuse "$s.mcap" --model "$model" --poses "$1" $flag --sigma-v "$sigma" --sigma-w "$sigma" \
      --report "$rep" --save "${rep%.json}.rrd" >/dev/null
    "$bin" eval "$s.mcap" --report "$rep" --json | python3 -c '
import json, sys
e = json.load(sys.stdin)[0]
r = json.load(open(sys.argv[1]))
errs = ",".join("%.3f" % m["error_m"] for m in e["matches"]) or "-"
t = e["trajectory"] or {}
print("%-22s %-10s %-14s %8d %-14s %9.3f %9.3f %8.1f" % (sys.argv[2], sys.argv[3], sys.argv[4],
      len(e["spurious"]), errs, t.get("odometry_ate_m", float("nan")), t.get("fused_ate_m", float("nan")),
      r["timing_ms"]["replay"]))
' "$rep" "$(basename "$s")" "$1" "$2"
  done
done
