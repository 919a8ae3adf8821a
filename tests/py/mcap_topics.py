"""Topics of any MCAP file per the third-party `mcap` reader: the ground truth for inspect.

Usage: mcap_topics.py FILE.mcap
Prints a JSON object: header profile and library, total message count and, per topic, its
schema name, message encoding and the number of messages (counted by reading every message,
not from the summary statistics, so channels without messages show 0).
"""

import json
import sys

from mcap.reader import make_reader


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        topics = {}
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            topics[channel.topic] = {
                "type": schema.name if schema else "",
                "message_encoding": channel.message_encoding,
                "count": 0,
            }
        total = 0
        for _schema, channel, _message in reader.iter_messages(log_time_order=False):
            topics[channel.topic]["count"] += 1
            total += 1
    json.dump(
        {
            "profile": header.profile,
            "library": header.library,
            "messages": total,
            "topics": dict(sorted(topics.items())),
        },
        sys.stdout,
        indent=1,
    )
    sys.stdout.write("\n")


if __name__ == "__main__":
    main(sys.argv[1])
