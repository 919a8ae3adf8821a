"""List what an .rrd recording holds, with the third-party Rerun SDK's own RRD reader.

Usage: rrd_contents.py FILE.rrd
       rrd_contents.py --entities FILE.rrd
       rrd_contents.py --blobs ENTITY FILE.rrd DIR
Prints a JSON list with one entry per chunk: entity path, static or not, row count and its
columns. Time columns become int64 nanoseconds; Blob columns (encoded images) become
{len, sha256} per row; other component columns are given in full, except the raw MCAP
channel/schema records and reflected ROS messages, which are named but not listed.

With --blobs ENTITY DIR, writes every blob logged on ENTITY (an encoded image's file) to
DIR/NNNN.bin in the order the reader yields them, and prints the list of paths.

With --entities, prints instead one entry per entity path, its chunks merged: static (true
when every chunk is), its column names (sorted) and the sorted values of its `log_time` and
`frame` timelines (int64 nanoseconds and frame indices), without the component data.
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


def entities(path):
    out = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        e = out.setdefault(
            chunk.entity_path, {"static": True, "columns": [], "log_time": [], "frame": []}
        )
        e["static"] = e["static"] and chunk.is_static
        for name in batch.schema.names:
            if not name.startswith("rerun.controls.") and name not in e["columns"]:
                e["columns"].append(name)
        for timeline in ("log_time", "frame"):
            if timeline in batch.schema.names:
                e[timeline] += column_values(timeline, batch.column(timeline))
    for e in out.values():
        for key in ("columns", "log_time", "frame"):
            e[key].sort()
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")


def blobs(entity, path, out_dir):
    import os

    paths = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if not name.endswith(":blob"):
                continue
            for row in batch.column(name).to_pylist():
                for b in row or []:
                    p = os.path.join(out_dir, "%04d.bin" % len(paths))
                    with open(p, "wb") as f:
                        f.write(bytes(b))
                    paths.append(p)
    json.dump(paths, sys.stdout)
    sys.stdout.write("\n")


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
    if sys.argv[1] == "--entities":
        entities(sys.argv[2])
    elif sys.argv[1] == "--blobs":
        blobs(sys.argv[2], sys.argv[3], sys.argv[4])
    else:
        main(sys.argv[1])
