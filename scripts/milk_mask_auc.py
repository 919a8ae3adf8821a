#!/usr/bin/env python3
"""How much of the milk carton's tile AUC the rectangles cost: scores the tile head's
probabilities (`objloc predict` output: tile_probs.npy, labels.npy) against the capture's own
masks (../shared/realdata/milk/images_mask) as well as against the label rectangles.

Usage (from the repository root, after scripts/measure_realdata.py has built the session and
model; needs NumPy and Pillow, e.g. the venv at target/pyenv):
  target/release/objloc predict target/measure-realdata/milk/tour.mcap \\
      --model target/measure-realdata/milk/milk.json --out /tmp/milk-predict --no-rerun
  target/pyenv/bin/python scripts/milk_mask_auc.py /tmp/milk-predict
Prints the share of rectangle-positive tiles the mask calls background and both AUCs.
"""
import os
import sys

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MASKS = os.environ.get("MILK_MASKS", os.path.join(ROOT, "..", "shared", "realdata", "milk",
                                                  "images_mask"))
IMAGE_SIZE = (1140, 855)  # the JPEGs' size; the masks are 577 x 433 and are scaled to it


def auc(score, positive):
    """ROC AUC with average ranks for ties (Mann-Whitney)."""
    order = np.argsort(score, kind="mergesort")
    _, first, counts = np.unique(score[order], return_index=True, return_counts=True)
    ranks = np.empty(len(score))
    ranks[order] = np.repeat(first + (counts + 1) / 2.0, counts)
    npos = positive.sum()
    return (ranks[positive].sum() - npos * (npos + 1) / 2) / (npos * (len(score) - npos))


def main():
    d = sys.argv[1]
    p = np.load(os.path.join(d, "tile_probs.npy")).astype(float)
    y = np.load(os.path.join(d, "labels.npy"))
    frames, rows, cols = p.shape
    tile = IMAGE_SIZE[0] // cols
    cover = np.zeros_like(p)
    for f in range(frames):  # frames are 1.jpg ... 43.jpg in natural order
        m = Image.open(os.path.join(MASKS, f"{f + 1}-removebg-preview.png")).convert("RGBA")
        alpha = np.asarray(m.resize(IMAGE_SIZE, Image.BILINEAR))[..., 3] > 127
        a = alpha[: rows * tile, : cols * tile].astype(float)
        cover[f] = a.reshape(rows, tile, cols, tile).mean(axis=(1, 3))
    labelled = y >= 0
    in_rect = y == 1
    on_carton = cover >= 0.5
    print(f"rectangle-positive tiles the mask calls background: {(~on_carton[in_rect]).mean():.3f}")
    print(f"tile AUC against the rectangles: {auc(p[labelled], in_rect[labelled]):.4f}")
    print(f"tile AUC against the masks (tile at least half carton): "
          f"{auc(p[labelled], on_carton[labelled]):.4f}")


if __name__ == "__main__":
    main()
