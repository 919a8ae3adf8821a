"""List what an .rrd recording holds, with the third-party Rerun SDK's own RRD reader.

Usage: rrd_contents.py FILE.rrd
Prints a JSON list with one entry per chunk: entity path, static or not, row count and its
columns. Time columns become int64 nanoseconds; Blob columns (encoded images) become
{len, sha256} per row; other component columns are given in full, except the raw MCAP
channel/schema records and reflected ROS messages, which are named but not listed.
"""

import hashlib
import json
import sys

import pyarrow as pa
from rerun.experimental import RrdReader


def column_values(name, column):
    if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
        return column.cast(pa.int64()).to_pylist()
    if name.endswith(":blob"):
        out = []
        for row in column.to_pylist():
            blobs = row or []
            out.append([{"len": len(b), "sha256": hashlib.sha256(bytes(b)).hexdigest()} for b in blobs])
        return out
    if name.startswith(("McapChannel:", "McapSchema:")) or name.endswith(":message"):
        return None
    return column.to_pylist()


def main(path):
    chunks = []
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = {}
        for name in batch.schema.names:
            if name.startswith("rerun.controls."):
                continue
            columns[name] = column_values(name, batch.column(name))
        chunks.append(
            {
                "entity": chunk.entity_path,
                "static": chunk.is_static,
                "rows": chunk.num_rows,
                "columns": columns,
            }
        )
    json.dump(chunks, sys.stdout, indent=1)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main(sys.argv[1])
