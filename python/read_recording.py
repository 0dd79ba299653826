#!/usr/bin/env python3
"""Reads a Deep Contact recording into numpy arrays: per step its bodies, contacts and solver
statistics.

usage: python3 python/read_recording.py RECORDING.mcap [--json]

Prints one line per simulation (steps, bodies, mean contacts, total sweeps); with --json, one JSON
summary (what the repository's test compares with the Rust reader).
"""
import argparse
import json
import sys

import numpy as np
from mcap.reader import make_reader

from deep_contact import FrameError, decode, step_of


def load(path):
    """{simulation: {"bodies": [array per step], "contacts": [...], "sweeps": array, "model": name}}."""
    sims = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(topics=["bodies", "contacts", "stats/solve"]):
            header, items = decode(channel.topic, message.data)
            simulation, step = step_of(header)
            sim = sims.setdefault(simulation, {"bodies": {}, "contacts": {}, "sweeps": {}, "model": None})
            if channel.topic == "stats/solve":
                sim["sweeps"][step] = header["sweeps"]
                sim["model"] = header["model"]
            else:
                sim[channel.topic][step] = items
    # Steps in order; sweeps as one array.
    for sim in sims.values():
        for topic in ("bodies", "contacts"):
            sim[topic] = [sim[topic][k] for k in sorted(sim[topic])]
        sim["sweeps"] = np.array([sim["sweeps"][k] for k in sorted(sim["sweeps"])], dtype=np.int64)
    return sims


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--json", action="store_true", help="print one JSON summary")
    args = parser.parse_args()
    try:
        sims = load(args.recording)
    except (OSError, FrameError) as e:
        sys.exit(f"{args.recording}: {e}")
    summary = {}
    for simulation, sim in sorted(sims.items()):
        positions = np.stack([np.stack([b["x"], b["y"]], -1) for b in sim["bodies"]])
        summary[str(simulation)] = {
            "steps": len(sim["bodies"]),
            "bodies": int(positions.shape[1]),
            "contacts": int(sum(len(c) for c in sim["contacts"])),
            "sweeps": int(sim["sweeps"].sum()),
            "model": sim["model"],
            "mean_height": float(positions[-1, :, 1].mean()),
        }
        if not args.json:
            s = summary[str(simulation)]
            print(f"simulation {simulation}: {s['steps']} steps of {s['bodies']} bodies, "
                  f"{s['contacts'] / max(s['steps'], 1):.1f} contacts a step, {s['sweeps']} sweeps ({s['model']})")
    if args.json:
        print(json.dumps(summary, sort_keys=True))


if __name__ == "__main__":
    main()
