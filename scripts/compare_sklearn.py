#!/usr/bin/env python3
"""Compare objloc's pruned probability tree with scikit-learn's DecisionTreeClassifier.

Runs `objloc train --export-features` on a session, then fits
DecisionTreeClassifier(criterion="entropy") on exactly the exported training examples, with
cost-complexity pruning whose ccp_alpha is chosen on the pruning third (lowest log-loss), and
prints fit time, node count, test-third accuracy, log-loss and ROC AUC for both, and the
fit-time ratio. Deterministic (random_state=0, fixed alpha grid).

Needs numpy and scikit-learn: when they are not importable the script creates a venv under
target/pyenv (python3 -m venv), installs them there and re-runs itself with that interpreter.

Usage (from the repository root, after `cargo build --release`):
    python3 scripts/compare_sklearn.py [--session recordings/chair-train.mcap]
        [--features hsv] [--train-stride 4] [--context-tiles 0] [--repeats 3]
The tile head is compared (objloc trains with --no-region); for the region head of a default
model, pass --features hsv --context-tiles 2 --train-stride 2 (the same tree: the region head
is trained as a tile head with those options).
"""

import argparse
import json
import os
import re
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VENV = os.path.join(ROOT, "target", "pyenv")


def ensure_packages():
    try:
        import numpy  # noqa: F401
        import sklearn  # noqa: F401
        return
    except ImportError:
        pass
    py = os.path.join(VENV, "bin", "python")
    if os.path.abspath(sys.executable) == os.path.abspath(py):
        sys.exit("error: numpy/scikit-learn still missing in %s after installing" % VENV)
    if not os.path.exists(py):
        subprocess.run([sys.executable, "-m", "venv", VENV], check=True)
    probe = subprocess.run([py, "-c", "import numpy, sklearn"], capture_output=True)
    if probe.returncode != 0:
        subprocess.run([py, "-m", "pip", "install", "--quiet", "numpy", "scikit-learn"], check=True)
    os.execv(py, [py] + sys.argv)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", default=os.path.join(ROOT, "recordings", "chair-train.mcap"))
    ap.add_argument("--features", default="hsv")
    ap.add_argument("--train-stride", default="4")
    ap.add_argument("--context-tiles", default="0",
                    help="neighbourhood radius; the region head of `objloc train` is "
                         "--features hsv --context-tiles 2 --train-stride 2")
    ap.add_argument("--seed", default="0")
    ap.add_argument("--objloc", default=os.path.join(ROOT, "target", "release", "objloc"))
    ap.add_argument("--out", default=os.path.join(ROOT, "target", "compare_sklearn"))
    ap.add_argument("--repeats", type=int, default=3, help="fits timed; the median is reported")
    ap.add_argument("--max-alphas", type=int, default=40)
    args = ap.parse_args()
    ensure_packages()

    import numpy as np
    from sklearn.metrics import accuracy_score, log_loss, roc_auc_score
    from sklearn.tree import DecisionTreeClassifier

    os.makedirs(args.out, exist_ok=True)
    model_path = os.path.join(args.out, "model.json")
    feats = os.path.join(args.out, "features")
    fit_times = []
    for _ in range(args.repeats):
        r = subprocess.run(
            [args.objloc, "train", args.session, "-o", model_path, "--features", args.features,
             "--train-stride", args.train_stride, "--seed", args.seed,
             "--context-tiles", args.context_tiles, "--no-region", "--no-rerun",
             "--export-features", feats],
            capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit("error: objloc train failed: " + r.stderr.strip())
        m = re.search(r"fit time ([0-9.]+) s", r.stdout)
        if not m:
            sys.exit("error: no 'fit time' in objloc output:\n" + r.stdout)
        fit_times.append(float(m.group(1)))
    with open(model_path) as f:
        model = json.load(f)
    meta = model["metadata"]
    objloc_fit = float(np.median(fit_times))

    X = np.load(os.path.join(feats, "X.npy"))
    y = np.load(os.path.join(feats, "y.npy")).astype(bool)
    split = np.load(os.path.join(feats, "split.npy"))
    tr, te, pr = split == 0, split == 1, split == 2
    Xtr, ytr = X[tr], y[tr]

    def fit(alpha):
        clf = DecisionTreeClassifier(criterion="entropy", ccp_alpha=alpha, random_state=0)
        t0 = time.perf_counter()
        clf.fit(Xtr, ytr)
        return clf, time.perf_counter() - t0

    def proba(clf, Xs):
        return clf.predict_proba(Xs)[:, list(clf.classes_).index(True)]

    # Unpruned fit (timed), then the pruning path and a choice of alpha on the pruning third.
    times = []
    for _ in range(args.repeats):
        full, t = fit(0.0)
        times.append(t)
    sk_fit_full = float(np.median(times))
    t0 = time.perf_counter()
    path = full.cost_complexity_pruning_path(Xtr, ytr)
    alphas = np.unique(path.ccp_alphas)
    if len(alphas) > args.max_alphas:
        alphas = np.unique(np.quantile(alphas, np.linspace(0, 1, args.max_alphas)))
    best = None
    for a in alphas:
        clf, _ = fit(float(a))
        loss = log_loss(y[pr], proba(clf, X[pr]), labels=[False, True])
        # Ties go to the larger alpha (the smaller tree), as objloc's pruning does.
        if best is None or loss <= best[0]:
            best = (loss, float(a), clf)
    sk_select = time.perf_counter() - t0
    _, alpha, clf = best
    times = []
    for _ in range(args.repeats):
        clf, t = fit(alpha)
        times.append(t)
    sk_fit_pruned = float(np.median(times))

    p_te = proba(clf, X[te])
    # The same m-estimate smoothing objloc's leaves use, applied to sklearn's leaves, so the
    # log-loss compares the trees rather than the smoothing.
    m_est = meta["tree_params"]["m_estimate"]
    prior = ytr.mean()
    leaves_tr = clf.apply(Xtr)
    n_leaf = np.bincount(leaves_tr, minlength=clf.tree_.node_count)
    pos_leaf = np.bincount(leaves_tr, weights=ytr, minlength=clf.tree_.node_count)
    smooth = (pos_leaf + m_est * prior) / (n_leaf + m_est)
    p_te_s = smooth[clf.apply(X[te])]

    tm = meta["test_metrics"]
    rows = [
        ("objloc (test stop + top-down prune)", objloc_fit, len(model["tree"]["nodes"]),
         tm["accuracy"], tm["log_loss"], tm["roc_auc"]),
        ("sklearn ccp_alpha=%.3g (raw leaves)" % alpha, sk_fit_pruned, clf.tree_.node_count,
         accuracy_score(y[te], p_te >= 0.5), log_loss(y[te], p_te, labels=[False, True]),
         roc_auc_score(y[te], p_te)),
        ("sklearn same tree, m-estimate leaves", sk_fit_pruned, clf.tree_.node_count,
         accuracy_score(y[te], p_te_s >= 0.5), log_loss(y[te], p_te_s, labels=[False, True]),
         roc_auc_score(y[te], p_te_s)),
        ("sklearn unpruned", sk_fit_full, full.tree_.node_count,
         accuracy_score(y[te], proba(full, X[te]) >= 0.5),
         log_loss(y[te], proba(full, X[te]), labels=[False, True]),
         roc_auc_score(y[te], proba(full, X[te]))),
    ]
    n_tr, n_te, n_pr = int(tr.sum()), int(te.sum()), int(pr.sum())
    print("session %s, features %s, context %s tiles, train stride %s: %d examples x %d features "
          "(train %d / %d positive, test %d / %d, prune %d / %d)"
          % (os.path.relpath(args.session, ROOT), args.features, args.context_tiles,
             args.train_stride, X.shape[0],
             X.shape[1], n_tr, int(ytr.sum()), n_te, int(y[te].sum()), n_pr, int(y[pr].sum())))
    print("%-38s %10s %7s %9s %9s %8s" % ("model", "fit s", "nodes", "accuracy", "log-loss", "AUC"))
    for name, t, nodes, acc, ll, auc in rows:
        print("%-38s %10.4f %7d %9.5f %9.5f %8.4f" % (name, t, nodes, acc, ll, auc))
    print("sklearn alpha selection (%d alphas, fit + prune-third scoring): %.2f s"
          % (len(alphas), sk_select))
    print("fit-time ratio sklearn(pruned fit) / objloc: %.1fx; sklearn(fit + alpha selection) / "
          "objloc: %.1fx (fit times are medians of %d)"
          % (sk_fit_pruned / objloc_fit, (sk_fit_full + sk_select) / objloc_fit, args.repeats))


if __name__ == "__main__":
    main()
