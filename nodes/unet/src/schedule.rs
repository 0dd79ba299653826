//! Learning-rate schedules burn lacks (cyclical triangular, cosine with warm restarts) and the
//! learning-rate finder's sweep and suggestion.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A learning rate as a function of the optimiser step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Schedule {
    Constant {
        lr: f64,
    },
    /// Smith's triangular cycle: `min -> max -> min` over `2 * half_cycle` steps, repeated.
    Triangular {
        min: f64,
        max: f64,
        half_cycle: usize,
    },
    /// SGDR: cosine from `max` down to `min` over `period` steps, then restart; each period is
    /// `mult` times the previous one.
    CosineRestarts {
        min: f64,
        max: f64,
        period: usize,
        mult: f64,
    },
}

impl Schedule {
    /// The rate at optimiser step `step` (0-based).
    pub fn lr(&self, step: usize) -> f64 {
        match *self {
            Schedule::Constant { lr } => lr,
            Schedule::Triangular { min, max, half_cycle } => {
                let half = half_cycle.max(1) as f64;
                let phase = (step as f64 / half) % 2.0; // 0..2
                let up = if phase <= 1.0 { phase } else { 2.0 - phase };
                min + (max - min) * up
            }
            Schedule::CosineRestarts { min, max, period, mult } => {
                let (mut start, mut len) = (0.0f64, period.max(1) as f64);
                let mult = mult.max(1.0);
                while step as f64 >= start + len {
                    start += len;
                    len *= mult;
                }
                let t = (step as f64 - start) / len;
                min + 0.5 * (max - min) * (1.0 + (PI * t).cos())
            }
        }
    }

    /// Parses `constant:LR`, `triangular:MIN:MAX:HALF_CYCLE`, `cosine:MIN:MAX:PERIOD[:MULT]`.
    pub fn parse(s: &str) -> Result<Schedule, String> {
        let parts: Vec<&str> = s.split(':').collect();
        let f = |i: usize| -> Result<f64, String> {
            parts
                .get(i)
                .ok_or_else(|| format!("schedule `{s}`: missing field {i}"))?
                .parse::<f64>()
                .map_err(|e| format!("schedule `{s}`: {e}"))
        };
        let n = |i: usize| -> Result<usize, String> {
            parts
                .get(i)
                .ok_or_else(|| format!("schedule `{s}`: missing field {i}"))?
                .parse::<usize>()
                .map_err(|e| format!("schedule `{s}`: {e}"))
        };
        let schedule = match parts[0] {
            "constant" => Schedule::Constant { lr: f(1)? },
            "triangular" => Schedule::Triangular { min: f(1)?, max: f(2)?, half_cycle: n(3)? },
            "cosine" => Schedule::CosineRestarts {
                min: f(1)?,
                max: f(2)?,
                period: n(3)?,
                mult: if parts.len() > 4 { f(4)? } else { 1.0 },
            },
            other => return Err(format!("unknown schedule `{other}` (constant, triangular, cosine)")),
        };
        // Finite rates (an infinite or NaN one would train to NaN), at most 10.
        let rate = |lr: f64| lr.is_finite() && lr <= 10.0;
        let rates_ok = match schedule {
            Schedule::Constant { lr } => lr > 0.0 && rate(lr),
            Schedule::Triangular { min, max, .. } => min >= 0.0 && max > min && rate(max),
            Schedule::CosineRestarts { min, max, mult, .. } => min >= 0.0 && max > min && rate(max) && mult.is_finite(),
        };
        if !rates_ok {
            return Err(format!("schedule `{s}`: rates must be finite, positive and at most 10, with max > min"));
        }
        Ok(schedule)
    }
}

/// The learning-rate finder's exponential sweep from `start` to `end` over `steps` steps.
pub fn sweep_lr(start: f64, end: f64, steps: usize, step: usize) -> f64 {
    let t = step as f64 / (steps.max(2) - 1) as f64;
    start * (end / start).powf(t)
}

/// Smith's suggestion from a finder curve `(lr, loss)`: the rate where the smoothed loss falls
/// fastest (steepest negative slope in log lr), searched before the loss minimum.
/// `None` when the loss never falls.
pub fn suggest_lr(curve: &[(f64, f64)]) -> Option<f64> {
    let smooth = smoothed(curve, 0.9);
    let min_at = smooth.iter().enumerate().min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?.0;
    let mut best: Option<(f64, f64)> = None;
    for w in smooth[..=min_at].windows(2) {
        let slope = (w[1].1 - w[0].1) / (w[1].0.ln() - w[0].0.ln());
        if slope < 0.0 && best.is_none_or(|(s, _)| slope < s) {
            best = Some((slope, w[0].0));
        }
    }
    best.map(|(_, lr)| lr)
}

/// Exponential moving average with bias correction (as fast.ai's finder).
pub fn smoothed(curve: &[(f64, f64)], beta: f64) -> Vec<(f64, f64)> {
    let mut avg = 0.0;
    curve
        .iter()
        .enumerate()
        .map(|(i, &(lr, loss))| {
            avg = beta * avg + (1.0 - beta) * loss;
            (lr, avg / (1.0 - beta.powi(i as i32 + 1)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangular_goes_up_and_down_between_its_bounds() {
        let s = Schedule::Triangular { min: 0.1, max: 1.1, half_cycle: 10 };
        assert!((s.lr(0) - 0.1).abs() < 1e-12);
        assert!((s.lr(5) - 0.6).abs() < 1e-12);
        assert!((s.lr(10) - 1.1).abs() < 1e-12);
        assert!((s.lr(15) - 0.6).abs() < 1e-12);
        assert!((s.lr(20) - 0.1).abs() < 1e-12);
        assert!((s.lr(30) - 1.1).abs() < 1e-12);
    }

    #[test]
    fn cosine_restarts_at_growing_periods() {
        let s = Schedule::CosineRestarts { min: 0.0, max: 1.0, period: 10, mult: 2.0 };
        assert_eq!(s.lr(0), 1.0);
        assert!((s.lr(5) - 0.5).abs() < 1e-12);
        assert!(s.lr(9) < 0.05);
        assert_eq!(s.lr(10), 1.0, "restart after the first period");
        assert!((s.lr(20) - 0.5).abs() < 1e-12, "the second period is 20 steps long");
        assert_eq!(s.lr(30), 1.0);
    }

    #[test]
    fn schedules_parse_and_reject_nonsense() {
        assert_eq!(Schedule::parse("constant:0.001").unwrap(), Schedule::Constant { lr: 0.001 });
        assert_eq!(
            Schedule::parse("cosine:0:0.01:100").unwrap(),
            Schedule::CosineRestarts { min: 0.0, max: 0.01, period: 100, mult: 1.0 }
        );
        assert!(Schedule::parse("triangular:0.1:0.01:5").is_err(), "max below min");
        assert!(Schedule::parse("cyclic:1").is_err());
        assert!(Schedule::parse("constant:abc").is_err());
        for nonsense in ["constant:inf", "constant:nan", "constant:1e308", "cosine:0:inf:100", "cosine:0:0.01:100:nan"]
        {
            assert!(Schedule::parse(nonsense).is_err(), "{nonsense}");
        }
    }

    #[test]
    fn the_finder_suggests_the_steepest_descent_before_the_blow_up() {
        // Loss flat, then falling fastest around 1e-3, then exploding past 1e-1.
        let curve: Vec<(f64, f64)> = (0..100)
            .map(|i| {
                let lr = sweep_lr(1e-6, 1.0, 100, i);
                let x = lr.log10();
                let loss = 1.0 / (1.0 + (2.0 * (x + 3.0)).exp()) + if x > -1.0 { 10.0 * (x + 1.0) } else { 0.0 };
                (lr, loss)
            })
            .collect();
        let lr = suggest_lr(&curve).unwrap();
        assert!((1e-4..1e-2).contains(&lr), "{lr}");
        assert!(suggest_lr(&[(1e-3, 1.0), (1e-2, 2.0), (1e-1, 3.0)]).is_none());
    }
}
