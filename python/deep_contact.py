"""Deep Contact frames in Python: the wire format the Rust `msgs` crate defines, decoded and
encoded; recorded step problems as numpy arrays for training; and `serve(predict)`, which runs a
Python function as an external warm-start model of a graph (docs/external.md).

A frame is CBOR `{"v": wire version, "h": header map, "i": items}`: the items are one byte string
of packed little-endian records (bodies, contacts, problem rows), or an array of floats (grids,
residuals). Recordings are MCAP files with one channel per topic (`message_encoding = "cbor"`);
live frames travel on zenoh keys `dc/<namespace>/<topic>`.
"""
import os
import sys

import cbor2
import numpy as np

WIRE_VERSIONS = (1, 2, 3)

# Packed item layouts (numpy structured dtypes, little-endian, as `#[repr(C)]` in msgs).
BODY = np.dtype([("id", "<u4"), ("shape", "<u4"), ("size", "<f4", 2), ("mass", "<f4"), ("inertia", "<f4"),
                 ("x", "<f4"), ("y", "<f4"), ("angle", "<f4"), ("vx", "<f4"), ("vy", "<f4"), ("omega", "<f4")])
CONTACT = np.dtype([("body_a", "<u4"), ("body_b", "<u4"), ("feature", "<u4"), ("x", "<f4"), ("y", "<f4"),
                    ("nx", "<f4"), ("ny", "<f4"), ("penetration", "<f4"), ("friction", "<f4"),
                    ("normal_impulse", "<f4"), ("tangent_impulse", "<f4")])
PROBLEM_BODY = np.dtype([("v", "<f4", 2), ("w", "<f4"), ("inv_mass", "<f4"), ("inv_inertia", "<f4")])
PROBLEM_CONTACT = np.dtype([("body_a", "<u4"), ("body_b", "<u4"), ("feature", "<u4"), ("age", "<u4"),
                            ("ra", "<f4", 2), ("rb", "<f4", 2), ("normal", "<f4", 2), ("friction", "<f4"),
                            ("penetration", "<f4"), ("previous", "<f4", 2), ("before_previous", "<f4", 2),
                            ("reference", "<f4", 2), ("height", "<f4")])
# Wire versions 1 and 2: problem contacts without the height (their first 72 bytes).
PROBLEM_CONTACT_V2 = np.dtype(PROBLEM_CONTACT.descr[:-1])

ITEM_TYPES = {
    "bodies": BODY,
    "contacts": CONTACT,
    "problem/bodies": PROBLEM_BODY,
    "problem/contacts": PROBLEM_CONTACT,
    "warm/gnn": CONTACT,
    "warm/external": CONTACT,
}


class FrameError(ValueError):
    """A payload that is not a Deep Contact frame (names the topic and what is wrong)."""


def decode(topic, payload):
    """One frame of `topic` -> (header dict, items: numpy array). Raises FrameError on bad input."""
    try:
        frame = cbor2.loads(payload)
    except Exception as e:  # cbor2 raises several types for malformed input
        raise FrameError(f"{topic}: not CBOR: {e}") from e
    if not isinstance(frame, dict) or set(frame) != {"v", "h", "i"}:
        raise FrameError(f"{topic}: not a frame (keys {sorted(frame) if isinstance(frame, dict) else type(frame)})")
    if frame["v"] not in WIRE_VERSIONS:
        raise FrameError(f"{topic}: wire version {frame['v']} (this reader knows {WIRE_VERSIONS})")
    header, items = frame["h"], frame["i"]
    dtype = ITEM_TYPES.get(topic)
    if dtype is PROBLEM_CONTACT and frame["v"] < 3:
        dtype = PROBLEM_CONTACT_V2
    if dtype is not None:
        if len(items) % dtype.itemsize:
            raise FrameError(f"{topic}: {len(items)} item bytes is not a multiple of {dtype.itemsize}")
        return header, np.frombuffer(items, dtype=dtype)
    if isinstance(items, (bytes, bytearray)):
        return header, np.frombuffer(items, dtype=np.uint8)
    return header, np.asarray(items, dtype=np.float32)


def step_of(header):
    """(simulation, step) of a frame header (problem/contacts nests it under "step")."""
    h = header.get("step", header) if isinstance(header.get("step"), dict) else header
    return h["simulation"], h["step"]


# --- Writing frames -------------------------------------------------------------------------

WIRE_VERSION = 3


def encode(header, items):
    """A frame as the Rust `msgs::encode` writes it: CBOR `{"v", "h", "i"}` in this order, the
    items a numpy structured array (packed records) or a float array (grids)."""
    items = np.ascontiguousarray(items)
    payload = items.tobytes() if items.dtype.names else items.astype("<f4").tolist()
    return cbor2.dumps({"v": WIRE_VERSION, "h": header, "i": payload})


# Control frames: the header's `kind` (msgs::ControlKind); a run start's items are CBOR of its
# parameters (`model` among them).
RUN_START, RUN_END, SIMULATION_START, SIMULATION_END, SHUTDOWN, NODE_DOWN, NODE_UP = range(1, 8)


# --- Reading recorded problems for training ---------------------------------------------------

class Problem:
    """One step's contact problem as the simulator publishes it (`problem/bodies` and
    `problem/contacts`): `header` (the contacts' header: tolerance, solver, ...), `bodies`
    (PROBLEM_BODY records) and `contacts` (PROBLEM_CONTACT records: keys, geometry, `previous`
    = builtin's warm start, and in a labelled recording `reference` = the step's solution)."""

    def __init__(self, header, bodies, contacts):
        self.header, self.bodies, self.contacts = header, bodies, contacts

    @property
    def key(self):
        """(run_id, simulation, step)."""
        s = self.header["step"]
        return s["run_id"], s["simulation"], s["step"]

    @property
    def labelled(self):
        """Whether `contacts["reference"]` holds the step's solution (a labelled recording)."""
        return self.header.get("reference_tolerance", 0) > 0


class _Pairer:
    """Pairs each step's `problem/bodies` and `problem/contacts` frames (either may come first),
    keeping a bounded number of unpaired steps."""

    def __init__(self, keep=256):
        self.pending, self.keep = {}, keep

    def add(self, topic, header, items):
        if topic == "problem/bodies":
            key = (header["run_id"], header["simulation"], header["step"])
            part = {"bodies": items}
        else:
            s = header["step"]
            key = (s["run_id"], s["simulation"], s["step"])
            part = {"header": header, "contacts": items}
        entry = self.pending.setdefault(key, {})
        entry.update(part)
        if len(entry) == 3:
            del self.pending[key]
            return Problem(entry["header"], entry["bodies"], entry["contacts"])
        while len(self.pending) > self.keep:
            self.pending.pop(next(iter(self.pending)))
        return None


def load_problems(path, labelled_only=True):
    """The step problems of a recording (`dc record` of a graph whose simulator publishes them,
    e.g. `--publish-problem --label-tolerance 2e-6`), in recording order; only the labelled ones
    (with the step's solution) unless `labelled_only` is false. Raises FrameError on bad frames."""
    from mcap.reader import make_reader

    pairer, out = _Pairer(), []
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(topics=["problem/bodies", "problem/contacts"]):
            header, items = decode(channel.topic, message.data)
            problem = pairer.add(channel.topic, header, items)
            if problem is not None and (problem.labelled or not labelled_only):
                out.append(problem)
    return out


# --- Serving a model: the external-model contract (docs/external.md) ---------------------------

CONTRACT_VERSION = 1  # msgs::models::EXTERNAL_CONTRACT_VERSION
EXTERNAL_TOPIC = "warm/external"
SERVER_SUBSCRIBES = ("control", "problem/bodies", "problem/contacts")
PORTS_MARKER, READY_MARKER, CONNECTED_MARKER = "\x1edc-ports ", "\x1edc-ready", "\x1edc-connected"


def _zenoh_config(bus):
    import json

    import zenoh

    z = bus.get("zenoh", {})
    mode = z.get("mode") or "peer"
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("connect/endpoints", json.dumps(z.get("connect", [])))
    config.insert_json5("scouting/multicast/enabled", "false")
    tls = z.get("tls")
    if mode == "client":
        config.insert_json5("connect/timeout_ms", "120000")
    else:
        scheme = "tls" if tls else "tcp"
        config.insert_json5("listen/endpoints", json.dumps(z.get("listen") or [f"{scheme}/127.0.0.1:0"]))
    if tls:
        for key, value in (("root_ca_certificate", tls["ca"]), ("listen_certificate", tls["cert"]),
                           ("listen_private_key", tls["key"]), ("connect_certificate", tls["cert"]),
                           ("connect_private_key", tls["key"])):
            config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
        config.insert_json5("transport/link/tls/enable_mtls", json.dumps(bool(tls.get("mutual"))))
        config.insert_json5("transport/link/tls/verify_name_on_connect", "true")
    return config


def _say(line):
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def _wait_for_line(expected):
    for line in sys.stdin:
        if line.strip() == expected:
            return True
    return False


def reply_frame(problem, impulses):
    """The reply to `problem`: its contacts (keys in the problem's order) with `impulses`
    ((n, 2): normal, tangent), as a `warm/external` frame."""
    impulses = np.asarray(impulses, dtype=np.float64)
    n = len(problem.contacts)
    if impulses.shape != (n, 2):
        raise ValueError(f"the model returned impulses of shape {impulses.shape} for {n} contacts; expected ({n}, 2)")
    if not np.isfinite(impulses).all():
        raise ValueError(f"the model returned non-finite impulses for step {problem.key}")
    out = np.zeros(n, dtype=CONTACT)
    c = problem.contacts
    for field in ("body_a", "body_b", "feature", "penetration", "friction"):
        out[field] = c[field]
    out["nx"], out["ny"] = c["normal"][:, 0], c["normal"][:, 1]
    out["normal_impulse"], out["tangent_impulse"] = impulses[:, 0], impulses[:, 1]
    run_id, simulation, step = problem.key
    return encode({"run_id": run_id, "simulation": simulation, "step": step}, out)


def serve(predict, name=None):
    """Runs `predict` as the server of the external model `name` (default: the name dc gave
    this node, `DC_EXTERNAL_MODEL`): for each step's problem of a run of that model,
    `predict(problem)` returns the warm start, (n, 2) normal and tangent impulses for the
    problem's n contacts in their order, and it goes back to the simulator on `warm/external`.

    Meant to be started by dc as a node of the graph (`dc eval --models external:NAME --serve
    "python3 my_model.py"`): dc says where the graph is (`DC_BUS`) and when to start. A reply
    later than the simulator's deadline is not used (builtin stands in, counted); an exception
    in `predict` stops the server with an `error:` line, which dc reports under the node's name.
    """
    import json
    import queue
    import threading

    if os.environ.get("DC_DESCRIBE") == "1":
        _say(PORTS_MARKER + json.dumps({"publishes": [EXTERNAL_TOPIC], "subscribes": list(SERVER_SUBSCRIBES)}))
        return
    if os.environ.get("DC_VALIDATE") == "1":
        return
    import zenoh

    name = name or os.environ.get("DC_EXTERNAL_MODEL")
    if "DC_BUS" not in os.environ:
        raise SystemExit("error: run this server as a node of a graph: "
                         "dc eval --models external:NAME --serve \"python3 <this script>\"")
    bus = json.loads(os.environ["DC_BUS"])
    prefix = f"dc/{bus['namespace']}/" if bus.get("namespace") else "dc/"
    inbox = queue.Queue()
    with zenoh.open(_zenoh_config(bus)) as session:
        zid = str(session.zid())
        subscribers, tokens = [], []
        for i, topic in enumerate(SERVER_SUBSCRIBES):
            key = prefix + topic
            subscribers.append(session.declare_subscriber(
                key, lambda sample, topic=topic: inbox.put((topic, bytes(sample.payload.to_bytes())))))
            # Announced after the subscriber exists: the simulator's publisher waits for it.
            tokens.append(session.liveliness().declare_token(f"{key}/_readers/{zid}/{i}"))
        key = prefix + EXTERNAL_TOPIC
        publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        tokens.append(session.liveliness().declare_token(f"{key}/_writers/{zid}/{len(tokens)}/reliable"))
        if os.environ.get("DC_LAUNCHED") == "1":
            _say(READY_MARKER)
            if not _wait_for_line("connect"):
                return
            _say(CONNECTED_MARKER)
            if not _wait_for_line("start"):
                return

            def stdin_closed():
                for _ in sys.stdin:
                    pass
                inbox.put(("", None))  # the launcher closed stdin: the graph is stopping

            threading.Thread(target=stdin_closed, daemon=True).start()
        runs, pairer, served = {}, _Pairer(), 0
        while True:
            topic, payload = inbox.get()
            if payload is None:
                break
            try:
                header, items = decode(topic, payload)
            except FrameError as e:
                print(f"WARN skipped a frame: {e}", file=sys.stderr, flush=True)
                continue
            if topic == "control":
                if header["kind"] == RUN_START:
                    runs[header["step"]["run_id"]] = cbor2.loads(bytes(items))["model"]
                elif header["kind"] == SHUTDOWN:
                    break
                continue
            problem = pairer.add(topic, header, items)
            # Another model's problems (a graph with several servers, --publish-problem) are not ours.
            if problem is None or runs.get(problem.key[0], name) != name:
                continue
            publisher.put(reply_frame(problem, predict(problem)))
            served += 1
        print(f"INFO {name}: served {served} steps", file=sys.stderr, flush=True)
        del subscribers, tokens


def main_guard(run):
    """Runs `run()`, turning an exception into one `error: ...` line on stderr and exit status
    1 (what dc reports under the node's name), without a traceback."""
    try:
        run()
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as e:  # a server's failure, said in one line
        sys.exit(f"error: {type(e).__name__}: {e}")
