"""NumPy peer for benches/fuse.rs: the same per-frame update and a translation blur on a
100^3 grid, timed as medians. Prints `update_ms X blur_ms Y`."""
import time

import numpy as np


def median_ms(reps, f):
    t = []
    for _ in range(reps):
        s = time.perf_counter()
        f()
        t.append((time.perf_counter() - s) * 1e3)
    return sorted(t)[len(t) // 2]


n, v = 100, 0.04
half = n * v / 2
ax = (np.arange(n) + 0.5) * v
x, y, z = np.meshgrid(ax - half, ax - half, ax, indexing="ij")
L = np.full((n, n, n), np.log(0.005 / 0.995), dtype=np.float32)
# Camera looking along +x from (-half - 0.5, 0.1, 1.2), level (a simplified pose: the cost is
# the same as for a full rotation).
fx = fy = 128 / np.tan(1.05 / 2)
cx, cy = 128.0, 120.0
delta = np.random.default_rng(0).normal(size=(30, 32)).astype(np.float32)


def update():
    zc = x - (-half - 0.5)
    xc = -(y - 0.1)
    yc = -(z - 1.2)
    ok = zc > 1e-9
    u = np.where(ok, fx * xc / np.where(ok, zc, 1) + cx, -1)
    vv = np.where(ok, fy * yc / np.where(ok, zc, 1) + cy, -1)
    inside = ok & (u >= 0) & (u < 256) & (vv >= 0) & (vv < 240)
    c = (u[inside] // 8).astype(np.int64)
    r = (vv[inside] // 8).astype(np.int64)
    L[inside] += delta[r, c]


def blur():
    # Gaussian along x with sigma 0.017 m sampled at whole cells (+-4 sigma), via shifts.
    sigma = 0.017 / v
    k = np.arange(-int(np.ceil(4 * sigma)), int(np.ceil(4 * sigma)) + 1)
    w = np.exp(-0.5 * (k / sigma) ** 2)
    w /= w.sum()
    out = np.zeros_like(L)
    for kk, ww in zip(k, w):
        out += ww * np.roll(L, kk, axis=0)
    return out


print(f"update_ms {median_ms(9, update):.2f} blur_ms {median_ms(5, blur):.2f}")
