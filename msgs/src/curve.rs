//! Where an accuracy sits on a reference curve: the real-time regime's one piece of arithmetic,
//! shared by the simulator's budget study and the launcher's budget table.

/// Where an accuracy sits on builtin's curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Worth {
    /// As accurate as builtin at this many sweeps (interpolated).
    Sweeps(f64),
    /// Less accurate than builtin at the curve's smallest budget.
    Below(f64),
    /// More accurate than builtin at the curve's largest budget.
    Above(f64),
}

impl std::fmt::Display for Worth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Worth::Sweeps(n) => write!(f, "{n:.1}"),
            Worth::Below(n) if n.is_nan() => write!(f, "-"),
            Worth::Below(n) => write!(f, "< {n}"),
            Worth::Above(n) => write!(f, "> {n}"),
        }
    }
}

/// Places `value` (an error: smaller is better) on `curve`, builtin's (budget, error) points in
/// increasing budget: the budget at which builtin's error equals it, interpolated linearly in
/// log(budget) against log(error) between the first pair of points that brackets it (PGS's error
/// falls about geometrically, so a power law between points). Points with a non-positive or
/// non-finite error are skipped.
pub fn worth(curve: &[(f64, f64)], value: f64) -> Worth {
    let points: Vec<(f64, f64)> =
        curve.iter().copied().filter(|&(k, e)| k > 0.0 && e > 0.0 && e.is_finite() && k.is_finite()).collect();
    let (Some(&first), Some(&last)) = (points.first(), points.last()) else { return Worth::Below(f64::NAN) };
    // An unmeasured error has no place (shown `-`); no error at all is better than any point.
    if value.is_nan() {
        return Worth::Below(f64::NAN);
    }
    if value <= 0.0 {
        return Worth::Above(last.0);
    }
    if value > first.1 {
        return Worth::Below(first.0);
    }
    if points.len() == 1 {
        return Worth::Sweeps(first.0);
    }
    for w in points.windows(2) {
        let ((k0, e0), (k1, e1)) = (w[0], w[1]);
        if e0.min(e1) <= value && value <= e0.max(e1) {
            if e0 == e1 {
                return Worth::Sweeps(k0);
            }
            let t = (value.ln() - e0.ln()) / (e1.ln() - e0.ln());
            return Worth::Sweeps((k0.ln() + t * (k1.ln() - k0.ln())).exp());
        }
    }
    Worth::Above(last.0)
}

/// `y` at `x` on `points` (increasing x), linear in log(x) between the bracketing points; the end
/// values outside.
pub fn along(points: &[(f64, f64)], x: f64) -> f64 {
    let Some(&(x0, y0)) = points.first() else { return f64::NAN };
    if x <= x0 {
        return y0;
    }
    for w in points.windows(2) {
        let ((a, ya), (b, yb)) = (w[0], w[1]);
        if x <= b {
            let t = (x.ln() - a.ln()) / (b.ln() - a.ln());
            return ya + t * (yb - ya);
        }
    }
    points.last().map_or(f64::NAN, |p| p.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worth_interpolates_a_power_law_curve_exactly() {
        // error = 1 / budget: a model with error 1/12 is worth 12 sweeps, on any bracketing pair.
        let curve: Vec<(f64, f64)> = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0].iter().map(|&k| (k, 1.0 / k)).collect();
        for n in [1.5, 3.0, 12.0, 20.0, 31.0] {
            match worth(&curve, 1.0 / n) {
                Worth::Sweeps(w) => assert!((w - n).abs() < 1e-9, "{n}: {w}"),
                other => panic!("{n}: {other:?}"),
            }
        }
        assert_eq!(worth(&curve, 1.0), Worth::Sweeps(1.0));
        assert_eq!(worth(&curve, 2.0), Worth::Below(1.0));
        assert_eq!(worth(&curve, 1.0 / 64.0), Worth::Above(32.0));
        assert_eq!(worth(&curve, 0.0), Worth::Above(32.0));
        assert_eq!(worth(&curve, f64::NAN).to_string(), "-");
        // A flat stretch (converged early) returns its first budget; a point with error 0 is skipped.
        let flat = [(1.0, 0.5), (2.0, 0.25), (4.0, 0.25), (8.0, 0.0)];
        assert_eq!(worth(&flat, 0.25), Worth::Sweeps(2.0));
        assert_eq!(worth(&flat, 0.1), Worth::Above(4.0));
        assert_eq!(along(&[(1.0, 10.0), (4.0, 30.0)], 2.0), 20.0);
        assert_eq!(along(&[(1.0, 10.0), (4.0, 30.0)], 8.0), 30.0);
    }
}
