#!/usr/bin/env python3
"""Writes a session as a posed capture comes: its frames as image files, the camera's poses
as a TUM trajectory (camera in world, OpenCV axes: /ground_truth/pose at each frame's stamp,
or /odom where the session has no ground truth, composed with the /tf_static mount), its
intrinsics, its label rectangles as a labels CSV, and the objects' true centres where it
has them (per name, a list: the volume-weighted centroid of each group of touching boxes, as
`objloc eval` scores it). `objloc record import --trajectory` then makes a session without
/cmd_vel of it: the path a real capture takes (issue #18), on a scene whose truth is known
(docs/realdata.md, "A simulated capture"), or an imported real capture again, as a held-out
one comes (a TUM trajectory and a labels CSV; `--scale` downscales it as users do). The
camera's mount is chained from /tf_static and /tf at each frame's stamp (a pan-tilt head:
interpolated, as tf2 does, no further than 50 ms past the samples); a radial-tangential lens
is written for `--distortion`.

Usage: target/pyenv/bin/python scripts/sim_as_capture.py SESSION.mcap OUT_DIR [--scale S] [--world-scale W]
       [--world-rotation RX,RY,RZ]
Writes OUT_DIR/images/<stamp>.png (or .jpg, as recorded), trajectory.txt, labels.csv,
camera.txt (FX,FY,CX,CY), distortion.txt (K1,K2,P1,P2,K3, for `--distortion`; only for a
distorted lens) and truth.json (only with /ground_truth/objects). `--scale S`: every image
resampled to S times its size (bicubic; JPEG quality 92 or PNG, as recorded), and the
intrinsics and rectangles scaled alike (a pixel's centre stays where it was: cx' = (cx + 0.5)
sx - 0.5). Needs mcap and mcap-ros2-support (the test environment's target/pyenv has them;
pillow for `--scale`). `--world-scale W`: every camera position (and true centre) multiplied by
W, as a structure-from-motion model comes in units of its own (a capture's results must not
depend on them). `--world-rotation RX,RY,RZ`: the world turned by these angles (degrees, about
x, then y, then z) before it is scaled, as a model whose z is not up comes.
"""
import argparse
import io
import json
import os
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def quat_to_rot(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def euler_xyz(angles):
    """The rotation about x by angles[0], then about y, then about z (radians)."""
    rx, ry, rz = angles
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return z @ y @ x


def rot_to_quat(r):
    # Shepperd's method, w kept non-negative.
    t = np.trace(r)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) * 2
        q = [0.0] * 4
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
        q[3] = (r[k, j] - r[j, k]) / s
    q = np.array(q)
    return q if q[3] >= 0 else -q


def pose(p, o):
    m = np.eye(4)
    m[:3, :3] = quat_to_rot([o.x, o.y, o.z, o.w])
    m[:3, 3] = [p.x, p.y, p.z]
    return m


def slerp(a, b, f):
    """Spherical interpolation of unit quaternions (x, y, z, w), the shorter way."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    dot = float(a @ b)
    if dot < 0:
        b, dot = -b, -dot
    if dot > 0.9995:
        q = a + f * (b - a)
        return q / np.linalg.norm(q)
    th = np.arccos(dot)
    return (np.sin((1 - f) * th) * a + np.sin(f * th) * b) / np.sin(th)


def at_stamp(samples, t):
    """A /tf link at `t` as tf2 gives it: interpolated between the samples around it (the
    translation linearly, the rotation by slerp); None past either end by more than 50 ms."""
    samples = sorted(samples, key=lambda s: s[0])
    for (t0, (p0, q0)), (t1, (p1, q1)) in zip(samples, samples[1:]):
        if t0 <= t <= t1:
            f = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
            qa, qb = [q0.x, q0.y, q0.z, q0.w], [q1.x, q1.y, q1.z, q1.w]
            m = np.eye(4)
            m[:3, :3] = quat_to_rot(slerp(qa, qb, f))
            m[:3, 3] = (1 - f) * np.array([p0.x, p0.y, p0.z]) + f * np.array([p1.x, p1.y, p1.z])
            return m
    for ts, (p, q) in (samples[0], samples[-1]):
        if abs(ts - t) <= 50_000_000:
            return pose(p, q)
    return None


def mount_at(session, static, dynamic, camera_frame, t):
    """base_link -> the camera's frame at `t`: /tf_static and /tf chained from the camera up."""
    m, frame = np.eye(4), camera_frame
    while frame != "base_link":
        if frame in static:
            parent, link = static[frame]
        elif frame in dynamic:
            parent, samples = dynamic[frame]
            link = at_stamp(samples, t)
            if link is None:
                sys.exit(f"{session}: no /tf for {frame} within 50 ms of {t} ns")
        else:
            sys.exit(f"{session}: no transform from base_link to {camera_frame} ({frame} has no parent)")
        m, frame = link @ m, parent
    return m


def stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def scaled(data, fmt, scale):
    """The image's bytes resampled to `scale` times its size, and the (x, y) factors."""
    from PIL import Image
    img = Image.open(io.BytesIO(data)).convert("RGB")
    w, h = max(1, round(img.width * scale)), max(1, round(img.height * scale))
    out = io.BytesIO()
    img.resize((w, h), Image.BICUBIC).save(out, "PNG" if "png" in fmt else "JPEG",
                                           **({} if "png" in fmt else {"quality": 92}))
    return out.getvalue(), (w / img.width, h / img.height)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("session")
    ap.add_argument("out")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--world-scale", type=float, default=1.0)
    ap.add_argument("--world-rotation", default="0,0,0", metavar="RX,RY,RZ")
    a = ap.parse_args()
    try:
        angles = [np.radians(float(v)) for v in a.world_rotation.split(",")]
        if len(angles) != 3:
            raise ValueError
    except ValueError:
        ap.error(f"--world-rotation {a.world_rotation}: three angles in degrees, RX,RY,RZ")
    turned = np.eye(4)
    turned[:3, :3] = euler_xyz(angles)
    for flag, v in (("--scale", a.scale), ("--world-scale", a.world_scale)):
        if not 0 < v < float("inf"):
            ap.error(f"{flag} {v}: must be a positive number")
    session, out = a.session, a.out
    if not os.path.isfile(session):
        sys.exit(f"{session}: no such session file")
    os.makedirs(os.path.join(out, "images"), exist_ok=True)
    frames, labels, gt_pose, k, d, truth, camera_frame = [], {}, {}, None, None, None, None
    odom = {}
    # child frame -> (parent, transform) on /tf_static; -> (parent, [(stamp, transform)]) on /tf.
    static, dynamic = {}, {}
    with open(session, "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            t = channel.topic
            if t == "/camera/image/compressed":
                frames.append((stamp_ns(msg.header), msg.format, bytes(msg.data)))
                camera_frame = msg.header.frame_id
            elif t == "/camera/camera_info" and k is None:
                if msg.distortion_model not in ("", "plumb_bob", "rational_polynomial") or any(
                        v != 0 for v in list(msg.d)[5:]):
                    sys.exit(f"{session}: lens model {msg.distortion_model} {list(msg.d)} is not k1,k2,p1,p2,k3")
                k, d = list(msg.k), (list(msg.d) + [0.0] * 5)[:5]
            elif t == "/labels":
                # A label without rectangles marks a background frame: an empty box in the CSV.
                labels.setdefault(stamp_ns(msg.header), []).extend(
                    [(msg.object, r.x_offset, r.y_offset, r.width, r.height) for r in msg.regions]
                    or [(msg.object, "", "", "", "")])
            elif t == "/ground_truth/pose":
                gt_pose[stamp_ns(msg.header)] = pose(msg.pose.position, msg.pose.orientation)
            elif t == "/odom":
                odom[stamp_ns(msg.header)] = pose(msg.pose.pose.position, msg.pose.pose.orientation)
            elif t in ("/tf_static", "/tf"):
                for tr in msg.transforms:
                    x = (tr.transform.translation, tr.transform.rotation)
                    if t == "/tf_static":
                        static[tr.child_frame_id] = (tr.header.frame_id, pose(*x))
                    else:
                        dynamic.setdefault(tr.child_frame_id, (tr.header.frame_id, []))[1].append(
                            (stamp_ns(tr.header), x))
            elif t == "/ground_truth/objects":
                truth = msg
    # A simulated session's poses are its ground truth; an imported capture has /odom alone.
    poses = gt_pose or odom
    if not frames or k is None or not poses:
        sys.exit(f"{session}: needs frames, camera info and /ground_truth/pose or /odom")
    pose_times = np.array(sorted(poses))
    traj, rows, factors = [], ["image,x,y,width,height,object"], (1.0, 1.0)
    for t, fmt, data in frames:
        # The robot stands still while it takes a frame (an imported capture's /odom is at
        # the frame's stamp): the nearest pose is its pose, within 1 ms of the stamp.
        near = int(pose_times[np.argmin(np.abs(pose_times - t))])
        if abs(near - t) > 1_000_000:
            sys.exit(f"{session}: no pose within 1 ms of the frame at {t} ns")
        world_from_camera = turned @ poses[near] @ mount_at(session, static, dynamic, camera_frame, t)
        q = rot_to_quat(world_from_camera[:3, :3])
        p = world_from_camera[:3, 3] * a.world_scale
        name = f"{t / 1e9:.6f}.{'png' if 'png' in fmt else 'jpg'}"
        if a.scale != 1.0:
            data, factors = scaled(data, fmt, a.scale)
        open(os.path.join(out, "images", name), "wb").write(data)
        # 12 significant digits whatever the world's unit (a fixed 9 decimals would round a
        # position of 0.004 units to 7 digits).
        traj.append(f"{t / 1e9:.6f} {p[0]:.12g} {p[1]:.12g} {p[2]:.12g} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
        sx, sy = factors
        for obj, x, y, w, h in labels.get(t, []):
            if x != "" and a.scale != 1.0:
                x0, y0 = round(x * sx), round(y * sy)
                x, y, w, h = x0, y0, round((x + w) * sx) - x0, round((y + h) * sy) - y0
            rows.append(f"{name},{x},{y},{w},{h},{obj}")
    open(os.path.join(out, "trajectory.txt"), "w").write("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(traj) + "\n")
    open(os.path.join(out, "labels.csv"), "w").write("\n".join(rows) + "\n")
    sx, sy = factors
    fx, fy, cx, cy = k[0] * sx, k[4] * sy, (k[2] + 0.5) * sx - 0.5, (k[5] + 0.5) * sy - 0.5
    open(os.path.join(out, "camera.txt"), "w").write(
        f"{k[0]},{k[4]},{k[2]},{k[5]}\n" if a.scale == 1.0 else f"{fx!r},{fy!r},{cx!r},{cy!r}\n")
    # `--distortion K1,K2,P1,P2,K3` (ROS's d is k1, k2, p1, p2, k3): written only for a lens.
    dist = os.path.join(out, "distortion.txt")
    if any(v != 0 for v in d):
        open(dist, "w").write(",".join(repr(float(v)) for v in d) + "\n")
    elif os.path.exists(dist):
        os.remove(dist)
    if truth is None:
        if os.path.exists(os.path.join(out, "truth.json")):
            os.remove(os.path.join(out, "truth.json"))
        print(f"{len(frames)} frames, {len(rows) - 1} label rows -> {out} (no ground truth)")
        return
    # Boxes of one name whose bounds touch (within 0.01 m, `eval::PART_TOUCH_M`) are one
    # instance (a chair's seat, back and legs), scored at their volume-weighted centroid, as
    # `objloc eval` groups them.
    boxes = []
    for n, c, s in zip(truth.object, truth.box_center, truth.box_size):
        r = quat_to_rot([c.orientation.x, c.orientation.y, c.orientation.z, c.orientation.w])
        half = np.abs(r) @ (np.array([s.x, s.y, s.z]) / 2)
        centre = np.array([c.position.x, c.position.y, c.position.z])
        boxes.append((n, centre, np.array([s.x, s.y, s.z]), centre - half, centre + half))
    group = list(range(len(boxes)))

    def root(i):
        while group[i] != i:
            i = group[i]
        return i
    for i, (ni, _, _, lo_i, hi_i) in enumerate(boxes):
        for j, (nj, _, _, lo_j, hi_j) in enumerate(boxes[:i]):
            if ni == nj and np.all(lo_i <= hi_j + 0.01) and np.all(lo_j <= hi_i + 0.01):
                ri, rj = root(i), root(j)
                group[max(ri, rj)] = min(ri, rj)
    instances = {}
    for i, (n, c, s, _, _) in enumerate(boxes):
        acc = instances.setdefault((n, root(i)), [0.0, np.zeros(3)])
        acc[0] += float(np.prod(s))
        acc[1] += float(np.prod(s)) * c
    centres = {}
    for (n, _), (v, m) in sorted(instances.items(), key=lambda kv: kv[0][1]):
        centres.setdefault(n, []).append(list(turned[:3, :3] @ (m / v) * a.world_scale))
    json.dump(centres, open(os.path.join(out, "truth.json"), "w"))
    print(f"{len(frames)} frames, {len(rows) - 1} label rows -> {out}")


if __name__ == "__main__":
    try:
        main()
    except (OSError, ValueError, KeyError, EOFError) as e:
        # A damaged or foreign file: one line naming it, not a traceback (mcap's
        # InvalidMagic and its record errors are ValueErrors or of their own kind, below).
        sys.exit(f"{sys.argv[1]}: {type(e).__name__}: {e}")
    except Exception as e:  # noqa: BLE001 - mcap's own exception classes, reported the same
        if type(e).__module__.startswith("mcap"):
            sys.exit(f"{sys.argv[1]}: not a readable MCAP session: {e}")
        raise
