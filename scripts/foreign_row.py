"""One table row of scripts/measure_foreign.sh: errors against the manifest's centroids (the
volume-weighted centroid of each instance's boxes), matched greedily by distance."""
import json, sys, math
manifest, name, refine, report_path = sys.argv[1:5]
e = json.load(sys.stdin)[0]
r = json.load(open(report_path))
m = [s for s in json.load(open(manifest))["sessions"] if s["file"] == name + ".mcap"][0]
truth = [o["centroid"] for o in m["objects"]]
found = [o["centroid_m"] for o in r["objects"]]
pairs = sorted((math.dist(t, f), i, j) for i, t in enumerate(truth) for j, f in enumerate(found))
used_t, used_f, errs = set(), set(), []
for d, i, j in pairs:
    if i in used_t or j in used_f:
        continue
    used_t.add(i); used_f.add(j); errs.append(d)
errs.sort()
missed = len(truth) - len(errs)
spurious = len(found) - len(errs)
text = ",".join("%.3f" % d for d in errs) or "-"
if missed: text += " %d missed" % missed
if spurious: text += " %d spur" % spurious
t = e.get("trajectory") or {}
outcomes = {}
for f in r.get("per_frame", []):
    c = f.get("correction")
    k = c.get("outcome", "applied" if c.get("applied") else "kept") if c else None
    if k: outcomes[k] = outcomes.get(k, 0) + 1
ok = (missed == 0 and spurious == 0 and all(d <= 0.12 for d in errs))
print("%-28s %-8s %-22s %8.3f %8.3f %s %s" % (name, refine, text, t.get("odometry_ate_m", float("nan")),
      t.get("fused_ate_m", float("nan")), " ".join("%s=%d" % kv for kv in sorted(outcomes.items())), "ok" if ok else "FAIL"))
