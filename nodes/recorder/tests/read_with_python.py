#!/usr/bin/env python3
"""Reads a Deep Contact recording with the PyPI `mcap` and `cbor2` packages, the way a Python
trainer or notebook would, and checks what the Rust tests expect of it.

usage: read_with_python.py FILE.mcap EXPECTED_JSON
EXPECTED_JSON: {"counts": {"topic": n, ...}, "first_body": {"run_id": r, "simulation": s, "step": k,
                "n": bodies, "x0": x of body 0}, "stats_model": name, "run_start": {field: value},
                "wire_version": v}
Exits 0 when every check holds, 1 with a message otherwise.
"""
import json
import struct
import sys

import cbor2
from mcap.reader import make_reader

BODY = struct.Struct("<II2f8f")  # id, shape, size[2], mass, inertia, x, y, angle, vx, vy, omega


def main():
    path, expected = sys.argv[1], json.loads(sys.argv[2])
    counts = {}
    first_body = None
    stats_models = set()
    run_start = None
    version = expected["wire_version"]
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, f"{path}: no summary section"
        for channel in summary.channels.values():
            assert channel.message_encoding == "cbor", channel
            assert channel.metadata.get("wire_version") == str(version), channel.metadata
            assert channel.metadata.get("type", "").startswith("dc::"), channel.metadata
        for _schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            frame = cbor2.loads(message.data)
            assert set(frame) == {"v", "h", "i"}, frame.keys()
            assert frame["v"] == version
            if channel.topic == "stats/solve":
                stats_models.add(frame["h"]["model"])
            if channel.topic == "control" and frame["h"]["kind"] == 1 and run_start is None:
                run_start = cbor2.loads(frame["i"])  # RunStart: its details are a CBOR map
            if channel.topic == "bodies" and first_body is None:
                h, items = frame["h"], frame["i"]
                assert len(items) % BODY.size == 0, len(items)
                body0 = BODY.unpack_from(items, 0)
                first_body = {
                    "run_id": h["run_id"],
                    "simulation": h["simulation"],
                    "step": h["step"],
                    "n": len(items) // BODY.size,
                    "x0": body0[6],
                    "x1": BODY.unpack_from(items, BODY.size)[6],
                }
    want_counts = expected["counts"]
    got_counts = {t: counts.get(t, 0) for t in want_counts}
    if got_counts != want_counts:
        sys.exit(f"counts differ: got {counts}, expected {want_counts}")
    want_body = expected["first_body"]
    if first_body is None or any(abs(first_body[k] - v) > 1e-6 for k, v in want_body.items()):
        sys.exit(f"first body frame differs: got {first_body}, expected {want_body}")
    if stats_models != {expected["stats_model"]}:
        sys.exit(f"stats model names: got {stats_models}, expected {{{expected['stats_model']!r}}} (text)")
    if run_start is None or any(run_start.get(k) != v for k, v in expected["run_start"].items()):
        sys.exit(f"run start details: got {run_start}, expected {expected['run_start']}")
    print(f"python read {sum(counts.values())} messages on {len(counts)} topics: ok")


if __name__ == "__main__":
    main()
