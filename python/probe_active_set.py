#!/usr/bin/env python3
"""What knowing the active set buys once contacts are compliant: re-solves recorded late step
problems with the project's PGS made compliant (`dc-sim --compliance G`) from warm starts that
solve the step's linear problem exactly on a given active set, and prints sweeps vs builtin.

usage: python3 python/probe_active_set.py RECORDING.mcap [--compliance 0.01] [--limit 12]

Variants (each solved by compliant PGS to the recording's tolerance):
  builtin          the recorded warm start (the previous step's impulses)
  builtin-set      the exact compliant linear solution on builtin's active set
  true-set         the same on the exact solution's own active set (closed/open, stick/slip,
                   slip direction): with compliance that *is* the solution
  true-set-Kflips  the true set with K random row states wrong (stick <-> slip on a closed
                   contact, an open one taken as closed and sticking)
Record the problems with the same compliance (`launch/record-gnn-val-compliant.toml`, 0.01):
on a rigid run's recording builtin carries the rigid run's impulses and looks worse than it is.
"""
import argparse
import sys

import numpy as np

from deep_contact import FrameError
from probe_headroom import Problem, load


def states(p, impulses):
    """Closed, sticking and slip direction per contact of (normal, tangent) impulses."""
    closed = impulses[:, 0] > 1e-6
    stick = closed & (np.abs(impulses[:, 1]) < p.mu * impulses[:, 0] * (1 - 1e-4))
    return closed, stick, np.sign(impulses[:, 1])


def active_set_solution(p, compliance, closed, stick, sign):
    """The impulses that satisfy the compliant rows `u + G W_ii lambda = 0` of the closed normals
    and sticking tangents, sliding tangents at `sign mu normal`, open contacts at 0."""
    J, minv = p.jacobian()
    W = (J * minv) @ J.T
    u0 = J @ p.v0.reshape(-1)
    m = len(p.a)
    unknowns, equations = [], []
    for i in np.where(closed)[0]:
        z = np.zeros(2 * m)
        z[2 * i + 1] = 1.0
        equations.append(z.copy())
        if not stick[i]:
            z[2 * i] = sign[i] * p.mu[i]
        unknowns.append(z)
    for i in np.where(stick)[0]:
        z = np.zeros(2 * m)
        z[2 * i] = 1.0
        unknowns.append(z)
        equations.append(z)
    if not unknowns:
        return np.zeros((m, 2))
    Z, T = np.stack(unknowns, 1), np.stack(equations, 1)
    system = T.T @ (W + compliance * np.diag(np.diag(W))) @ Z
    y = np.linalg.lstsq(system, -T.T @ u0, rcond=1e-12)[0]
    return Problem.contacts_of(Z @ y)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--compliance", type=float, default=0.01)
    parser.add_argument("--from-step", type=int, default=150)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--limit", type=int, default=12, help="probe at most this many steps (0: all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random flips")
    args = parser.parse_args()
    try:
        bodies, contacts, keys, tolerance = load(args.recording, args.from_step, args.every)
    except (OSError, FrameError) as e:
        sys.exit(f"{args.recording}: {e}")
    if args.limit:
        keys = keys[: args.limit]
    if not keys:
        sys.exit(f"{args.recording}: no problem frames from step {args.from_step} (record with --publish-problem)")
    g, rng, totals = args.compliance, np.random.default_rng(args.seed), {}
    for key in keys:
        p = Problem(bodies[key], contacts[key])
        exact = np.zeros_like(p.previous)
        result = {"builtin": p.solve(p.previous, tolerance, compliance=g, out=exact)}
        p.solve(exact.copy(), 1e-8, cap=20000, compliance=g, out=exact)
        true = states(p, exact)
        result["builtin-set"] = p.solve(active_set_solution(p, g, *states(p, p.previous)), tolerance, compliance=g)
        result["true-set"] = p.solve(active_set_solution(p, g, *true), tolerance, compliance=g)
        for flips in (2, 5, 10):
            closed, stick, sign = (x.copy() for x in true)
            for i in rng.choice(len(closed), size=min(flips, len(closed)), replace=False):
                if closed[i]:
                    stick[i] = not stick[i]
                    sign[i] = sign[i] if sign[i] != 0 else 1.0
                else:
                    closed[i], stick[i] = True, True
            result[f"true-set-{flips}flips"] = p.solve(
                active_set_solution(p, g, closed, stick, sign), tolerance, compliance=g
            )
        for name, sweeps in result.items():
            totals[name] = totals.get(name, 0) + sweeps
    base = totals["builtin"]
    print(f"{len(keys)} steps (from step {args.from_step}, every {args.every}), tolerance {tolerance:g}, compliance {g:g}")
    print(f"{'variant':<18} {'sweeps':>8} {'vs builtin':>10}")
    for name, total in totals.items():
        print(f"{name:<18} {total:>8} {total / base:>9.3f}x")


if __name__ == "__main__":
    main()
