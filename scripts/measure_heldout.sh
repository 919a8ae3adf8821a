#!/usr/bin/env bash
# Held-out-style check of the whole pipeline on sessions the defaults were not tuned on:
# new tours (seeds 21 and 22) of the built-in scenes and of the scenes in scripts/heldout/
# (two-bottles: two identical bottles, on a table at 0.75 m and on a shelf at 1.25 m;
# chair-bare-floor: the chair room with a flat, untextured floor and no rug;
# chair-tiled-floor: a floor of 0.3 m stripes, the rug moved off-centre), at the default speed
# noise and at a realistic 5 %/3 %; train on the scene's training session (seed 11), fuse
# with the room as --bounds and otherwise default options (poses refined against objects and
# floor), with --no-floor (objects only) and with --no-refine-poses (the paper); prints
# the object errors, missed/spurious counts and the ATE of /odom and of the fused poses.
# Usage: [SCENES="chair ..."] scripts/measure_heldout.sh   (from the repository root; ~1.5 minutes once the sessions are recorded)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/objloc
[ -x "$bin" ] || cargo build --release
out=target/measure-heldout
mkdir -p "$out"
room=-3.5,-3.5,0,3.5,3.5,2.5
scene_args() { if [ -f "scripts/heldout/$1.json" ]; then echo --scene-file "scripts/heldout/$1.json"; else echo --scene "$1"; fi; }
printf '%-12s %-8s %-5s %-8s %-20s %8s %8s\n' scene noise seed refine "errors (m)" "odom ATE" ATE
for scene in ${SCENES:-chair bottle two-chairs two-bottles chair-bare-floor chair-tiled-floor}; do
  train="$out/$scene-train.mcap"
  [ -f "$train" ] || "$bin" record sim $(scene_args $scene) --kind train --seed 11 -o "$train" >/dev/null 2>&1
  "$bin" train "$train" -o "$out/$scene.json" --save "$out/$scene-train.rrd" >/dev/null
  for noise in default 0.05,0.03; do
    for seed in 21 22; do
      tour="$out/$scene-$noise-$seed.mcap"
      flags=""; [ "$noise" = default ] || flags="--speed-noise $noise"
      [ -f "$tour" ] || "$bin" record sim $(scene_args $scene) --kind tour --seed $seed $flags -o "$tour" >/dev/null 2>&1
      for refine in no objects default; do
        case $refine in no) r="--no-refine-poses";; objects) r="--no-floor";; default) r="";; esac
        rep="${tour%.mcap}-$refine.json"
        "$bin" fuse "$tour" --model "$out/$scene.json" --bounds=$room $r --report "$rep" --save "${rep%.json}.rrd" >/dev/null
        "$bin" eval "$tour" --report "$rep" --json | python3 -c '
import json, sys
e = json.load(sys.stdin)[0]
t = e["trajectory"] or {}
errs = ",".join("%.3f" % m["error_m"] for m in e["matches"]) or "-"
extra = "".join([" %d missed" % len(e["missed"]) if e["missed"] else "", " %d spurious" % len(e["spurious"]) if e["spurious"] else ""])
print("%-12s %-8s %-5s %-8s %-20s %8.3f %8.3f" % (sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], errs + extra, t.get("odometry_ate_m", 0), t.get("fused_ate_m", 0)))
' "$scene" "${noise/0.05,0.03/5%/3%}" "$seed" "$refine"
      done
    done
  done
done
