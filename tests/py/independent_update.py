"""An independent implementation of objloc's per-frame update (paper section 3.1), in NumPy.

Reads the session's /odom, /tf_static and /camera/camera_info with the Python mcap +
mcap-ros2-support readers (not objloc), the tile head's probability maps that `objloc predict`
wrote (tile_probs.npy: what the fuser integrates), and the grid's spec from the fuse report.
For every frame, every cell whose centre lies in front of the camera, no deeper than the
report's range limit (options.max_footprint_voxels: where a tile's footprint, depth * 8 /
min(fx, fy), exceeds that many cells), and projects into a tile gets log-odds += logit(p) -
logit(prior). No motion blur (the fuse must run with both sigmas 0). Compares the posterior
with objloc's --grid (the cells the report's grid.export names: the whole grid when dense,
the stored blocks' box when sparse) and prints JSON: cells compared, cells that differ,
largest difference, cells the frames updated (in the whole grid), cells above 0.5.

usage: independent_update.py SESSION TILE_PROBS.npy STAMPS.npy REPORT.json GRID.npy
"""
import json
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def rot(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def logit(p):
    return np.log(p / (1 - p))


session, probs_path, stamps_path, report_path, grid_path = sys.argv[1:6]
probs = np.load(probs_path).astype(np.float64)
stamps = np.load(stamps_path)
report = json.load(open(report_path))
g = report["grid"]
nx, ny, nz = g["dims"]
voxel = g["voxel_size_m"]
origin = np.array(g["origin_m"])
prior = g["prior"]

odom, mount, K = {}, None, None
with open(session, "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, channel, _, m in reader.iter_decoded_messages(
        topics=["/odom", "/tf_static", "/camera/camera_info"]
    ):
        if channel.topic == "/odom":
            t = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            p = m.pose.pose
            odom[t] = (np.array([p.position.x, p.position.y, p.position.z]), rot(p.orientation))
        elif channel.topic == "/tf_static":
            tr = m.transforms[0].transform
            mount = (np.array([tr.translation.x, tr.translation.y, tr.translation.z]), rot(tr.rotation))
        elif K is None:
            K = np.array(m.k).reshape(3, 3)

tile = 8
rows, cols = probs.shape[1], probs.shape[2]
n_fp = report["options"].get("max_footprint_voxels")
zmax = np.inf if n_fp is None else n_fp * voxel * min(K[0, 0], K[1, 1]) / tile
i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
centres = origin + (np.stack([i, j, k], axis=-1) + 0.5) * voxel
L = np.full((nx, ny, nz), logit(prior))
updated = 0
for n, stamp in enumerate(stamps):
    t_base, r_base = odom[int(stamp)]
    t_cam = r_base @ mount[0] + t_base
    r_cam = r_base @ mount[1]
    pc = (centres - t_cam) @ r_cam  # rows of R^T (c - t)
    z = pc[..., 2]
    front = (z > 1e-9) & (z <= zmax)
    zs = np.where(front, z, 1.0)
    u = K[0, 0] * pc[..., 0] / zs + K[0, 2]
    v = K[1, 1] * pc[..., 1] / zs + K[1, 2]
    inside = front & (u >= 0) & (u < cols * tile) & (v >= 0) & (v < rows * tile)
    c = np.floor(u[inside] / tile).astype(np.int64)
    r = np.floor(v[inside] / tile).astype(np.int64)
    L[inside] += logit(probs[n][r, c]) - logit(prior)
    updated += int(inside.sum())

posterior = 1 / (1 + np.exp(-L))
export = g.get("export") or {"first_cell": [0, 0, 0], "dims": [nx, ny, nz]}
(i0, j0, k0), (a, b, c) = export["first_cell"], export["dims"]
posterior = posterior[i0:i0 + a, j0:j0 + b, k0:k0 + c]
ours = np.load(grid_path).astype(np.float64)
assert ours.shape == posterior.shape, (ours.shape, posterior.shape)
diff = np.abs(ours - posterior)
print(
    json.dumps(
        {
            "cells": int(posterior.size),
            "differing": int((diff > 1e-5).sum()),
            "max_abs_diff": float(diff.max()),
            "updated": updated,
            "above_half": int((posterior > 0.5).sum()),
        }
    )
)
