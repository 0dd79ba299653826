#!/usr/bin/env python3
"""An external warm-start model in numpy: builtin's start (each contact's previous impulse) plus
a per-contact correction, linear in a few features of the contact, fitted by least squares on a
labelled recording. It shows the three steps of docs/python.md:

  # train: fit the correction on recorded problems with their solutions (training seeds)
  python3 python/serve_example.py --fit recordings/py/train.mcap --out models/py-correction.json
  # serve and judge: dc starts this script as a node of the evaluation graph
  dc eval --models builtin,external:py --serve "python3 python/serve_example.py"

Served, it reads the coefficients from --coefficients (default: the repository's
models/py-correction.json); with --builtin it returns builtin's start unchanged, which must
cost exactly builtin's sweeps (the contract's own check).
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from deep_contact import load_problems, main_guard, serve  # noqa: E402

DEFAULT_COEFFICIENTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "models", "py-correction.json")
FEATURES = ["one", "previous normal", "previous tangent", "new contact", "penetration", "height",
            "change of the normal", "change of the tangent"]


def features(problem):
    """(n, len(FEATURES)) features of the problem's contacts: only what the simulator knows
    before the solve (never the reference)."""
    c = problem.contacts
    prev, before = c["previous"].astype(np.float64), c["before_previous"].astype(np.float64)
    new = (c["age"] == 0).astype(np.float64)
    return np.column_stack([np.ones(len(c)), prev[:, 0], prev[:, 1], new, c["penetration"], c["height"],
                            prev[:, 0] - before[:, 0], prev[:, 1] - before[:, 1]])


def fit(recording, out):
    problems = load_problems(recording)
    if not problems:
        raise ValueError(f"{recording}: no labelled problems (record with --publish-problem --label-tolerance 2e-6)")
    x = np.concatenate([features(p) for p in problems])
    y = np.concatenate([p.contacts["reference"].astype(np.float64) - p.contacts["previous"] for p in problems])
    # Ridge-regularised least squares: a feature that never varies gets no weight.
    lam = 1e-6 * len(x)
    w = np.linalg.solve(x.T @ x + lam * np.eye(x.shape[1]), x.T @ y)
    before, after = np.sqrt((y ** 2).mean()), np.sqrt(((y - x @ w) ** 2).mean())
    with open(out, "w") as f:
        json.dump({"features": FEATURES, "weights": w.tolist(), "trained_on": os.path.basename(recording),
                   "contacts": len(x), "rms_error_builtin": before, "rms_error_fitted": after}, f, indent=1)
    print(f"{out}: {len(problems)} steps, {len(x)} contacts; RMS error to the solution "
          f"{before:.4g} (builtin) -> {after:.4g} (fitted)")


def predictor(coefficients, builtin_only):
    if builtin_only:
        return lambda p: p.contacts["previous"]
    with open(coefficients) as f:
        spec = json.load(f)
    if spec.get("features") != FEATURES:
        raise ValueError(f"{coefficients}: made for features {spec.get('features')}, this script has {FEATURES}")
    w = np.asarray(spec["weights"], dtype=np.float64)

    def predict(problem):
        c = problem.contacts
        start = c["previous"] + features(problem) @ w
        # Inside the friction law, as a solver's projection would put it.
        start[:, 0] = np.maximum(start[:, 0], 0.0)
        bound = c["friction"] * start[:, 0]
        start[:, 1] = np.clip(start[:, 1], -bound, bound)
        return start

    return predict


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit", metavar="RECORDING", help="fit the correction on a labelled recording and exit")
    parser.add_argument("--out", default=DEFAULT_COEFFICIENTS, help="where --fit writes the coefficients")
    parser.add_argument("--coefficients", default=DEFAULT_COEFFICIENTS, help="the fitted correction to serve")
    parser.add_argument("--builtin", action="store_true", help="serve builtin's start unchanged")
    args = parser.parse_args()
    if args.fit:
        fit(args.fit, args.out)
    else:
        serve(predictor(args.coefficients, args.builtin))


if __name__ == "__main__":
    main_guard(main)
