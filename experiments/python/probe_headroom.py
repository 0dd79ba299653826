#!/usr/bin/env python3
"""Where builtin's warm-start error costs sweeps: re-solves recorded step problems with the
project's PGS (f64, same row order and projections) from warm starts that fix one part of
builtin's error at a time, and prints the sweeps of each relative to builtin's.

usage: python3 experiments/python/probe_headroom.py RECORDING.mcap [--from-step 150] [--every 10] [--limit N]

The recording must carry labelled problems (`dc-sim --publish-problem --label-tolerance 2e-6`,
e.g. `dc launch launch/record-gnn-val.toml`). Variants (each then solved by PGS to the run's
tolerance; `cgK` counts its K conjugate-gradient iterations as sweeps):
  builtin            the recorded warm start (previous step's impulse)
  reference          the recorded exact solution (sanity: ~1 sweep)
  previous-exact     the previous step's exact solution (builtin if every solve were finished)
  normals / tangents the exact normal (tangent) impulses, builtin's others
  top10              the exact solution on the 10% of contacts with the largest error
  active-change      exact on contacts whose closed/open state changes
  slip-change        exact on contacts whose stick/slip state changes
  cg5, cg20, cg50    K conjugate-gradient iterations on builtin's active set, then PGS
  low20, low150      builtin corrected exactly within the K slowest linear modes of its active set
  prox1e-4, prox1e-3 builtin plus the exact regularised linear solve (W + a diag W) on its active set
  true-set           the exact linear solution on the reference's own active set (closed/open,
                     stick/slip with direction), least change from builtin
  physics            the reference's net impulse on every body (the step's exact outcome),
                     least change from builtin: only the choice among equivalent impulses left
The last six are exact global solves whose cost is not counted: an upper bound for any warm
start that corrects builtin by linear algebra on the step's problem.
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

# The product's frame decoder lives in the repository's python/ folder.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "python"))
from deep_contact import FrameError, decode, step_of  # noqa: E402


def load(path, from_step, every):
    bodies, contacts, tolerance = {}, {}, None
    with open(path, "rb") as f:
        for _s, channel, message in make_reader(f).iter_messages(topics=["problem/bodies", "problem/contacts"]):
            header, items = decode(channel.topic, message.data)
            key = step_of(header)
            if key[1] < from_step - 1:
                continue
            if channel.topic == "problem/bodies":
                bodies[key] = items
            else:
                contacts[key] = items
                tolerance = header["tolerance"]
    keys = [k for k in sorted(contacts) if k[1] >= from_step and (k[1] - from_step) % every == 0 and k in bodies]
    return bodies, contacts, keys, tolerance


class Problem:
    """One step's velocity problem: rows in the solver's order (tangent, then normal, per contact)."""

    def __init__(self, bodies, contacts):
        self.v0 = np.stack([bodies["v"][:, 0], bodies["v"][:, 1], bodies["w"]], 1).astype(np.float64)
        self.inv_m = bodies["inv_mass"].astype(np.float64)
        self.inv_i = bodies["inv_inertia"].astype(np.float64)
        self.a, self.b = contacts["body_a"].astype(int), contacts["body_b"].astype(int)
        self.ra, self.rb = contacts["ra"].astype(np.float64), contacts["rb"].astype(np.float64)
        self.n = contacts["normal"].astype(np.float64)
        self.t = np.stack([self.n[:, 1], -self.n[:, 0]], 1)
        self.mu = contacts["friction"].astype(np.float64)
        self.previous = contacts["previous"].astype(np.float64)
        self.reference = contacts["reference"].astype(np.float64)
        self.keys = list(zip(contacts["body_a"].tolist(), contacts["body_b"].tolist(), contacts["feature"].tolist()))
        self.mass_n, self.mass_t = self._mass(self.n), self._mass(self.t)

    def _mass(self, d):
        cross = lambda r: r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]
        k = (self.inv_m[self.a] + self.inv_m[self.b] + self.inv_i[self.a] * cross(self.ra) ** 2
             + self.inv_i[self.b] * cross(self.rb) ** 2)
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), 0.0)

    def jacobian(self):
        m, nb = len(self.a), len(self.inv_m)
        J = np.zeros((2 * m, 3 * nb))
        for i in range(m):
            for k, d in ((0, self.t[i]), (1, self.n[i])):
                r = 2 * i + k
                a, b, ra, rb = self.a[i], self.b[i], self.ra[i], self.rb[i]
                J[r, 3 * a:3 * a + 2] -= d
                J[r, 3 * a + 2] -= ra[0] * d[1] - ra[1] * d[0]
                J[r, 3 * b:3 * b + 2] += d
                J[r, 3 * b + 2] += rb[0] * d[1] - rb[1] * d[0]
        minv = np.stack([self.inv_m, self.inv_m, self.inv_i], 1).reshape(-1)
        return J, minv

    def solve(self, start, tolerance, cap=1000, compliance=0.0, out=None):
        """Sweeps of projected Gauss-Seidel from `start` ((normal, tangent) per contact); with
        `compliance` G each row's update is the rigid one over 1 + G (`dc-sim --compliance`);
        the final impulses are written to `out` when given."""
        soft = 1.0 / (1.0 + compliance)
        v = [list(x) for x in self.v0]
        im, ii = self.inv_m, self.inv_i
        rows = list(zip(self.a.tolist(), self.b.tolist(), self.ra.tolist(), self.rb.tolist(), self.n.tolist(),
                        self.t.tolist(), self.mu.tolist(), self.mass_n.tolist(), self.mass_t.tolist()))
        lam = []

        def apply(a, b, ra, rb, px, py):
            va, vb = v[a], v[b]
            va[0] -= px * im[a]; va[1] -= py * im[a]; va[2] -= ii[a] * (ra[0] * py - ra[1] * px)
            vb[0] += px * im[b]; vb[1] += py * im[b]; vb[2] += ii[b] * (rb[0] * py - rb[1] * px)

        for (a, b, ra, rb, n, t, mu, _, _), s in zip(rows, start):
            ln = max(float(s[0]), 0.0)
            lt = min(max(float(s[1]), -mu * ln), mu * ln)
            lam.append([ln, lt])
            apply(a, b, ra, rb, n[0] * ln + t[0] * lt, n[1] * ln + t[1] * lt)
        for sweep in range(1, cap + 1):
            residual = 0.0
            for (a, b, ra, rb, n, t, mu, mn, mt), l in zip(rows, lam):
                for k, d, mass in ((1, t, mt), (0, n, mn)):
                    va, vb = v[a], v[b]
                    dvx = vb[0] - vb[2] * rb[1] - va[0] + va[2] * ra[1]
                    dvy = vb[1] + vb[2] * rb[0] - va[1] - va[2] * ra[0]
                    new = (l[k] - mass * (dvx * d[0] + dvy * d[1])) * soft
                    new = min(max(new, -mu * l[0]), mu * l[0]) if k == 1 else max(new, 0.0)
                    change = new - l[k]
                    l[k] = new
                    apply(a, b, ra, rb, d[0] * change, d[1] * change)
                    residual = max(residual, abs(change))
            if residual <= tolerance:
                break
        if out is not None:
            out[:] = np.array(lam)
        return min(sweep, cap)

    def builtin_rows(self):
        """builtin projected onto the friction cone, as solver rows (tangent, normal per contact),
        its active set (closed normals, sticking tangents), W = J M^-1 J^T and the free velocity."""
        J, minv = self.jacobian()
        W = (J * minv) @ J.T
        u0 = J @ self.v0.reshape(-1)
        lam = np.empty(2 * len(self.a))
        lam[1::2] = np.maximum(self.previous[:, 0], 0.0)
        lam[0::2] = np.clip(self.previous[:, 1], -self.mu * lam[1::2], self.mu * lam[1::2])
        closed = lam[1::2] > 0
        active = np.zeros(len(lam), bool)
        active[1::2] = closed
        active[0::2] = closed & (np.abs(lam[0::2]) < self.mu * lam[1::2] * 0.999)
        return lam, active, W, u0

    @staticmethod
    def contacts_of(lam):
        return np.stack([lam[1::2], lam[0::2]], 1)

    def cg_start(self, iterations):
        """builtin, then `iterations` CG steps on its active set (closed normals, sticking tangents)."""
        lam, active, W, u0 = self.builtin_rows()
        rhs = -(u0 + W @ np.where(active, 0.0, lam))[active]
        Waa = W[np.ix_(active, active)]
        x = lam[active]
        r = rhs - Waa @ x
        d, rr = r.copy(), r @ r
        for _ in range(iterations):
            if rr < 1e-30:
                break
            Wd = Waa @ d
            alpha = rr / (d @ Wd)
            x, r = x + alpha * d, r - alpha * Wd
            rn = r @ r
            d, rr = r + (rn / rr) * d, rn
        lam[active] = x
        return self.contacts_of(lam)

    def prox_start(self, regularisation):
        """builtin plus the exact solution of (W_aa + a diag(W_aa)) y = -u on its active set: a
        global linear solve that does not chase the near-null modes (uncounted)."""
        lam, active, W, u0 = self.builtin_rows()
        Waa = W[np.ix_(active, active)]
        r = -(u0 + W @ lam)[active]
        lam[active] += np.linalg.solve(Waa + regularisation * np.diag(np.diag(Waa)), r)
        return self.contacts_of(lam)

    def low_modes_start(self, k):
        """builtin corrected exactly (Galerkin) within the k lowest non-null modes of the
        diagonally scaled W on its active set: the smooth, slow error (uncounted)."""
        lam, active, W, u0 = self.builtin_rows()
        if not active.any():
            return self.contacts_of(lam)
        Waa = W[np.ix_(active, active)]
        d = np.sqrt(np.maximum(np.diag(Waa), 1e-30))
        w, V = np.linalg.eigh(Waa / d[:, None] / d[None, :])
        Z = V[:, np.where(w > 1e-8 * w.max())[0][:k]] / d[:, None]
        r = -(u0 + W @ lam)[active]
        lam[active] += Z @ np.linalg.lstsq(Z.T @ Waa @ Z, Z.T @ r, rcond=1e-10)[0]
        return self.contacts_of(lam)

    def physics_start(self):
        """builtin moved, by the least change (in each row's own scale, diag W), to impulses whose
        net effect on every body equals the reference's: the step's exact outcome (velocities)
        known, the choice among the impulses that produce it left at builtin's (uncounted)."""
        J, minv = self.jacobian()
        lam, _, _, _ = self.builtin_rows()
        reference = np.empty_like(lam)
        reference[0::2], reference[1::2] = self.reference[:, 1], self.reference[:, 0]
        moves = (minv > 0) & (np.abs(J).sum(0) > 0)
        if not moves.any():
            return self.contacts_of(lam)
        Js = J[:, moves]
        scale = 1.0 / np.maximum(((J * minv) * J).sum(1), 1e-12)
        body = (Js.T * scale) @ Js
        y = np.linalg.lstsq(body, Js.T @ (reference - lam), rcond=1e-12)[0]
        return self.contacts_of(lam + scale * (Js @ y))

    def active_set_columns(self, closed, stick, sign):
        """The linear problem of an active set, as solver-row vectors: per closed contact its
        normal unknown (a sliding one drags its tangent along at `sign mu`), per sticking one its
        tangent unknown (Z); and the rows that must hold there, closed normals and sticking
        tangents (T). `None` when nothing is active."""
        m = len(self.a)
        unknowns, equations = [], []
        for i in np.where(closed)[0]:
            z = np.zeros(2 * m)
            z[2 * i + 1] = 1.0
            equations.append(z.copy())
            if not stick[i]:
                z[2 * i] = sign[i] * self.mu[i]
            unknowns.append(z)
        for i in np.where(stick)[0]:
            z = np.zeros(2 * m)
            z[2 * i] = 1.0
            unknowns.append(z)
            equations.append(z)
        return (np.stack(unknowns, 1), np.stack(equations, 1)) if unknowns else None

    def true_set_start(self):
        """builtin moved, by the least change, onto a solution of the linear problem of the
        reference's own active set (closed / open, sticking / sliding with its direction): what
        knowing the exact active set buys (uncounted)."""
        lam0, _, W, u0 = self.builtin_rows()
        closed = self.reference[:, 0] > 1e-7
        stick = closed & (np.abs(self.reference[:, 1]) < self.mu * self.reference[:, 0] * 0.999)
        sign = np.sign(self.reference[:, 1])
        x0 = np.zeros(2 * len(self.a))
        x0[1::2] = np.where(closed, lam0[1::2], 0.0)
        x0[0::2] = np.where(stick, lam0[0::2], np.where(closed, sign * self.mu * x0[1::2], 0.0))
        problem = self.active_set_columns(closed, stick, sign)
        if problem is None:
            return self.contacts_of(x0)
        Z, _ = problem
        y = np.linalg.lstsq(Z.T @ W @ Z, -Z.T @ (u0 + W @ x0), rcond=1e-12)[0]
        return self.contacts_of(x0 + Z @ y)


def variants(p, previous_reference):
    prev, ref = p.previous, p.reference
    error = ((ref - prev) ** 2).sum(1)
    top = np.zeros(len(prev), bool)
    top[np.argsort(-error)[: max(len(prev) // 10, 1)]] = True
    closed = lambda x: x[:, 0] > 1e-7
    sliding = lambda x: closed(x) & (np.abs(x[:, 1]) >= p.mu * x[:, 0] * 0.999)

    def fix(mask, columns=(0, 1)):
        start = prev.copy()
        for c in columns:
            start[mask, c] = ref[mask, c]
        return start

    everywhere = np.ones(len(prev), bool)
    yield "builtin", prev, 0
    yield "reference", ref, 0
    yield "previous-exact", previous_reference, 0
    yield "normals", fix(everywhere, (0,)), 0
    yield "tangents", fix(everywhere, (1,)), 0
    yield "top10", fix(top), 0
    yield "active-change", fix(closed(prev) != closed(ref)), 0
    yield "slip-change", fix(sliding(prev) != sliding(ref)), 0
    for k in (5, 20, 50):
        yield f"cg{k}", p.cg_start(k), k
    # Exact global linear solves, their cost not counted: what linear algebra could buy at best.
    for k in (20, 150):
        yield f"low{k}", p.low_modes_start(k), 0
    for a in (1e-4, 1e-3):
        yield f"prox{a:g}", p.prox_start(a), 0
    yield "true-set", p.true_set_start(), 0
    yield "physics", p.physics_start(), 0


def probe_arguments(doc, limit=0):
    """The arguments every probe takes: a recording, which late steps, how many."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--from-step", type=int, default=150, help="first step probed (the late phase)")
    parser.add_argument("--every", type=int, default=10, help="probe every k-th step")
    parser.add_argument("--limit", type=int, default=limit, help="probe at most this many steps (0: all)")
    return parser


def load_probed(args):
    """The recording's problems and the keys of the steps to probe; exits naming the file when
    it does not read or holds no problem there."""
    try:
        bodies, contacts, keys, tolerance = load(args.recording, args.from_step, args.every)
    except (OSError, FrameError) as e:
        sys.exit(f"{args.recording}: {e}")
    if args.limit:
        keys = keys[: args.limit]
    if not keys:
        sys.exit(f"{args.recording}: no problem frames from step {args.from_step} (record with --publish-problem)")
    return bodies, contacts, keys, tolerance


def print_totals(totals, width):
    """Each variant's sweeps and their ratio to builtin's."""
    base = totals["builtin"]
    print(f"{'variant':<{width}} {'sweeps':>8} {'vs builtin':>10}")
    for name, total in totals.items():
        print(f"{name:<{width}} {total:>8} {total / base:>9.3f}x")


def main():
    args = probe_arguments(__doc__).parse_args()
    bodies, contacts, keys, tolerance = load_probed(args)
    if np.isnan(contacts[keys[0]]["reference"]).any():
        sys.exit(f"{args.recording}: problems carry no reference solution (record with --label-tolerance)")
    totals = {}
    for key in keys:
        p = Problem(bodies[key], contacts[key])
        before = contacts.get((key[0], key[1] - 1))
        by_key = {} if before is None else {
            k: r for k, r in zip(zip(before["body_a"].tolist(), before["body_b"].tolist(), before["feature"].tolist()),
                                 before["reference"].astype(np.float64))}
        previous_reference = np.array([by_key.get(k, (0.0, 0.0)) for k in p.keys]).reshape(-1, 2)
        for name, start, extra in variants(p, previous_reference):
            totals[name] = totals.get(name, 0) + p.solve(start, tolerance) + extra
    print(f"{len(keys)} steps (from step {args.from_step}, every {args.every}), tolerance {tolerance:g}")
    print_totals(totals, 16)


if __name__ == "__main__":
    main()
