"""Write a session with the third-party `rosbags` package (its rosbag2 writer, MCAP storage).

Usage: write_rosbags.py SCHEMAS_DIR OUT_DIR
The custom objloc_msgs types are registered from the .msg files in SCHEMAS_DIR, so this also
checks that those files are valid ROS 2 message definitions. rosbags writes OUT_DIR/ with
metadata.yaml and OUT_DIR/<name>.mcap. Prints a JSON object: the .mcap path and, per topic,
the message type and count written. Contents (all stamps = log times, 100 ms apart):
5 frames (32 x 24 PNG), CameraInfo, /odom and /ground_truth/pose per frame; frames 0 and 1
labelled "mug", frame 2 background; 1 /tf_static, 1 /cmd_vel, 1 /ground_truth/objects; and
2 /rosout messages (a topic with no session role).
"""

import json
import struct
import sys
import zlib
from pathlib import Path

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

T0_NS = 1_600_000_000_250_000_000
PERIOD_NS = 100_000_000
FRAMES = 5
WIDTH, HEIGHT = 32, 24


def png_rgb(width, height, rect):
    """A minimal RGB PNG: grey with a blue rectangle (x, y, w, h); only zlib is needed."""
    x0, y0, w, h = rect
    raw = bytearray()
    for y in range(height):
        raw.append(0)  # filter type None
        for x in range(width):
            inside = x0 <= x < x0 + w and y0 <= y < y0 + h
            raw.extend((20, 40, 230) if inside else (128, 128, 128))

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(bytes(raw)))
        + chunk(b"IEND", b"")
    )


def main(schemas_dir, out_dir):
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for msg_file in sorted(Path(schemas_dir).glob("*/msg/*.msg")):
        pkg = msg_file.parent.parent.name
        types.update(get_types_from_msg(msg_file.read_text(), f"{pkg}/msg/{msg_file.stem}"))
    store.register(types)
    T = store.types

    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    Vector3 = T["geometry_msgs/msg/Vector3"]
    Point = T["geometry_msgs/msg/Point"]
    Quaternion = T["geometry_msgs/msg/Quaternion"]
    Pose = T["geometry_msgs/msg/Pose"]
    Roi = T["sensor_msgs/msg/RegionOfInterest"]

    def header(ns, frame):
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame)

    def pose(x, y, z):
        return Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))

    import numpy as np

    messages = []  # (topic, type, stamp, msg)
    stamps = [T0_NS + k * PERIOD_NS for k in range(FRAMES)]
    mount = T["geometry_msgs/msg/TransformStamped"](
        header=header(T0_NS, "base_link"),
        child_frame_id="camera_optical_frame",
        transform=T["geometry_msgs/msg/Transform"](
            translation=Vector3(x=0.1, y=0.0, z=1.0),
            rotation=Quaternion(x=-0.5, y=0.5, z=-0.5, w=0.5),
        ),
    )
    messages.append(("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, T["tf2_msgs/msg/TFMessage"](transforms=[mount])))
    twist = T["geometry_msgs/msg/Twist"](linear=Vector3(x=0.3, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.1))
    messages.append(
        ("/cmd_vel", "geometry_msgs/msg/TwistStamped", T0_NS, T["geometry_msgs/msg/TwistStamped"](header=header(T0_NS, "base_link"), twist=twist))
    )
    messages.append(
        (
            "/ground_truth/objects",
            "objloc_msgs/msg/GroundTruth",
            T0_NS,
            T["objloc_msgs/msg/GroundTruth"](
                header=header(T0_NS, "odom"),
                object=["mug"],
                box_center=[pose(2.0, 0.0, 0.75)],
                box_size=[Vector3(x=0.1, y=0.1, z=0.12)],
            ),
        )
    )
    rect = (10, 6, 8, 9)
    for k, s in enumerate(stamps):
        info = T["sensor_msgs/msg/CameraInfo"](
            header=header(s, "camera_optical_frame"),
            height=HEIGHT,
            width=WIDTH,
            distortion_model="plumb_bob",
            d=np.zeros(5, dtype=np.float64),
            k=np.array([30.0, 0, 16.0, 0, 30.0, 12.0, 0, 0, 1], dtype=np.float64),
            r=np.eye(3, dtype=np.float64).reshape(9),
            p=np.array([30.0, 0, 16.0, 0, 0, 30.0, 12.0, 0, 0, 0, 1, 0], dtype=np.float64),
            binning_x=0,
            binning_y=0,
            roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        )
        messages.append(("/camera/camera_info", "sensor_msgs/msg/CameraInfo", s, info))
        image = T["sensor_msgs/msg/CompressedImage"](
            header=header(s, "camera_optical_frame"),
            format="png",
            data=np.frombuffer(png_rgb(WIDTH, HEIGHT, rect), dtype=np.uint8),
        )
        messages.append(("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", s, image))
        odom = T["nav_msgs/msg/Odometry"](
            header=header(s, "odom"),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(0.03 * k, 0.0, 0.0), covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )
        messages.append(("/odom", "nav_msgs/msg/Odometry", s, odom))
        gt = T["geometry_msgs/msg/PoseStamped"](header=header(s, "odom"), pose=pose(0.03 * k, 0.001 * k, 0.0))
        messages.append(("/ground_truth/pose", "geometry_msgs/msg/PoseStamped", s, gt))
        if k < 3:
            regions = [Roi(x_offset=rect[0], y_offset=rect[1], height=rect[3], width=rect[2], do_rectify=False)] if k < 2 else []
            label = T["objloc_msgs/msg/ObjectLabel"](header=header(s, "camera_optical_frame"), object="mug", regions=regions)
            messages.append(("/labels", "objloc_msgs/msg/ObjectLabel", s, label))
    for i in range(2):
        s = T0_NS + i * 250_000_000
        log = T["rcl_interfaces/msg/Log"](
            stamp=Time(sec=s // 1_000_000_000, nanosec=s % 1_000_000_000),
            level=20,
            name="recorder",
            msg=f"tick {i}",
            file="rec.py",
            function="main",
            line=1,
        )
        messages.append(("/rosout", "rcl_interfaces/msg/Log", s, log))

    messages.sort(key=lambda m: m[2])
    out = Path(out_dir)
    counts = {}
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, msgtype, stamp, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], stamp, store.serialize_cdr(msg, msgtype))
            t, n = counts.get(topic, (msgtype, 0))
            counts[topic] = (t, n + 1)
    mcap_path = out / f"{out.name}.mcap"
    json.dump(
        {"mcap": str(mcap_path), "topics": {k: {"type": t, "count": n} for k, (t, n) in sorted(counts.items())}},
        sys.stdout,
        indent=1,
    )
    sys.stdout.write("\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
