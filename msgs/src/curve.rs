//! Where a figure sits on a reference curve, shared by the reports that place models: on
//! builtin's curve of accuracy against budget ([`worth`], the simulator's budget study and the
//! launcher's budget table), and on the oracle blend curve ([`blend_place`], the metrics report
//! and the budget study); and how those tables write a figure ([`figure`]).

/// The largest sweep budget a step may be given (`dc-sim --budget`, `dc eval --budget`).
pub const MAX_BUDGET: u32 = 4096;

/// A figure of a budget table: four decimals, three significant digits in scientific notation
/// when small (< 1e-3) or large (>= 1e5), `-` when not finite.
pub fn figure(x: f64) -> String {
    if !x.is_finite() {
        "-".into()
    } else if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e5) {
        format!("{x:.3e}")
    } else {
        format!("{x:.4}")
    }
}

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
        // One budget measured: equal is worth it, better is beyond it (not "worth" it).
        return if value < first.1 { Worth::Above(first.0) } else { Worth::Sweeps(first.0) };
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

/// What a user buys with a model at a budget: its time per step (warm start, inference
/// included, and solve) over builtin's time at the budget where builtin is as accurate (its
/// [`worth`]), both on builtin's curves of (budget, error) and (budget, time). `None` where the
/// model is less accurate than builtin at the curve's smallest budget; where it is more accurate
/// than builtin anywhere on the curve, the ratio to builtin's time at the curve's top (an upper
/// bound, [`TimeRatio::AtMost`]).
pub fn time_ratio(
    accuracy: &[(f64, f64)],
    time: &[(f64, f64)],
    model_error: f64,
    model_time: f64,
) -> Option<TimeRatio> {
    let over = |t: f64| (t > 0.0 && t.is_finite() && model_time.is_finite()).then(|| model_time / t);
    match worth(accuracy, model_error) {
        Worth::Sweeps(n) => over(along(time, n)).map(TimeRatio::Equal),
        Worth::Above(top) => over(along(time, top)).map(TimeRatio::AtMost),
        Worth::Below(_) => None,
    }
}

/// A model's time over builtin's at equal accuracy ([`time_ratio`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TimeRatio {
    /// At the budget where builtin is exactly as accurate.
    Equal(f64),
    /// Builtin is never as accurate on the curve: at most this (its time at the curve's top).
    AtMost(f64),
}

impl std::fmt::Display for TimeRatio {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TimeRatio::Equal(r) => write!(f, "{r:.2}x"),
            TimeRatio::AtMost(r) => write!(f, "< {r:.2}x"),
        }
    }
}

/// [`time_ratio`] as a table cell: `-` where there is none.
pub fn time_ratio_cell(ratio: Option<TimeRatio>) -> String {
    ratio.map_or_else(|| "-".to_string(), |r| r.to_string())
}

/// Where a value sits on the blend curve `blend:F` (builtin + F (oracle - builtin)).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum BlendPlace {
    /// At this F, between two blends the run measured (builtin: F = 0).
    At(f64),
    /// Worse than builtin (F would be negative).
    BelowBuiltin,
    /// Better than the largest blend measured (its F given).
    Beyond(f64),
}

impl BlendPlace {
    /// `0.12`, `< 0`, `> 0.75`.
    pub fn label(&self) -> String {
        match self {
            BlendPlace::At(f) => format!("{f:.2}"),
            BlendPlace::BelowBuiltin => "< 0".into(),
            BlendPlace::Beyond(f) => format!("> {f:.2}"),
        }
    }

    /// F for comparing two places, with a place outside the measured curve at its nearer end.
    pub fn position(&self) -> f64 {
        match *self {
            BlendPlace::At(f) | BlendPlace::Beyond(f) => f,
            BlendPlace::BelowBuiltin => 0.0,
        }
    }

    /// F when inside the measured curve.
    pub fn fraction(&self) -> Option<f64> {
        match *self {
            BlendPlace::At(f) => Some(f),
            _ => None,
        }
    }
}

/// Where the piecewise-linear curve through `points` (sorted by x, starting at builtin's (0, 1))
/// takes the value y: the first bracketing segment from the start; outside them, below builtin
/// when y is nearer the start (worse than builtin), else beyond the last point.
pub fn blend_place(points: impl Iterator<Item = (f64, f64)>, y: f64) -> Option<BlendPlace> {
    let points: Vec<(f64, f64)> = points.collect();
    if !y.is_finite() || points.len() < 2 {
        return None;
    }
    for w in points.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        if (y0.min(y1)..=y0.max(y1)).contains(&y) {
            let x = if y1 == y0 { x0 } else { x0 + (y - y0) * (x1 - x0) / (y1 - y0) };
            return Some(BlendPlace::At(x));
        }
    }
    let (first, last) = (points[0], points[points.len() - 1]);
    Some(if (y - first.1).abs() <= (y - last.1).abs() { BlendPlace::BelowBuiltin } else { BlendPlace::Beyond(last.0) })
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
        // A curve of one budget (`dc eval --budget 8`): only equal is worth it.
        let one = [(8.0, 0.0109)];
        assert_eq!(worth(&one, 0.0109), Worth::Sweeps(8.0));
        assert_eq!(worth(&one, 0.0097).to_string(), "> 8");
        assert_eq!(worth(&one, 0.0125).to_string(), "< 8");
        assert_eq!(along(&[(1.0, 10.0), (4.0, 30.0)], 2.0), 20.0);
        assert_eq!(along(&[(1.0, 10.0), (4.0, 30.0)], 8.0), 30.0);
    }

    #[test]
    fn the_time_ratio_at_equal_accuracy_on_a_synthetic_curve() {
        // Builtin: error 1/k after k sweeps, 10 us a sweep.
        let budgets = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];
        let accuracy: Vec<(f64, f64)> = budgets.iter().map(|&k| (k, 1.0 / k)).collect();
        let time: Vec<(f64, f64)> = budgets.iter().map(|&k| (k, 10.0 * k)).collect();
        // A model as accurate as builtin at 2K = 16 in the time of K = 8 sweeps: half the time.
        assert_eq!(time_ratio(&accuracy, &time, 1.0 / 16.0, 80.0), Some(TimeRatio::Equal(0.5)));
        // As accurate as builtin at K, in K's time plus an inference of 20 us: 1.25x.
        assert_eq!(time_ratio(&accuracy, &time, 1.0 / 8.0, 100.0), Some(TimeRatio::Equal(1.25)));
        // Between budgets: worth 11.31 sweeps (log-log), builtin's time 10 * 11.31 interpolated
        // linearly in log(k) between 80 and 160.
        let r = time_ratio(&accuracy, &time, 1.0 / 11.313_708_5, 80.0).unwrap();
        let TimeRatio::Equal(r) = r else { panic!("{r:?}") };
        assert!((r - 80.0 / 120.0).abs() < 1e-6, "{r}");
        // Better than builtin anywhere on the curve: at most its time at the top.
        assert_eq!(time_ratio(&accuracy, &time, 1e-3, 80.0), Some(TimeRatio::AtMost(0.25)));
        assert_eq!(time_ratio_cell(Some(TimeRatio::AtMost(0.25))), "< 0.25x");
        // Worse than builtin at one sweep: no place.
        assert_eq!(time_ratio(&accuracy, &time, 2.0, 80.0), None);
        assert_eq!(time_ratio_cell(None), "-");
    }
}
