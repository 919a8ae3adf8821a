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
Skips with a message when ../shared/realdata is absent (REALDATA_DIR overrides it; its
sessions then go to target/measure-realdata-<its directory name>-<hash of its path>).
TRAIN_FLAGS in the environment are passed to `objloc train`; OBJLOC_BIN names the binary
(default target/release/objloc); `--tag T` names the models and
reports `OBJECT-T.json` so that several settings can be measured side by side.

`--train-triples N [--seed S]`: how much the result depends on which three frames were
labelled for training: N seeded random triples of each object's labelled frames (their rows
of labels.csv) instead of train-labels.csv, one table row per triple and a summary per
object (a held-out capture's labeller picks frames of their own).

`--via-tum SCALE`: each session is first written as a held-out capture comes (image files
named by their stamps, a TUM trajectory of /odom, `--camera`/`--distortion` and a labels CSV;
scripts/sim_as_capture.py, which needs target/pyenv) with its images resampled to SCALE times
their size, and imported again with `record import --trajectory` (issue #18's graded path):
`--via-tum 1` checks that path gives the native importers' table, `--via-tum 0.5` a
downscaled copy. `--world-scale W` (implies `--via-tum 1` unless given): the trajectory's
positions multiplied by W, as a structure-from-motion model comes in units of its own; the
table must not change, but for the voxel size (times W). `--world-rotation RX,RY,RZ` (also
implies `--via-tum 1`): the world turned by these angles (degrees, about x, y, z), as a model
whose z is not up comes.
"""
import random
import argparse
import hashlib
import json
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# OBJLOC_BIN: measure another build (a copy, so that rebuilding this tree cannot change it
# halfway through a run).
BIN = os.environ.get("OBJLOC_BIN") or os.path.join(ROOT, "target", "release", "objloc")
PY = os.path.join(ROOT, "target", "pyenv", "bin", "python")
DATA = os.environ.get("REALDATA_DIR", os.path.join(ROOT, "..", "shared", "realdata"))
# Sessions are built once per output directory and reused, so another REALDATA_DIR gets its
# own (a perturbed copy measured into the unperturbed sessions would measure those).
OUT = os.path.join(ROOT, "target", "measure-realdata" + (
    "-" + os.path.basename(os.path.normpath(DATA)) + "-"
    + hashlib.sha256(os.path.realpath(DATA).encode()).hexdigest()[:8]
    if "REALDATA_DIR" in os.environ else ""))
LABELS = os.path.join(ROOT, "recordings", "realdata")
# --world-scale W: the graded path's trajectory in other units (every position times W);
# --world-rotation RX,RY,RZ: its world turned (degrees), as a model whose z is not up comes.
WORLD_SCALE = 1.0
WORLD_ROTATION = "0,0,0"


def world_tag():
    """The session and report names' suffix for a world in other units or turned."""
    return ((f"-w{WORLD_SCALE:g}" if WORLD_SCALE != 1.0 else "")
            + (f"-r{WORLD_ROTATION.replace(',', '_')}" if WORLD_ROTATION != "0,0,0" else ""))

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


def triple_session(capture, obj, images, tag):
    """A training session of `images` (their rows of labels.csv, every object's)."""
    d = os.path.join(OUT, capture)
    rows = open(os.path.join(LABELS, capture, "labels.csv")).read().splitlines()
    csv = os.path.join(d, f"train-{obj}-{tag}.csv")
    with open(csv, "w") as f:
        f.write("\n".join([rows[0]] + [r for r in rows[1:] if r.split(",")[0] in images]) + "\n")
    out = os.path.join(d, f"train-{obj}-{tag}.mcap")
    session(capture, csv, out)
    return out


def labelled_images(capture, obj):
    rows = open(os.path.join(LABELS, capture, "labels.csv")).read().splitlines()[1:]
    return sorted({r.split(",")[0] for r in rows
                   if r.split(",")[-1] == obj and int(r.split(",")[3]) > 0})


def via_tum(mcap, scale):
    """`mcap` written as a held-out capture comes (scripts/sim_as_capture.py: image files named
    by their stamps, a TUM trajectory, a labels CSV; images scaled by `scale`) and imported
    again with `record import --trajectory`: the graded path, in the world WORLD_SCALE and
    WORLD_ROTATION give. Returns the new session."""
    d = os.path.splitext(mcap)[0] + f"-tum{scale:g}" + world_tag()
    run([PY, os.path.join(ROOT, "scripts", "sim_as_capture.py"), mcap, d, "--scale", str(scale),
         "--world-scale", repr(WORLD_SCALE), "--world-rotation", WORLD_ROTATION])
    read = lambda f: open(os.path.join(d, f)).read().strip()
    lens = ["--distortion", read("distortion.txt")] if os.path.exists(
        os.path.join(d, "distortion.txt")) else []
    out = d + ".mcap"
    run([BIN, "record", "import", "--images", os.path.join(d, "images"), "--trajectory",
         os.path.join(d, "trajectory.txt"), "--camera", read("camera.txt"), *lens,
         "--labels", os.path.join(d, "labels.csv"), "-o", out])
    return out


def measure(capture, obj, fuse_flags, tag="", train_images=None, tum_scale=None):
    d = os.path.join(OUT, capture)
    os.makedirs(d, exist_ok=True)
    train = os.path.join(d, "train.mcap")
    tour = os.path.join(d, "tour.mcap")
    if not os.path.exists(tour):
        session(capture, os.path.join(LABELS, capture, "train-labels.csv"), train)
        session(capture, os.path.join(LABELS, capture, "labels.csv"), tour)
    if train_images is not None:
        train = triple_session(capture, obj, train_images, tag)
    if tum_scale is not None:
        train, tour = via_tum(train, tum_scale), via_tum(tour, tum_scale)
        via = f"tum{tum_scale:g}" + world_tag()
        tag = f"{tag}-{via}" if tag else via
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
        "train": " ".join(train_images) if train_images else "train-labels.csv",
        "capture": capture, "object": obj, "objects": len(rep["objects"]),
        "error": s.get("error_fraction"), "inside": (s["frames_inside"], s["frames"]) if s else None,
        "views": (s.get("triangulated") or {}).get("views"), "auc": auc,
        "voxel": rep["grid"]["voxel_size_m"], "fitted": len(rep.get("fitted", [])),
    }


def meets(r):
    fi, fn = r["inside"] or (0, 0)
    return bool(r["objects"] == 1 and r["error"] is not None and r["error"] <= 0.08
                and fn and fi / fn >= 0.95 and (r["auc"] or 0) >= 0.93)


def row(r):
    err = "n/a (never wholly in view)" if r["error"] is None else f"{100 * r['error']:.1f} %"
    fi, fn = r["inside"] or (0, 0)
    return (f"| {r['capture']} | {r['object']} | {r['objects']} | {err} | {fi} of {fn} | "
            f"{r['auc']:.3f} | {r['voxel']:.4g} | {'yes' if meets(r) else 'no'} |")


def triples(a):
    """One row per seeded random triple of labelled frames, then a summary per object."""
    rng = random.Random(a.seed)
    lines = ["| capture | object | training frames | objects found | centre error / size | "
             "in rectangle | tile AUC |", "|---|---|---|---|---|---|---|"]
    summary = ["| object | triples | exactly one object | error <= 8 % | inside >= 95 % | "
               "AUC >= 0.93 | all four | error (min / median / max) | AUC (min / median / max) |",
               "|---|---|---|---|---|---|---|---|---|"]
    for capture, (_, _, objs) in CAPTURES.items():
        for obj in objs:
            images = labelled_images(capture, obj)
            rs = []
            for k in range(a.train_triples):
                pick = sorted(rng.sample(images, 3))
                r = measure(capture, obj, a.fuse_flags, f"triple{a.seed}-{k}", pick, a.via_tum)
                rs.append(r)
                err = "n/a" if r["error"] is None else f"{100 * r['error']:.1f} %"
                fi, fn = r["inside"] or (0, 0)
                lines.append(f"| {capture} | {obj} | {r['train']} | {r['objects']} | {err} | "
                             f"{fi} of {fn} | {r['auc']:.3f} |")
            errs = sorted(r["error"] for r in rs if r["error"] is not None)
            aucs = sorted(r["auc"] for r in rs if r["auc"] is not None)
            spread = lambda v, f: (f"{f(v[0])} / {f(v[len(v) // 2])} / {f(v[-1])}" if v else "n/a")
            inside = [r for r in rs if r["inside"] and r["inside"][1]
                      and r["inside"][0] / r["inside"][1] >= 0.95]
            summary.append(
                f"| {obj} | {len(rs)} | {sum(r['objects'] == 1 for r in rs)} | "
                f"{sum(e <= 0.08 for e in errs)} | {len(inside)} | {sum(x >= 0.93 for x in aucs)} | "
                f"{sum(meets(r) for r in rs)} | {spread(errs, lambda e: f'{100 * e:.1f} %')} | "
                f"{spread(aucs, lambda x: f'{x:.3f}')} |")
    return "\n".join(lines + [""] + summary)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--markdown")
    ap.add_argument("--tag", default="")
    ap.add_argument("--train-triples", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--via-tum", type=float, metavar="SCALE")
    ap.add_argument("--world-scale", type=float, default=1.0, metavar="W")
    ap.add_argument("--world-rotation", default="0,0,0", metavar="RX,RY,RZ")
    ap.add_argument("fuse_flags", nargs="*")
    a = ap.parse_args()
    if a.via_tum is not None and not 0 < a.via_tum < float("inf"):
        ap.error(f"--via-tum {a.via_tum}: the scale must be a positive number")
    if not 0 < a.world_scale < float("inf"):
        ap.error(f"--world-scale {a.world_scale}: the scale must be a positive number")
    try:
        if len([float(v) for v in a.world_rotation.split(",")]) != 3:
            raise ValueError
    except ValueError:
        ap.error(f"--world-rotation {a.world_rotation}: three angles in degrees, RX,RY,RZ")
    global WORLD_SCALE, WORLD_ROTATION
    WORLD_SCALE, WORLD_ROTATION = a.world_scale, a.world_rotation
    if (WORLD_SCALE != 1.0 or WORLD_ROTATION != "0,0,0") and a.via_tum is None:
        a.via_tum = 1.0
    if not os.path.isdir(DATA):
        print(f"skipped: {DATA} is absent")
        return
    if not os.path.exists(BIN):
        subprocess.run(["cargo", "build", "--release"], cwd=ROOT, check=True)
    if a.train_triples:
        text = triples(a)
        print(text)
        if a.markdown:
            open(a.markdown, "w").write(text + "\n")
        return
    lines = ["| capture | object | objects found | centre error / size | in rectangle | "
             "tile AUC | voxel (units) | all targets |", "|---|---|---|---|---|---|---|---|"]
    for capture, (_, _, objs) in CAPTURES.items():
        for obj in objs:
            lines.append(row(measure(capture, obj, a.fuse_flags, a.tag, None, a.via_tum)))
    text = "\n".join(lines)
    print(text)
    if a.markdown:
        open(a.markdown, "w").write(text + "\n")


if __name__ == "__main__":
    main()
