#!/usr/bin/env python3
"""Taps a live Deep Contact topic over zenoh and prints each frame's step (and, for solver
statistics, the sweeps).

usage: python3 python/subscribe.py --connect tcp/127.0.0.1:7447 [--key dc/NAMESPACE/stats/solve]
                                   [--count N] [--timeout SECONDS] [--json]

A graph publishes a topic on zenoh when its launch file says so (`[topics] "stats/solve" =
"zenoh"`, see launch/python-tap.toml); connect to the publishing node's endpoint
(`zenoh_port + its index` in a peer graph, or the router's). Exits 0 after --count frames, 1 when
none arrived within --timeout seconds.
"""
import argparse
import json
import queue
import sys
import time

import zenoh

from deep_contact import FrameError, decode, step_of


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", required=True, help="zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--key", default="dc/python-tap/stats/solve", help="dc/<namespace>/<topic>")
    parser.add_argument("--count", type=int, default=0, help="stop after this many frames (0: never)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for frames")
    parser.add_argument("--json", action="store_true", help="one JSON line per frame")
    args = parser.parse_args()
    topic = args.key.split("/", 2)[-1] if args.key.count("/") >= 2 else args.key

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    frames = queue.Queue()
    with zenoh.open(config) as session:
        session.declare_subscriber(args.key, lambda sample: frames.put(bytes(sample.payload.to_bytes())))
        got, deadline = 0, time.monotonic() + args.timeout
        while args.count == 0 or got < args.count:
            try:
                payload = frames.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                sys.exit(f"{args.key}: {got} frames within {args.timeout} s")
            try:
                header, items = decode(topic, payload)
            except FrameError as e:
                print(f"skipped a frame: {e}", file=sys.stderr)
                continue
            got += 1
            simulation, step = step_of(header)
            line = {"simulation": simulation, "step": step, "items": int(len(items))}
            if "sweeps" in header:
                line.update(model=header["model"], sweeps=header["sweeps"])
            print(json.dumps(line) if args.json else " ".join(f"{k}={v}" for k, v in line.items()), flush=True)


if __name__ == "__main__":
    main()
