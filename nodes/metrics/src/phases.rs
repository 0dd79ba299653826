//! Where the sweeps are spent: runs split into step ranges ("phases" by step number, e.g. 0-99,
//! 100-149, 150-end: the late phase is where the piles jam), per model and phase the sweeps and
//! their share, the sweeps histogram, the per-step (warm-start error, sweeps) pairs, and the
//! accuracy -> sweeps table (late-phase warm-start error and total sweeps, both relative to
//! `builtin`).
//!
//! These phases are fixed step ranges, the same for every model and simulation, so models compare
//! like for like; the falling / settled split of [`crate::aggregate::Phase`] depends on each
//! simulation's bodies instead.

use crate::aggregate::{Aggregate, StepRecord};
use crate::stats::median;
use serde::Serialize;

/// The default phase boundaries: steps 0-99, 100-149 and 150-end.
pub const DEFAULT_PHASE_BOUNDARIES: [u32; 2] = [100, 150];

/// Steps `first..end` of every simulation (`end` exclusive; `None`: to the last step).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct StepRange {
    pub first: u32,
    pub end: Option<u32>,
}

impl StepRange {
    /// The ranges between `boundaries` (each the first step of a range after the first): `[100,
    /// 150]` -> 0-99, 100-149, 150-end; none -> 0-end. Boundaries are sorted, repeats and 0 are
    /// dropped.
    pub fn from_boundaries(boundaries: &[u32]) -> Vec<StepRange> {
        let mut b: Vec<u32> = boundaries.iter().copied().filter(|&b| b > 0).collect();
        b.sort_unstable();
        b.dedup();
        let starts = std::iter::once(0).chain(b.iter().copied());
        let ends = b.iter().copied().map(Some).chain(std::iter::once(None));
        starts.zip(ends).map(|(first, end)| StepRange { first, end }).collect()
    }

    pub fn contains(&self, step: u32) -> bool {
        step >= self.first && self.end.is_none_or(|end| step < end)
    }

    /// `0-99`, `150-end`.
    pub fn label(&self) -> String {
        match self.end {
            Some(end) => format!("{}-{}", self.first, end.saturating_sub(1)),
            None => format!("{}-end", self.first),
        }
    }
}

/// Checks phase boundaries given by hand: positive and strictly increasing.
pub fn check_boundaries(boundaries: &[u32]) -> Result<(), String> {
    if boundaries.contains(&0) {
        return Err("phase boundaries are first steps of later phases: 0 is not one".into());
    }
    if boundaries.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!("phase boundaries must increase strictly, got {boundaries:?}"));
    }
    Ok(())
}

/// Parses phase boundaries written `100,150` (spaces allowed; empty: none) and checks them.
pub fn parse_boundaries(s: &str) -> Result<Vec<u32>, String> {
    let b = s
        .split(',')
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .map(|p| p.parse::<u32>().map_err(|e| format!("`{p}`: {e}")))
        .collect::<Result<Vec<u32>, String>>()?;
    check_boundaries(&b)?;
    Ok(b)
}

/// One model's sweeps in one phase.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhaseRow {
    pub model: String,
    pub phase: StepRange,
    pub steps: usize,
    pub total_sweeps: u64,
    /// The model's total sweeps over all phases.
    pub model_total_sweeps: u64,
    /// `total_sweeps / model_total_sweeps` (0..1; NaN when the model spent no sweeps).
    pub share_of_model: f64,
    /// `total_sweeps / builtin's total sweeps over all phases` (None without a builtin run, or
    /// when builtin spent no sweeps).
    pub ratio_to_builtin_total: Option<f64>,
    /// The phase's sweeps over builtin's on the same step problems (None unless every step of
    /// the phase measured builtin alongside, or builtin needed none there).
    pub same_states_ratio: Option<f64>,
    /// Steps that hit the sweep cap (not converged).
    pub cap_hits: usize,
    /// Sweeps of those steps.
    pub cap_sweeps: u64,
    /// `cap_sweeps / model_total_sweeps` (NaN when the model spent no sweeps).
    pub cap_sweeps_share: f64,
    pub median_sweeps: f64,
    /// Median over the phase's steps with contacts of the warm start's normal MSE.
    pub median_warm_error_normal_mse: f64,
}

/// A bin of sweeps per step, `lo..=hi`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct SweepBin {
    pub lo: u32,
    pub hi: u32,
}

impl SweepBin {
    /// `0`, `1`, `2-3`, `512-1023`.
    pub fn label(&self) -> String {
        if self.lo == self.hi {
            self.lo.to_string()
        } else {
            format!("{}-{}", self.lo, self.hi)
        }
    }

    /// Log-spaced bins 0 (with `zero`), 1, 2-3, 4-7, ... up to the one holding `max`.
    pub fn log2_bins(max: u32, zero: bool) -> Vec<SweepBin> {
        let top = 32 - max.max(1).leading_zeros(); // bins 1..=top: [2^(k-1), 2^k - 1]
        let zero = zero.then_some(SweepBin { lo: 0, hi: 0 });
        zero.into_iter()
            .chain(
                (1..=top)
                    .map(|k| SweepBin { lo: 1u32 << (k - 1), hi: if k == 32 { u32::MAX } else { (1u32 << k) - 1 } }),
            )
            .collect()
    }
}

/// One model's steps in one phase, counted per [`SweepBin`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepHistogram {
    pub model: String,
    pub phase: StepRange,
    pub steps: usize,
    /// Steps per bin (the bins of [`SweepHistograms::bins`]).
    pub counts: Vec<usize>,
    /// `counts / steps` (all 0 for a phase without steps).
    pub fractions: Vec<f64>,
}

/// Sweeps histograms of every model and phase over the same bins.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepHistograms {
    pub bins: Vec<SweepBin>,
    /// Models in [`Aggregate::model_order`], phases in order within each.
    pub histograms: Vec<SweepHistogram>,
}

/// One model's point on the accuracy -> sweeps curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AccuracyRow {
    pub model: String,
    /// The late phase: the last of the step ranges.
    pub late_phase: StepRange,
    /// Late-phase steps with persisting contacts (those the warm-start error is taken over).
    pub late_steps: usize,
    /// Median / mean over those steps of the warm start's normal MSE.
    pub median_warm_error_normal_mse: f64,
    pub mean_warm_error_normal_mse: f64,
    /// The median relative to builtin's (builtin: 1.0; None without builtin or when its median is
    /// 0 or undefined).
    pub error_vs_builtin: Option<f64>,
    pub total_sweeps: u64,
    /// Total sweeps relative to builtin's (builtin: 1.0).
    pub sweeps_vs_builtin: Option<f64>,
    /// Sweeps of every late-phase step, and relative to builtin's.
    pub late_sweeps: u64,
    pub late_sweeps_vs_builtin: Option<f64>,
}

fn ratio(value: f64, reference: Option<f64>) -> Option<f64> {
    reference.filter(|r| *r > 0.0 && r.is_finite()).map(|r| value / r)
}

fn share(part: u64, whole: u64) -> f64 {
    if whole == 0 {
        f64::NAN
    } else {
        part as f64 / whole as f64
    }
}

impl Aggregate {
    /// The step ranges of [`Aggregate::phase_boundaries`].
    pub fn phase_ranges(&self) -> Vec<StepRange> {
        StepRange::from_boundaries(&self.phase_boundaries)
    }

    fn in_range<'a>(&'a self, model: &str, range: StepRange) -> impl Iterator<Item = &'a StepRecord> + 'a {
        self.records(model).filter(move |r| range.contains(r.step))
    }

    fn builtin_total(&self) -> Option<f64> {
        self.models
            .contains_key("builtin")
            .then(|| self.records("builtin").map(|r| r.sweeps as u64).sum::<u64>() as f64)
    }

    /// Per model (in [`Aggregate::model_order`]) and phase: steps, sweeps and their share of the
    /// model's total, sweeps relative to builtin's whole-run total, capped steps and their
    /// sweeps, median sweeps and median warm-start error.
    pub fn phase_rows(&self) -> Vec<PhaseRow> {
        let builtin = self.builtin_total();
        let ranges = self.phase_ranges();
        let mut out = Vec::new();
        for model in self.model_order() {
            let model_total: u64 = self.records(&model).map(|r| r.sweeps as u64).sum();
            for &range in &ranges {
                let steps: Vec<&StepRecord> = self.in_range(&model, range).collect();
                let total: u64 = steps.iter().map(|r| r.sweeps as u64).sum();
                let capped = || steps.iter().filter(|r| !r.converged);
                let cap_sweeps: u64 = capped().map(|r| r.sweeps as u64).sum();
                let sweeps: Vec<f64> = steps.iter().map(|r| r.sweeps as f64).collect();
                let errors: Vec<f64> =
                    steps.iter().filter(|r| r.contacts > 0).map(|r| r.warm_error_normal_mse as f64).collect();
                out.push(PhaseRow {
                    model: model.clone(),
                    phase: range,
                    steps: steps.len(),
                    total_sweeps: total,
                    model_total_sweeps: model_total,
                    share_of_model: share(total, model_total),
                    ratio_to_builtin_total: ratio(total as f64, builtin),
                    same_states_ratio: crate::aggregate::same_states_totals(steps.iter().copied())
                        .and_then(|(own, builtin)| ratio(own as f64, Some(builtin as f64))),
                    cap_hits: capped().count(),
                    cap_sweeps,
                    cap_sweeps_share: share(cap_sweeps, model_total),
                    median_sweeps: median(&sweeps),
                    median_warm_error_normal_mse: median(&errors),
                });
            }
        }
        out
    }

    /// Per model and phase, the fraction of steps per log-spaced bin of sweeps (bins 1, 2-3,
    /// 4-7, ... up to the largest sweep count of any model; a 0 bin when some step needed none).
    pub fn sweeps_histograms(&self) -> SweepHistograms {
        let models = self.model_order();
        let all = || models.iter().flat_map(|m| self.records(m));
        let max = all().map(|r| r.sweeps).max().unwrap_or(1);
        let bins = SweepBin::log2_bins(max, all().any(|r| r.sweeps == 0));
        let bin_of = |sweeps: u32| bins.iter().position(|b| (b.lo..=b.hi).contains(&sweeps));
        let mut histograms = Vec::new();
        for model in &models {
            for range in self.phase_ranges() {
                let mut counts = vec![0usize; bins.len()];
                let mut steps = 0;
                for r in self.in_range(model, range) {
                    steps += 1;
                    if let Some(b) = bin_of(r.sweeps) {
                        counts[b] += 1;
                    }
                }
                let fractions =
                    counts.iter().map(|&c| if steps == 0 { 0.0 } else { c as f64 / steps as f64 }).collect();
                histograms.push(SweepHistogram { model: model.clone(), phase: range, steps, counts, fractions });
            }
        }
        SweepHistograms { bins, histograms }
    }

    /// The model's steps as (warm-start normal MSE, sweeps), both positive (for log axes), at most
    /// `max_points` of them: every k-th such step in simulation and step order.
    pub fn sweeps_vs_warm_error(&self, model: &str, max_points: usize) -> Vec<(f64, f64)> {
        let valid: Vec<(f64, f64)> = self
            .records(model)
            .map(|r| (r.warm_error_normal_mse as f64, r.sweeps as f64))
            .filter(|&(e, s)| e > 0.0 && e.is_finite() && s > 0.0)
            .collect();
        let every = valid.len().div_ceil(max_points.max(1)).max(1);
        valid.into_iter().step_by(every).collect()
    }

    /// The accuracy -> sweeps curve, one row per model: its median warm-start normal MSE over the
    /// late phase's steps with persisting contacts and its total sweeps, each also relative to
    /// builtin's.
    pub fn accuracy(&self) -> Vec<AccuracyRow> {
        let late = *self.phase_ranges().last().expect("at least one phase");
        let rows: Vec<AccuracyRow> = self
            .model_order()
            .into_iter()
            .map(|model| {
                let errors: Vec<f64> = self
                    .in_range(&model, late)
                    .filter(|r| r.persisting_contacts > 0)
                    .map(|r| r.warm_error_normal_mse as f64)
                    .collect();
                let mean = if errors.is_empty() { f64::NAN } else { errors.iter().sum::<f64>() / errors.len() as f64 };
                AccuracyRow {
                    late_phase: late,
                    late_steps: errors.len(),
                    median_warm_error_normal_mse: median(&errors),
                    mean_warm_error_normal_mse: mean,
                    error_vs_builtin: None,
                    total_sweeps: self.records(&model).map(|r| r.sweeps as u64).sum(),
                    sweeps_vs_builtin: None,
                    late_sweeps: self.in_range(&model, late).map(|r| r.sweeps as u64).sum(),
                    late_sweeps_vs_builtin: None,
                    model,
                }
            })
            .collect();
        let builtin = rows.iter().find(|r| r.model == "builtin").cloned();
        rows.into_iter()
            .map(|r| {
                let b = builtin.as_ref();
                AccuracyRow {
                    error_vs_builtin: ratio(r.median_warm_error_normal_mse, b.map(|b| b.median_warm_error_normal_mse))
                        .filter(|v| v.is_finite()),
                    sweeps_vs_builtin: ratio(r.total_sweeps as f64, b.map(|b| b.total_sweeps as f64)),
                    late_sweeps_vs_builtin: ratio(r.late_sweeps as f64, b.map(|b| b.late_sweeps as f64)),
                    ..r
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_from_boundaries() {
        let r = StepRange::from_boundaries(&[100, 150]);
        assert_eq!(r.iter().map(StepRange::label).collect::<Vec<_>>(), ["0-99", "100-149", "150-end"]);
        assert!(r[0].contains(0) && r[0].contains(99) && !r[0].contains(100));
        assert!(r[2].contains(150) && r[2].contains(u32::MAX));
        assert_eq!(StepRange::from_boundaries(&[]), vec![StepRange { first: 0, end: None }]);
        assert_eq!(StepRange::from_boundaries(&[50, 0, 20, 50]).len(), 3, "sorted, 0 and repeats dropped");
        assert!(check_boundaries(&[100, 150]).is_ok());
        assert!(check_boundaries(&[]).is_ok());
        assert!(check_boundaries(&[150, 100]).is_err());
        assert!(check_boundaries(&[0, 100]).is_err());
        assert!(check_boundaries(&[100, 100]).is_err());
        assert_eq!(parse_boundaries("100,150").unwrap(), DEFAULT_PHASE_BOUNDARIES, "the CLI's default");
        assert_eq!(parse_boundaries(" 50 , 200 ").unwrap(), [50, 200]);
        assert_eq!(parse_boundaries("").unwrap(), Vec::<u32>::new());
        assert!(parse_boundaries("150,100").is_err());
        assert!(parse_boundaries("10,x").unwrap_err().contains("`x`"));
    }

    #[test]
    fn log2_bins_cover_every_count_once() {
        let bins = SweepBin::log2_bins(1000, true);
        assert_eq!(bins.iter().map(SweepBin::label).collect::<Vec<_>>()[..4], ["0", "1", "2-3", "4-7"]);
        assert_eq!(bins.last().unwrap().label(), "512-1023");
        for s in 0..=1000u32 {
            assert_eq!(bins.iter().filter(|b| (b.lo..=b.hi).contains(&s)).count(), 1, "{s}");
        }
        assert_eq!(SweepBin::log2_bins(1024, false).last().unwrap().label(), "1024-2047");
        assert_eq!(SweepBin::log2_bins(0, false), vec![SweepBin { lo: 1, hi: 1 }]);
        assert_eq!(SweepBin::log2_bins(u32::MAX, false).len(), 32);
    }
}
