"""Decode every message of an MCAP with the third-party `mcap` + `mcap-ros2-support` readers.

Usage: decode_session.py FILE.mcap
Prints one JSON document: the header (profile, library), every schema and channel, and every
message in file order with its decoded fields. uint8[] fields are replaced by their length and
SHA-256 so the output stays small; floats are printed with repr, so they round-trip exactly.
"""

import hashlib
import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def to_plain(value):
    """Decoded ROS message (objects with __slots__) -> JSON-able dicts and lists."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        b = bytes(value)
        return {"len": len(b), "sha256": hashlib.sha256(b).hexdigest()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays, if a decoder returns them
        return to_plain(value.tolist())
    slots = getattr(value, "__slots__", None)
    if slots is not None:
        return {name: to_plain(getattr(value, name)) for name in slots}
    return value


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        out = {
            "header": {"profile": header.profile, "library": header.library},
            "schemas": [
                {"id": s.id, "name": s.name, "encoding": s.encoding}
                for s in sorted(summary.schemas.values(), key=lambda s: s.id)
            ],
            "channels": [
                {
                    "id": c.id,
                    "topic": c.topic,
                    "message_encoding": c.message_encoding,
                    "schema_id": c.schema_id,
                }
                for c in sorted(summary.channels.values(), key=lambda c: c.id)
            ],
            "statistics": {
                "message_count": summary.statistics.message_count,
                "channel_message_counts": {
                    str(k): v for k, v in sorted(summary.statistics.channel_message_counts.items())
                },
            },
            "messages": [],
        }
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            out["messages"].append(
                {
                    "topic": channel.topic,
                    "schema": schema.name,
                    "sequence": message.sequence,
                    "log_time": message.log_time,
                    "publish_time": message.publish_time,
                    "msg": to_plain(decoded),
                }
            )
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main(sys.argv[1])
