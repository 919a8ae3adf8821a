#!/usr/bin/env bash
# Tile ROC AUC of `objloc predict` (probs.npy: the region head) on the shipped tours and on
# the held-out-style tours of scripts/measure_heldout.sh (run that first: it records them
# into target/measure-heldout), each trained on its scene's training session with default
# options, or with the train options given as arguments (e.g. `--no-region` for the tile
# head alone, as the fuser sees it). Prints one line per scene: the AUC of each tour.
# Usage: scripts/measure_tile_auc.sh [TRAIN OPTIONS...]   (from the repository root, ~1 minute)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/objloc
[ -x "$bin" ] || cargo build --release
heldout=target/measure-heldout
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
auc() { "$bin" predict "$1" --model "$2" --out "$out/p" --no-rerun | tail -1 | sed -n 's/.*tile ROC AUC \([0-9.]*\).*/\1/p'; }
for train in chair bottle; do
  "$bin" train "recordings/$train-train.mcap" -o "$out/$train.json" --no-rerun "$@" >/dev/null
done
for tour in chair-tour two-chairs-tour chair-tour-drift bottle-tour; do
  model="$out/chair.json"; [ "$tour" = bottle-tour ] && model="$out/bottle.json"
  echo "$tour $(auc "recordings/$tour.mcap" "$model")"
done
for scene in chair bottle two-chairs two-bottles chair-bare-floor chair-tiled-floor; do
  [ -f "$heldout/$scene-train.mcap" ] || { echo "$scene: no $heldout/$scene-train.mcap (run scripts/measure_heldout.sh)"; continue; }
  "$bin" train "$heldout/$scene-train.mcap" -o "$out/$scene.json" --no-rerun "$@" >/dev/null
  line="$scene"
  for noise in default 0.05,0.03; do
    for seed in 21 22; do
      line="$line $(auc "$heldout/$scene-$noise-$seed.mcap" "$out/$scene.json")"
    done
  done
  echo "$line"
done
