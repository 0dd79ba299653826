"""Decoding Deep Contact frames in Python: the wire format the Rust `msgs` crate defines.

A frame is CBOR `{"v": wire version, "h": header map, "i": items}`: the items are one byte string
of packed little-endian records (bodies, contacts, problem rows), or an array of floats (grids,
residuals). Recordings are MCAP files with one channel per topic (`message_encoding = "cbor"`);
live frames travel on zenoh keys `dc/<namespace>/<topic>`.
"""
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
