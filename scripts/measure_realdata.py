#!/usr/bin/env python3
"""Builds sessions from the real captures in ../shared/realdata with the committed labels
(recordings/realdata/*/labels.csv, train-labels.csv), trains one model per object on the
three training frames, fuses the full capture with default options, and scores it without
3D ground truth: `objloc eval` (centre triangulated from the label rectangles, error as a
fraction of the object's size, frames whose rectangle holds the located centre) and
`objloc predict` (tile ROC AUC of the fuser's evidence). Prints one markdown table.

The targets (issue #18): exactly one object per model, centre within 8 % of the object's
size, inside the rectangle in >= 95 % of the frames, tile AUC >= 0.93.

Usage: scripts/measure_realdata.py [--markdown OUT.md] [-- extra fuse flags...]
       (from the repository root; stdlib only; calls target/release/objloc)
Skips with a message when ../shared/realdata is absent (REALDATA_DIR overrides it).
TRAIN_FLAGS in the environment are passed to `objloc train`; `--tag T` names the models and
reports `OBJECT-T.json` so that several settings can be measured side by side.
"""
import argparse
import json
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "objloc")
OUT = os.path.join(ROOT, "target", "measure-realdata")
DATA = os.environ.get("REALDATA_DIR", os.path.join(ROOT, "..", "shared", "realdata"))
LABELS = os.path.join(ROOT, "recordings", "realdata")

# capture -> (import flags, default object name, objects to model)
CAPTURES = {
    "fruit": (["--nerf", "{d}/fruit/transforms.json"], "object", ["apple", "banana"]),
    "milk": (["--llff", "{d}/milk/poses_bounds.npy", "--images", "{d}/milk/images"],
             "milk", ["milk"]),
    "dtu-scan24": (["--idr", "{d}/dtu-scan24/cameras.npz", "--images", "{d}/dtu-scan24",
                    "--crop", "200,0,1200,1200"], "house", ["house"]),
}


def run(args):
    p = subprocess.run(args, cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"failed: {' '.join(args)}\n{p.stderr.strip()}")
    return p.stdout


def session(capture, labels, out):
    flags, obj, _ = CAPTURES[capture]
    flags = [f.format(d=DATA) for f in flags]
    run([BIN, "record", "import", *flags, "--labels", labels, "--object", obj, "-o", out])


def measure(capture, obj, fuse_flags, tag=""):
    d = os.path.join(OUT, capture)
    os.makedirs(d, exist_ok=True)
    train = os.path.join(d, "train.mcap")
    tour = os.path.join(d, "tour.mcap")
    if not os.path.exists(tour):
        session(capture, os.path.join(LABELS, capture, "train-labels.csv"), train)
        session(capture, os.path.join(LABELS, capture, "labels.csv"), tour)
    name = f"{obj}-{tag}" if tag else obj
    model = os.path.join(d, f"{name}.json")
    report = os.path.join(d, f"{name}.report.json")
    run([BIN, "train", train, "--object", obj, "-o", model, "--no-rerun",
         *os.environ.get("TRAIN_FLAGS", "").split()])
    run([BIN, "fuse", tour, "--model", model, "--report", report, "--no-rerun", *fuse_flags])
    pred = run([BIN, "predict", tour, "--model", model, "--object", obj,
                "--out", os.path.join(d, f"{name}-predict"), "--no-rerun"])
    # The tile head's line; a model without a region head prints only that one.
    m = (re.search(r"tile head .*?tile ROC AUC ([0-9.]+)", pred)
         or re.search(r"tile ROC AUC ([0-9.]+)", pred))
    auc = float(m.group(1)) if m else None
    ev = json.loads(run([BIN, "eval", tour, "--report", report, "--object", obj, "--json"]))
    s = ev[0]["score"] if ev else {}
    rep = json.load(open(report))
    return {
        "capture": capture, "object": obj, "objects": len(rep["objects"]),
        "error": s.get("error_fraction"), "inside": (s["frames_inside"], s["frames"]) if s else None,
        "views": (s.get("triangulated") or {}).get("views"), "auc": auc,
        "voxel": rep["grid"]["voxel_size_m"], "fitted": len(rep.get("fitted", [])),
    }


def row(r):
    err = "n/a (never wholly in view)" if r["error"] is None else f"{100 * r['error']:.1f} %"
    fi, fn = r["inside"] or (0, 0)
    ok = (r["objects"] == 1 and r["error"] is not None and r["error"] <= 0.08
          and fn and fi / fn >= 0.95 and (r["auc"] or 0) >= 0.93)
    return (f"| {r['capture']} | {r['object']} | {r['objects']} | {err} | {fi} of {fn} | "
            f"{r['auc']:.3f} | {r['voxel']:.4g} | {'yes' if ok else 'no'} |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--markdown")
    ap.add_argument("--tag", default="")
    ap.add_argument("fuse_flags", nargs="*")
    a = ap.parse_args()
    if not os.path.isdir(DATA):
        print(f"skipped: {DATA} is absent")
        return
    if not os.path.exists(BIN):
        subprocess.run(["cargo", "build", "--release"], cwd=ROOT, check=True)
    lines = ["| capture | object | objects found | centre error / size | in rectangle | "
             "tile AUC | voxel (units) | all targets |", "|---|---|---|---|---|---|---|---|"]
    for capture, (_, _, objs) in CAPTURES.items():
        for obj in objs:
            lines.append(row(measure(capture, obj, a.fuse_flags, a.tag)))
    text = "\n".join(lines)
    print(text)
    if a.markdown:
        open(a.markdown, "w").write(text + "\n")


if __name__ == "__main__":
    main()
