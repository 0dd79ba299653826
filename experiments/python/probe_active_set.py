#!/usr/bin/env python3
"""What knowing the active set buys once contacts are compliant: re-solves recorded late step
problems with the project's PGS made compliant (`dc-sim --compliance G`) from warm starts that
solve the step's linear problem exactly on a given active set, and prints sweeps vs builtin.

usage: python3 experiments/python/probe_active_set.py RECORDING.mcap [--compliance 0.01] [--limit 12]

Variants (each solved by compliant PGS to the recording's tolerance):
  builtin          the recorded warm start (the previous step's impulses)
  builtin-set      the exact compliant linear solution on builtin's active set
  true-set         the same on the exact solution's own active set (closed/open, stick/slip,
                   slip direction): with compliance that *is* the solution
  true-set-Kflips  the true set with K random row states wrong (stick <-> slip on a closed
                   contact, an open one taken as closed and sticking)
Record the problems with the same compliance
(`dc launch experiments/launch/record-gnn-val-compliant.toml`, 0.01): on a rigid run's recording
builtin carries the rigid run's impulses and looks worse than it is.
"""
import numpy as np

from probe_headroom import Problem, load_probed, print_totals, probe_arguments


def states(p, impulses):
    """Closed, sticking and slip direction per contact of (normal, tangent) impulses."""
    closed = impulses[:, 0] > 1e-6
    stick = closed & (np.abs(impulses[:, 1]) < p.mu * impulses[:, 0] * (1 - 1e-4))
    return closed, stick, np.sign(impulses[:, 1])


def active_set_solution(p, compliance, closed, stick, sign):
    """The impulses that satisfy the compliant rows `u + G W_ii lambda = 0` of the closed normals
    and sticking tangents, sliding tangents at `sign mu normal`, open contacts at 0."""
    problem = p.active_set_columns(closed, stick, sign)
    if problem is None:
        return np.zeros((len(p.a), 2))
    Z, T = problem
    J, minv = p.jacobian()
    W = (J * minv) @ J.T
    u0 = J @ p.v0.reshape(-1)
    system = T.T @ (W + compliance * np.diag(np.diag(W))) @ Z
    y = np.linalg.lstsq(system, -T.T @ u0, rcond=1e-12)[0]
    return Problem.contacts_of(Z @ y)


def main():
    parser = probe_arguments(__doc__, limit=12)
    parser.add_argument("--compliance", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=0, help="seed of the random flips")
    args = parser.parse_args()
    bodies, contacts, keys, tolerance = load_probed(args)
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
    print(f"{len(keys)} steps (from step {args.from_step}, every {args.every}), tolerance {tolerance:g}, compliance {g:g}")
    print_totals(totals, 18)


if __name__ == "__main__":
    main()
