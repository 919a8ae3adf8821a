#!/usr/bin/env python3
"""How much a robot set's result depends on the training seed alone: runs
scripts/measure_sessions.py (default options) once per training seed for each training
configuration, and prints per configuration the right counts per set and seed (right count
with every object within 0.12 m), their mean, and the sessions that are not right with every
seed (how many seeds got each right). A change measured with one seed can only be told from
this spread by more than the spread.

Usage: scripts/seed_spread.py [--sets small,approach,foreign,shelf,shipped] [--seeds 0,1,2,3,4]
           [--config "NAME=TRAIN FLAGS"]...      (from the repository root; stdlib only)
Each --config is a name and the `objloc train` flags it adds (default: one config, "tree",
with none: today's defaults); its runs are cached as target/seed-spread/NAME-seedS.json and
run again with --again or when target/release/objloc (OBJLOC_BIN) is newer than the cache. Example, a forest of 16 trees against the one tree:
  scripts/seed_spread.py --config "tree=" --config "forest16=--trees 16"
"""
import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "target", "seed-spread")
BIN = os.environ.get("OBJLOC_BIN") or os.path.join(ROOT, "target", "release", "objloc")
TARGET_M = 0.12


def right(res):
    return res["missed"] == 0 and res["spurious"] == 0 and all(e <= TARGET_M for e in res["errors"])


def run(name, flags, seed, sets, again):
    """One measure_sessions.py run; returns its JSON results."""
    out = os.path.join(OUT, "%s-seed%d.json" % (name, seed))
    stale = not os.path.exists(out) or (
        os.path.exists(BIN) and os.path.getmtime(out) < os.path.getmtime(BIN))
    if again or stale:
        env = dict(os.environ, TRAIN_FLAGS=" ".join(flags + ["--seed", str(seed)]))
        r = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "measure_sessions.py"),
                            "--sets", sets, "--modes", "default", "--json", out],
                           cwd=ROOT, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit("measure_sessions.py failed for %s seed %d:\n%s" % (name, seed, r.stderr.strip()))
    return json.load(open(out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", default="small,approach,foreign,shelf,shipped")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--config", action="append", metavar="NAME=FLAGS")
    ap.add_argument("--again", action="store_true", help="measure again what is cached")
    a = ap.parse_args()
    try:
        seeds = [int(s) for s in a.seeds.split(",")]
    except ValueError:
        ap.error("--seeds %r: whole numbers joined by ','" % a.seeds)
    configs = []
    for c in a.config or ["tree="]:
        name, _, flags = c.partition("=")
        if not name:
            ap.error("--config %r: NAME=FLAGS" % c)
        configs.append((name, flags.split()))
    os.makedirs(OUT, exist_ok=True)
    for name, flags in configs:
        per_seed = [run(name, flags, s, a.sets, a.again) for s in seeds]
        sets = sorted({r["set"] for rs in per_seed for r in rs})
        print("\n== %s (train flags: %s)" % (name, " ".join(flags) or "none"))
        print("%-10s %s  mean" % ("set", "".join("seed %-4d" % s for s in seeds)))
        totals = [0] * len(seeds)
        for st in sets:
            counts = [sum(right(r["default"]) for r in rs if r["set"] == st) for rs in per_seed]
            n = sum(1 for r in per_seed[0] if r["set"] == st)
            totals = [t + c for t, c in zip(totals, counts)]
            print("%-10s %s  %.1f of %d" % (st, "".join("%-9d" % c for c in counts),
                                            sum(counts) / len(counts), n))
        print("%-10s %s  %.1f" % ("all", "".join("%-9d" % t for t in totals), sum(totals) / len(totals)))
        by_session = {}
        for rs in per_seed:
            for r in rs:
                by_session.setdefault((r["set"], r["session"]), []).append(right(r["default"]))
        shaky = [(k, sum(v)) for k, v in sorted(by_session.items()) if not all(v)]
        print("not right with every seed: " + (", ".join(
            "%s %s %d/%d" % (k[0], k[1], n, len(seeds)) for k, n in shaky) or "none"))


if __name__ == "__main__":
    main()
