#!/usr/bin/env python3
"""Robot sessions with 3D truth taken through a capture's path: each training and tour
session written as a capture comes (scripts/sim_as_capture.py: image files, a TUM trajectory
of the true camera poses, a labels CSV), imported with `objloc record import --trajectory`
(so without /cmd_vel), trained and fused with a capture's defaults, and scored against the
true centres by `objloc eval` of the original session (docs/realdata.md, "A simulated capture"). Prints per set and configuration how
many tours have the right count with every object within 0.12 m, and the mean error.

Sets: wide (our simulator's six held-out-style scenes, tour seeds 1-8: recorded by
`scripts/measure_sessions.py --sets wide` first), mounts (a chair seen from a pan-tilt head,
its mount chained through /tf, and through a barrel lens: scripts/heldout/chair-pan-tilt.json
and chair-distorted.json, tour seeds 1-8, recorded here), arcs (the chair and the bin on a
shelf, scripts/heldout/bin-on-shelf.json, with the tour's 8 stops on an arc of 45 or 90
degrees instead of the whole circle, as a phone photographs an object on a shelf or against a
wall from the front only; tour seeds 1-4, recorded here), video (the same two scenes, 40
stops 3 degrees apart on a 120-degree arc, as frames taken from a video; tour seeds 1-2),
distractor (the bin's room with its sofa painted nearly the bin's blue; tour seeds 1-4) and
foreign (../shared/foreign:
another renderer's rooms; skipped with a message where absent).

Usage: scripts/measure_sim_captures.py [--sets wide,mounts,foreign] [--configs default,rgb332]
       [--perturb] [-- extra fuse flags...]     (from the repository root; needs target/pyenv, which the
       tests create; OBJLOC_BIN names another binary)
--perturb: every capture's frames perturbed in exposure, white balance and motion blur as
scripts/perturb_realdata.py does the real captures' (sessions in
target/measure-sim-captures-perturbed).
Configurations: default (the capture's training defaults), rgb332 (`train --features rgb332
--augment none`), extent (default training, `fuse --locate extent`), tree (`train --trees 1`:
the paper's single tree instead of a capture's forest), three (trained on each tour's own
capture with three of its frames labelled, as a real capture is: `train`'s second round labels
the others by the object its replay locates) and three-labelled (the same with
`--no-more-views`: the three frames alone).
"""
import argparse
import concurrent.futures as cf
import json
import math
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("OBJLOC_BIN") or os.path.join(ROOT, "target", "release", "objloc")
PY = os.path.join(ROOT, "target", "pyenv", "bin", "python")
OUT = os.path.join(ROOT, "target", "measure-sim-captures")
# Each capture's frames perturbed as scripts/perturb_realdata.py perturbs the real captures'
# (exposure, white balance, motion blur), seeded by the session's name.
PERTURB = """
import glob, os, sys, zlib
import numpy as np
sys.path.insert(0, sys.argv[1])
from perturb_realdata import pert
rng = np.random.default_rng(zlib.crc32(sys.argv[3].encode()))
for f in sorted(glob.glob(os.path.join(sys.argv[2], '*'))):
    pert(f, f, rng)
"""
HELDOUT = os.path.join(ROOT, "target", "measure-heldout")
FOREIGN = os.environ.get("FOREIGN_DIR", os.path.join(ROOT, "..", "shared", "foreign", "sessions"))
SCENES = ["chair", "bottle", "two-chairs", "two-bottles", "chair-bare-floor", "chair-tiled-floor"]
CONFIGS = {"default": ([], []), "rgb332": (["--features", "rgb332", "--augment", "none"], []),
           "extent": ([], ["--locate", "extent"]),
           "tree": (["--trees", "1"], []),
           # Trained on the tour itself with three of its frames labelled (as a real capture
           # is), then fused: with train's second round on the other frames, and without.
           "three": ([], []), "three-labelled": (["--no-more-views"], [])}
TARGET_M = 0.12


def run(args):
    p = subprocess.run(args, cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {p.stderr.strip()}")
    return p.stdout


PERTURBED = False


def as_capture(session):
    """The session imported as a capture (cached), and its true centres."""
    name = os.path.basename(session)[:-5]
    d = os.path.join(OUT, name)
    mcap = d + ".mcap"
    if not os.path.exists(mcap):
        run([PY, os.path.join(ROOT, "scripts", "sim_as_capture.py"), session, d])
        if PERTURBED:
            run([PY, "-c", PERTURB, os.path.join(ROOT, "scripts"), os.path.join(d, "images"), name])
        cam = open(os.path.join(d, "camera.txt")).read().strip()
        dist = os.path.join(d, "distortion.txt")
        lens = ["--distortion", open(dist).read().strip()] if os.path.exists(dist) else []
        run([BIN, "record", "import", "--images", os.path.join(d, "images"), "--trajectory",
             os.path.join(d, "trajectory.txt"), "--camera", cam, *lens, "--labels",
             os.path.join(d, "labels.csv"), "-q", "-o", mcap])
    truth = [c for cs in json.load(open(os.path.join(d, "truth.json"))).values() for c in cs]
    return mcap, truth


def pairs():
    """(set, training session, tour sessions) of each scene."""
    out = []
    if os.path.exists(os.path.join(HELDOUT, "chair-wide-1.mcap")):
        for s in SCENES:
            out.append(("wide", os.path.join(HELDOUT, s + "-train.mcap"),
                        [os.path.join(HELDOUT, f"{s}-wide-{k}.mcap") for k in range(1, 9)]))
    else:
        print("wide: skipped, run scripts/measure_sessions.py --sets wide first")
    # A pan-tilt head (the mount chained through /tf) and a barrel lens (`--distortion`).
    rec = os.path.join(OUT, "recorded")
    os.makedirs(rec, exist_ok=True)
    for scene in ["chair-pan-tilt", "chair-distorted"]:
        f = os.path.join(ROOT, "scripts", "heldout", scene + ".json")
        sessions = []
        for kind, seed in [("train", 11)] + [("tour", k) for k in range(1, 9)]:
            path = os.path.join(rec, f"{scene}-{kind}-{seed}.mcap")
            if not os.path.exists(path):
                run([BIN, "record", "sim", "--scene-file", f, "--kind", kind, "--seed", str(seed),
                     "-q", "-o", path])
            sessions.append(path)
        out.append(("mounts", sessions[0], sessions[1:]))
    # Narrow arcs: the tour's 8 stops span 45 or 90 degrees instead of the whole circle, as
    # a phone photographs an object on a shelf or against a wall from the front only; and
    # video: 40 frames 3 degrees apart on a 120-degree arc, as frames taken from a video.
    chair = os.path.join(ROOT, "crates", "core", "src", "sim", "scenes", "chair.json")
    shelf = os.path.join(ROOT, "scripts", "heldout", "bin-on-shelf.json")
    # Distractor: the bin's room with its sofa painted nearly the bin's blue (as the issue's
    # capture B has a blue-grey sofa the classifier fired on), the whole circle.
    for set_name, base, arc, stops, seeds in (
            [("arcs", b, a, 8, range(1, 5)) for b in (chair, shelf) for a in (45, 90)]
            + [("video", b, 120, 40, range(1, 3)) for b in (chair, shelf)]
            + [("distractor", shelf, 360, 8, range(1, 5))]):
        scene = json.load(open(base))
        if set_name == "distractor":
            scene["name"] += "-blue-sofa"
            for prim in scene["primitives"]:
                if prim.get("group") == "sofa":
                    prim["material"]["color"] = [0.2, 0.32, 0.68]
        else:
            scene["name"] = f"{scene['name']}-arc{arc}"
            scene["path"]["tour_arc_deg"] = float(arc)
        f = os.path.join(rec, scene["name"] + ".json")
        json.dump(scene, open(f, "w"), indent=1)
        sessions = []
        for kind, seed in [("train", 11)] + [("tour", k) for k in seeds]:
            suffix = f"-{stops}stops" if kind == "tour" and stops != 8 else ""
            path = os.path.join(rec, f"{scene['name']}-{kind}-{seed}{suffix}.mcap")
            if not os.path.exists(path):
                run([BIN, "record", "sim", "--scene-file", f, "--kind", kind, "--seed", str(seed),
                     "--stops", str(stops), "-q", "-o", path])
            sessions.append(path)
        out.append((set_name, sessions[0], sessions[1:]))
    if os.path.isdir(FOREIGN):
        m = json.load(open(os.path.join(FOREIGN, "manifest.json")))
        for t in sorted(s["file"] for s in m["sessions"] if s["kind"] == "train"):
            scene_seed = t.replace("-train", "-tour")[:-5]
            tours = sorted(s["file"] for s in m["sessions"]
                           if s["kind"] == "tour" and s["file"].startswith(scene_seed))
            out.append(("foreign", os.path.join(FOREIGN, t), [os.path.join(FOREIGN, f) for f in tours]))
    else:
        print(f"foreign: skipped, no {FOREIGN}")
    return out


def score(session, report):
    """(right count and every object within TARGET_M, errors of the matched objects), as
    `objloc eval` scores the capture's report against the original session's truth (the
    capture's world is the original's odom frame: its poses are the true ones)."""
    e = json.loads(run([BIN, "eval", session, "--report", report, "--json", "--any-session"]))[0]
    errs = sorted(m["error_m"] for m in e["matches"])
    ok = not e["missed"] and not e["spurious"] and all(d <= TARGET_M for d in errs)
    return ok, errs

def three_labelled(tour):
    """The tour's capture again with labels on three of its frames only (the first, middle
    and last that show an object; every row of those frames), cached."""
    mcap, _ = as_capture(tour)
    d = mcap[:-5]
    out = d + "-three.mcap"
    if not os.path.exists(out):
        rows = open(os.path.join(d, "labels.csv")).read().splitlines()
        shown = sorted({r.split(",")[0] for r in rows[1:] if r.split(",")[3] not in ("", "0")})
        pick = {shown[0], shown[len(shown) // 2], shown[-1]}
        csv = d + "-three.csv"
        with open(csv, "w") as f:
            f.write("\n".join([rows[0]] + [r for r in rows[1:] if r.split(",")[0] in pick]) + "\n")
        cam = open(os.path.join(d, "camera.txt")).read().strip()
        dist = os.path.join(d, "distortion.txt")
        lens = ["--distortion", open(dist).read().strip()] if os.path.exists(dist) else []
        run([BIN, "record", "import", "--images", os.path.join(d, "images"), "--trajectory",
             os.path.join(d, "trajectory.txt"), "--camera", cam, *lens, "--labels", csv, "-q",
             "-o", out])
    return out


def measure(set_name, train, tours, config, extra):
    tflags, fflags = CONFIGS[config]
    if config.startswith("three"):
        rows = []
        for tour in tours:
            mcap, _ = as_capture(tour)
            name = f"{os.path.basename(tour)[:-5]}-{config}"
            model = os.path.join(OUT, name + ".json")
            run([BIN, "train", three_labelled(tour), "-o", model, "--no-rerun", *tflags])
            report = os.path.join(OUT, name + ".report.json")
            run([BIN, "fuse", mcap, "--model", model, "--report", report, "--no-rerun", *fflags, *extra])
            ok, errs = score(tour, report)
            rows.append((set_name, os.path.basename(tour)[:-5], config, ok, errs))
        return rows
    tr, _ = as_capture(train)
    model = os.path.join(OUT, f"{os.path.basename(train)[:-5]}-{config}.json")
    run([BIN, "train", tr, "-o", model, "--no-rerun", *tflags])
    rows = []
    for tour in tours:
        mcap, _ = as_capture(tour)
        report = os.path.join(OUT, f"{os.path.basename(tour)[:-5]}-{config}.report.json")
        run([BIN, "fuse", mcap, "--model", model, "--report", report, "--no-rerun", *fflags, *extra])
        ok, errs = score(tour, report)
        rows.append((set_name, os.path.basename(tour)[:-5], config, ok, errs))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", default="wide,mounts,foreign")
    ap.add_argument("--configs", default="default,rgb332")
    ap.add_argument("--perturb", action="store_true",
                    help="perturb every capture's frames (into target/measure-sim-captures-perturbed)")
    ap.add_argument("extra", nargs="*")
    a = ap.parse_args()
    global OUT, PERTURBED
    if a.perturb:
        OUT, PERTURBED = OUT + "-perturbed", True
    os.makedirs(OUT, exist_ok=True)
    sets, configs = a.sets.split(","), a.configs.split(",")
    jobs = [(s, tr, tours, c) for s, tr, tours in pairs() if s in sets for c in configs]
    # Imports first, one process each, so that two jobs never write one capture at once.
    for _, tr, tours, c in jobs:
        for sess in [tr, *tours]:
            as_capture(sess)
        if c.startswith("three"):
            for t in tours:
                three_labelled(t)
    with cf.ThreadPoolExecutor(2) as ex:
        rows = [r for rs in ex.map(lambda j: measure(*j, a.extra), jobs) for r in rs]
    for s in sets:
        print(f"\n== {s} as captures")
        for c in configs:
            rs = [r for r in rows if r[0] == s and r[2] == c]
            errs = [e for r in rs for e in r[4]]
            if not rs:
                continue
            print(f"{c:10s} {sum(r[3] for r in rs)}/{len(rs)} right count, all within {TARGET_M} m; "
                  f"mean error {sum(errs) / max(1, len(errs)):.3f} m, worst {max(errs, default=0):.3f} m "
                  f"({len(errs)} objects)")
            for r in rs:
                if not r[3]:
                    print(f"    miss: {r[1]}: {', '.join(f'{e:.3f}' for e in r[4]) or '-'}")


if __name__ == "__main__":
    sys.exit(main())
