#!/usr/bin/env python3
"""Copies a session MCAP and adds a high-rate topic no role reads, as a robot's bag has: an
`/imu` channel (`sensor_msgs/msg/Imu`, opaque 320-byte payloads, seeded) at RATE_HZ over the
session's span. For measuring what such topics cost the reader (docs/scale.md, "Topics
without a role").

Usage: target/pyenv/bin/python scripts/add_imu_topic.py IN.mcap OUT.mcap [RATE_HZ]
Needs the `mcap` package (in target/pyenv, which `cargo test` sets up).
"""
import random
import sys

from mcap.reader import make_reader
from mcap.writer import Writer


def main():
    src, dst = sys.argv[1], sys.argv[2]
    rate_hz = float(sys.argv[3]) if len(sys.argv) > 3 else 400.0
    with open(src, "rb") as f:
        msgs = [(s, c, m) for s, c, m in make_reader(f).iter_messages(log_time_order=True)]
    t0, t1 = msgs[0][2].log_time, msgs[-1][2].log_time
    step = int(1e9 / rate_hz)
    rng = random.Random(7)
    with open(dst, "wb") as out:
        w = Writer(out)
        w.start(profile="ros2", library="add_imu_topic.py")
        schemas, channels = {}, {}
        for s, c, _ in msgs:
            if s is not None and s.id not in schemas:
                schemas[s.id] = w.register_schema(s.name, s.encoding, s.data)
            if c.id not in channels:
                channels[c.id] = w.register_channel(
                    c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata)
        imu_schema = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", b"")
        imu = w.register_channel("/imu", "cdr", imu_schema)
        t, seq, i = t0, 0, 0
        while i < len(msgs) or t <= t1:
            if i < len(msgs) and (t > t1 or msgs[i][2].log_time <= t):
                m = msgs[i][2]
                w.add_message(channels[msgs[i][1].id], m.log_time, m.data, m.publish_time, m.sequence)
                i += 1
            else:
                w.add_message(imu, t, rng.randbytes(320), t, seq)
                t += step
                seq += 1
        w.finish()


if __name__ == "__main__":
    main()
