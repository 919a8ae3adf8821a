#!/usr/bin/env python3
"""Two measurements of the tile head on the real captures that the rectangle AUC of
scripts/measure_realdata.py cannot make (run that script first, with the same --tag: this one
reads its models, sessions and `predict` outputs in target/measure-realdata):

1. Unseen backgrounds (--cross): each object's model classifies every frame of the *other*
   captures (a milk carton on white, a brick house on a table, fruit on a mattress: colours
   and textures its three training frames never showed, all negative). Printed: the AUC of
   its own tour's positive tiles against its own negatives plus those tiles, and the share of
   the other captures' tiles at or above the median positive's probability (how much of an
   unseen room would light up; issue #18's capture B fired on a sofa, a hallway and glare).
2. The label ceiling (--ceiling, the milk capture, the only one with masks): the tile AUC
   against the rectangles of a perfect pixel detector (each tile scored by its fraction of
   carton pixels), and the tile head's AUC against the masks (a tile is the carton when at
   least half its pixels are), i.e. how well it finds the object's pixels.

Usage: scripts/realdata_specificity.py [--tag T] [--cross] [--ceiling]
Needs numpy (target/pyenv has it) and, for --ceiling, pillow.
"""
import argparse
import os
import subprocess

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "objloc")
OUT = os.path.join(ROOT, "target", "measure-realdata")
DATA = os.environ.get("REALDATA_DIR", os.path.join(ROOT, "..", "shared", "realdata"))
OBJECTS = {"apple": "fruit", "banana": "fruit", "milk": "milk", "house": "dtu-scan24"}


def auc(pos, neg):
    """ROC AUC by ranks, ties counted half."""
    x = np.concatenate([pos, neg])
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x))
    xs = x[order]
    # Average rank over runs of equal values.
    starts = np.r_[0, np.nonzero(np.diff(xs))[0] + 1]
    ends = np.r_[starts[1:], len(xs)]
    avg = (starts + ends - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, ends - starts)
    n1, n0 = len(pos), len(neg)
    return (ranks[:n1].sum() - n1 * (n1 + 1) / 2.0) / (n1 * n0)


def name(obj, tag):
    return f"{obj}-{tag}" if tag else obj


def cross(tag):
    for obj, cap in OBJECTS.items():
        d = os.path.join(OUT, cap)
        pred = os.path.join(d, name(obj, tag) + "-predict")
        p = np.load(os.path.join(pred, "tile_probs.npy")).ravel()
        y = np.load(os.path.join(pred, "labels.npy")).ravel()
        pos, neg = p[y == 1], p[y == 0]
        other = []
        for c in sorted(set(OBJECTS.values()) - {cap}):
            o = os.path.join(OUT, c, f"{name(obj, tag)}-on-{c}")
            subprocess.run([BIN, "predict", os.path.join(OUT, c, "tour.mcap"), "--model",
                            os.path.join(d, name(obj, tag) + ".json"), "--out", o, "--no-rerun",
                            "-q"], check=True, capture_output=True)
            other.append(np.load(os.path.join(o, "tile_probs.npy")).ravel())
        other = np.concatenate(other)
        print(f"{obj}: AUC with the other captures' tiles as negatives "
              f"{auc(pos, np.concatenate([neg, other])):.3f} (own negatives only {auc(pos, neg):.3f}); "
              f"other captures' tiles >= the median positive: {100 * np.mean(other >= np.median(pos)):.1f} %")


def ceiling(tag):
    from PIL import Image
    pred = os.path.join(OUT, "milk", name("milk", tag) + "-predict")
    p = np.load(os.path.join(pred, "tile_probs.npy"))
    y = np.load(os.path.join(pred, "labels.npy"))
    t = 8
    frac = []
    for k in range(p.shape[0]):
        # Frames are in the session's order: 1.jpg .. 43.jpg (numbers as numbers).
        m = Image.open(os.path.join(DATA, "milk", "images_mask", f"{k + 1}-removebg-preview.png"))
        w, h = Image.open(os.path.join(DATA, "milk", "images", f"{k + 1}.jpg")).size
        a = np.asarray(m.convert("RGBA").resize((w, h), Image.BILINEAR))[..., 3] > 128
        r, c = p.shape[1], p.shape[2]
        frac.append(a[: r * t, : c * t].reshape(r, t, c, t).mean((1, 3)))
    frac, p, y = np.array(frac).ravel(), p.ravel(), y.ravel()
    print(f"milk: tile head against the rectangles {auc(p[y == 1], p[y == 0]):.3f}; "
          f"a perfect pixel detector (fraction of carton pixels) {auc(frac[y == 1], frac[y == 0]):.3f}; "
          f"{100 * np.mean(frac[y == 1] < 0.5):.0f} % of the positive tiles are mostly background")
    obj = frac >= 0.5
    print(f"milk: tile head against the masks (tile >= half carton) {auc(p[obj], p[~obj]):.3f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tag", default="")
    ap.add_argument("--cross", action="store_true")
    ap.add_argument("--ceiling", action="store_true")
    a = ap.parse_args()
    if a.cross:
        cross(a.tag)
    if a.ceiling:
        ceiling(a.tag)


if __name__ == "__main__":
    main()
