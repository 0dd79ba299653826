//! Per-step solver records and their aggregation per model, simulation and step, and the tables
//! computed from them: the summary per model, and the step-range phase tables whose rows
//! [`crate::phases`] defines.

use crate::phases::{
    AccuracyRow, BlendPlacement, PhaseRow, StepRange, SweepBin, SweepHistogram, SweepHistograms,
    DEFAULT_PHASE_BOUNDARIES,
};
use charts::{median, quantile};
use msgs::{Accuracy, ErrorSplit, SolveStatsHeader, StepStats};
use serde::Serialize;
use std::collections::BTreeMap;

/// One step's solve as the simulator reported it (`msgs::StepStats`, the one definition of the
/// statistics: its fields read through `Deref`), with the residual after each sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRecord {
    pub stats: StepStats,
    /// Residual (largest impulse change) after each sweep.
    pub residuals: Vec<f32>,
}

impl std::ops::Deref for StepRecord {
    type Target = StepStats;
    fn deref(&self) -> &StepStats {
        &self.stats
    }
}

impl StepRecord {
    pub fn from_msg(h: &SolveStatsHeader, residuals: &[f32]) -> StepRecord {
        StepRecord { stats: StepStats::from_header(h), residuals: residuals.to_vec() }
    }
}

/// Which part of a simulation a step belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Some body still moves faster than the settle speed (falling, bouncing, the pile forming).
    Falling,
    /// Every body stays slower than the settle speed for the rest of the simulation.
    Settled,
}

/// Index of the first step of the settled phase of one simulation: from there on every body's
/// speed stays at or below `settle_speed`. Speed, not the contact count: a diagnosis of the
/// ball-box scene found the count stable from step ~150 while balls still flew at 2-5 m/s into
/// the pile, so a count-based rule called a still-moving pile settled.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(v <= settle)` on purpose: NaN is not slow
pub fn settle_step(max_speed_per_step: &[f32], settle_speed: f32) -> usize {
    max_speed_per_step.iter().rposition(|&v| !(v <= settle_speed)).map_or(0, |last_fast| last_fast + 1)
}

/// Totals over a set of steps.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Totals {
    pub steps: usize,
    pub total_sweeps: u64,
    pub median_sweeps: f64,
    pub mean_sweeps: f64,
    /// Steps that hit the sweep cap (not converged).
    pub cap_hits: usize,
    pub fallbacks: usize,
    pub median_solve_us: f64,
    pub median_step_us: f64,
    pub total_solve_ms: f64,
    /// The median over the steps with contacts of the simulator's critical path: warm start
    /// (inference included) + solve (what a budget's time at equal accuracy compares).
    pub median_critical_us: f64,
}

impl Totals {
    pub fn of<'a>(steps: impl Iterator<Item = &'a StepRecord>) -> Totals {
        let steps: Vec<&StepRecord> = steps.collect();
        let sweeps: Vec<f64> = steps.iter().map(|s| s.sweeps as f64).collect();
        let solve: Vec<f64> = steps.iter().map(|s| s.solve_us as f64).collect();
        let step: Vec<f64> = steps.iter().map(|s| s.step_us as f64).collect();
        let critical: Vec<f64> = steps
            .iter()
            .filter(|s| s.stats.contacts > 0)
            .map(|s| s.stats.warm_start_us as f64 + s.stats.solve_us as f64)
            .collect();
        let total: u64 = steps.iter().map(|s| s.sweeps as u64).sum();
        Totals {
            steps: steps.len(),
            total_sweeps: total,
            median_sweeps: median(&sweeps),
            mean_sweeps: if steps.is_empty() { f64::NAN } else { total as f64 / steps.len() as f64 },
            cap_hits: steps.iter().filter(|s| !s.converged).count(),
            fallbacks: steps.iter().filter(|s| s.fallback).count(),
            median_solve_us: median(&solve),
            median_step_us: median(&step),
            total_solve_ms: solve.iter().sum::<f64>() / 1e3,
            median_critical_us: median(&critical),
        }
    }
}

/// One model's summary over every simulation it ran.
#[derive(Debug, Clone, Serialize)]
pub struct ModelSummary {
    pub model: String,
    pub simulations: usize,
    pub all: Totals,
    pub falling: Totals,
    pub settled: Totals,
    /// Total sweeps relative to the `builtin` model's (None without a builtin run).
    pub ratio_to_builtin: Option<f64>,
    /// Sweeps against builtin's on the very same step problems (None unless every step measured
    /// builtin alongside: `dc-sim --shadow-builtin`).
    pub same_states: Option<Paired>,
    /// Share of contacts that persisted from the previous step.
    pub persisting_share: f64,
    /// Median over steps of the warm start's normal / tangent MSE against the solution.
    pub median_warm_error_normal_mse: f64,
    pub median_warm_error_tangent_mse: f64,
    /// How accurate the steps were (what a fixed sweep budget trades).
    pub accuracy: Accuracy,
    /// Which part of builtin's warm-start error the model's removes, summed over its steps
    /// (`dc-sim --error-split`; None where not measured).
    pub split: Option<ErrorSplit>,
}

/// A model's sweeps against builtin's warm start on the same step problems: what the warm start
/// itself saves, apart from how its run's trajectory differs from builtin's run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Paired {
    /// Total sweeps over total builtin sweeps on the same problems.
    pub ratio: f64,
    /// The simulation where that ratio is highest, and its ratio.
    pub worst_simulation: u32,
    pub worst_ratio: f64,
}

/// Total sweeps of `steps` and builtin's on the same problems; None when a step did not measure
/// builtin.
pub fn same_states_totals<'a>(steps: impl IntoIterator<Item = &'a StepRecord>) -> Option<(u64, u64)> {
    steps.into_iter().try_fold((0u64, 0u64), |(own, builtin), r| {
        r.builtin_measured.then(|| (own + r.sweeps as u64, builtin + r.builtin_sweeps as u64))
    })
}

impl Paired {
    /// Over `simulations` (simulation -> step -> record); None when a step did not measure
    /// builtin or builtin took no sweeps at all.
    pub fn of(simulations: &BTreeMap<u32, BTreeMap<u32, StepRecord>>) -> Option<Paired> {
        let (mut own, mut builtin) = (0u64, 0u64);
        let mut worst: Option<(u32, f64)> = None;
        for (&simulation, steps) in simulations {
            let (o, b) = same_states_totals(steps.values())?;
            own += o;
            builtin += b;
            if b > 0 {
                let ratio = o as f64 / b as f64;
                if worst.is_none_or(|(_, w)| ratio > w) {
                    worst = Some((simulation, ratio));
                }
            }
        }
        let (worst_simulation, worst_ratio) = worst?;
        Some(Paired { ratio: own as f64 / builtin as f64, worst_simulation, worst_ratio })
    }
}

/// Per-step statistic across simulations: median and the 10-90% band.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Band {
    pub step: u32,
    pub p10: f64,
    pub median: f64,
    pub p90: f64,
}

/// Everything received, grouped by model then simulation, steps in order.
#[derive(Debug)]
pub struct Aggregate {
    /// model -> simulation -> step -> record.
    pub models: BTreeMap<String, BTreeMap<u32, BTreeMap<u32, StepRecord>>>,
    /// Speed (m/s) below which every body must stay for a step to count as settled.
    pub settle_speed: f32,
    /// First steps of the step-range phases after the first (`[100, 150]`: steps 0-99, 100-149,
    /// 150-end); see [`crate::phases`]. `None`: they scale with the simulations' length
    /// ([`Aggregate::boundaries`]).
    pub phase_boundaries: Option<Vec<u32>>,
}

impl Default for Aggregate {
    fn default() -> Aggregate {
        Aggregate::new()
    }
}

impl Aggregate {
    pub fn new() -> Aggregate {
        Aggregate { models: BTreeMap::new(), settle_speed: 0.1, phase_boundaries: None }
    }

    /// The phase boundaries: as given, or 2/5 and 3/5 of the longest simulation's steps (the
    /// thesis's 100 and 150 at 250 steps), so that a short run has a late phase too.
    pub fn boundaries(&self) -> Vec<u32> {
        if let Some(given) = &self.phase_boundaries {
            return given.clone();
        }
        let steps = self.models.keys().flat_map(|m| self.records(m)).map(|r| r.step + 1).max();
        match steps {
            Some(steps) if steps >= 5 => [2, 3].iter().map(|k| steps * k / 5).collect(),
            _ => DEFAULT_PHASE_BOUNDARIES.to_vec(),
        }
    }

    /// The models in a stable, meaningful order: the contract's table order (the thesis's), then
    /// the others by name; a model with a parameter (`blend:0.75`) sits where its base name does,
    /// by the parameter's value (`blend:0.5` before `blend:0.75` before `blend:10`).
    pub fn model_order(&self) -> Vec<String> {
        let order = msgs::models::MODELS;
        let key = |m: &str| {
            let (base, param) = m.split_once(':').map_or((m, None), |(b, p)| (b, p.trim().parse::<f64>().ok()));
            (order.iter().position(|o| o.name == base).unwrap_or(order.len()), base.to_string(), param)
        };
        let mut models: Vec<String> = self.models.keys().cloned().collect();
        models.sort_by(|a, b| {
            let ((pa, ba, xa), (pb, bb, xb)) = (key(a), key(b));
            let by_param = match (xa, xb) {
                (Some(x), Some(y)) => x.total_cmp(&y),
                (xa, xb) => xa.is_some().cmp(&xb.is_some()),
            };
            pa.cmp(&pb).then(ba.cmp(&bb)).then(by_param).then(a.cmp(b))
        });
        models
    }

    /// Adds a record; a repeated (model, simulation, step) replaces the earlier one.
    pub fn add(&mut self, r: StepRecord) {
        self.models.entry(r.model.clone()).or_default().entry(r.simulation).or_default().insert(r.step, r);
    }

    pub fn is_empty(&self) -> bool {
        self.models.is_empty()
    }

    /// Every record of a model, simulations then steps in order.
    pub fn records<'a>(&'a self, model: &str) -> impl Iterator<Item = &'a StepRecord> + 'a {
        self.models.get(model).into_iter().flat_map(|sims| sims.values().flat_map(|s| s.values()))
    }

    fn phase_of(&self, model: &str) -> BTreeMap<(u32, u32), Phase> {
        let mut out = BTreeMap::new();
        if let Some(sims) = self.models.get(model) {
            for (&sim, steps) in sims {
                let speeds: Vec<f32> = steps.values().map(|s| s.max_speed).collect();
                let settle = settle_step(&speeds, self.settle_speed);
                for (i, &step) in steps.keys().enumerate() {
                    out.insert((sim, step), if i >= settle { Phase::Settled } else { Phase::Falling });
                }
            }
        }
        out
    }

    /// Summaries of every model, with ratios to `builtin`.
    pub fn summaries(&self) -> Vec<ModelSummary> {
        let mut out: Vec<ModelSummary> = self
            .models
            .iter()
            .map(|(model, sims)| {
                let phases = self.phase_of(model);
                let phases = &phases;
                let in_phase = |p: Phase| self.records(model).filter(move |r| phases[&(r.simulation, r.step)] == p);
                let contacts: u64 = self.records(model).map(|r| r.contacts as u64).sum();
                let persisting: u64 = self.records(model).map(|r| r.persisting_contacts as u64).sum();
                let with_contacts = || self.records(model).filter(|r| r.contacts > 0);
                ModelSummary {
                    model: model.clone(),
                    simulations: sims.len(),
                    all: Totals::of(self.records(model)),
                    falling: Totals::of(in_phase(Phase::Falling)),
                    settled: Totals::of(in_phase(Phase::Settled)),
                    ratio_to_builtin: None,
                    same_states: Paired::of(sims),
                    persisting_share: if contacts == 0 { f64::NAN } else { persisting as f64 / contacts as f64 },
                    median_warm_error_normal_mse: median(
                        &with_contacts().map(|r| r.warm_error_normal_mse as f64).collect::<Vec<_>>(),
                    ),
                    median_warm_error_tangent_mse: median(
                        &with_contacts().map(|r| r.warm_error_tangent_mse as f64).collect::<Vec<_>>(),
                    ),
                    accuracy: Accuracy::of(
                        self.records(model).map(|r| &r.stats),
                        self.boundaries().iter().copied().max().unwrap_or(0),
                    ),
                    split: ErrorSplit::over(self.records(model).map(|r| &r.stats)),
                }
            })
            .collect();
        if let Some(builtin) = out.iter().find(|s| s.model == "builtin").map(|s| s.all.total_sweeps) {
            for s in &mut out {
                s.ratio_to_builtin = (builtin > 0).then(|| s.all.total_sweeps as f64 / builtin as f64);
            }
        }
        out
    }

    /// Per step: the statistic `f` across the model's simulations (median and 10-90% band).
    pub fn per_step(&self, model: &str, f: impl Fn(&StepRecord) -> f64) -> Vec<Band> {
        let mut by_step: BTreeMap<u32, Vec<f64>> = BTreeMap::new();
        for r in self.records(model) {
            by_step.entry(r.step).or_default().push(f(r));
        }
        by_step
            .into_iter()
            .map(|(step, v)| Band { step, p10: quantile(&v, 0.1), median: median(&v), p90: quantile(&v, 0.9) })
            .collect()
    }

    /// Share of the model's steps (with contacts) that converged within `n` sweeps, for n = 1..=max.
    pub fn converged_within(&self, model: &str, max: u32) -> Vec<(u32, f64)> {
        let sweeps: Vec<u32> = self
            .records(model)
            .filter(|r| r.contacts > 0)
            .map(|r| if r.converged { r.sweeps } else { u32::MAX })
            .collect();
        if sweeps.is_empty() {
            return Vec::new();
        }
        (1..=max).map(|n| (n, sweeps.iter().filter(|&&s| s <= n).count() as f64 / sweeps.len() as f64)).collect()
    }

    /// Median over the model's solves (steps with contacts) of the residual after n sweeps, for
    /// n = 1..=max; a solve that stopped earlier keeps its last residual.
    pub fn convergence(&self, model: &str, max: usize) -> Vec<(usize, f64)> {
        let solves: Vec<&Vec<f32>> =
            self.records(model).filter(|r| !r.residuals.is_empty()).map(|r| &r.residuals).collect();
        if solves.is_empty() {
            return Vec::new();
        }
        let longest = solves.iter().map(|r| r.len()).max().unwrap_or(0).min(max);
        (1..=longest)
            .map(|n| {
                let at: Vec<f64> = solves.iter().map(|r| r[(n - 1).min(r.len() - 1)] as f64).collect();
                (n, median(&at))
            })
            .collect()
    }
}

/// `value` relative to a positive, finite `reference`.
fn ratio(value: f64, reference: Option<f64>) -> Option<f64> {
    reference.filter(|r| *r > 0.0 && r.is_finite()).map(|r| value / r)
}

/// `part / whole`; NaN for nothing to share.
fn share(part: u64, whole: u64) -> f64 {
    if whole == 0 {
        f64::NAN
    } else {
        part as f64 / whole as f64
    }
}

/// The step-range phase tables of [`crate::phases`].
impl Aggregate {
    /// The step ranges of [`Aggregate::phase_boundaries`].
    pub fn phase_ranges(&self) -> Vec<StepRange> {
        StepRange::from_boundaries(&self.boundaries())
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
                    same_states_ratio: same_states_totals(steps.iter().copied())
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
                    same_states_vs_builtin: same_states_totals(self.records(&model))
                        .and_then(|(own, builtin)| ratio(own as f64, Some(builtin as f64))),
                    blend_by_error: None,
                    blend_by_sweeps: None,
                    placed_on_same_states: false,
                    model,
                }
            })
            .collect();
        let builtin = rows.iter().find(|r| r.model == "builtin").cloned();
        let rows: Vec<AccuracyRow> = rows
            .into_iter()
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
            .collect();
        // Same states when every model measured them: whole-run sweeps mix in the trajectory.
        let same_states = rows.iter().all(|r| r.same_states_vs_builtin.is_some());
        let rows: Vec<AccuracyRow> =
            rows.into_iter().map(|r| AccuracyRow { placed_on_same_states: same_states, ..r }).collect();
        let curve = BlendPlacement::of_table(&rows);
        rows.into_iter()
            .map(|r| AccuracyRow {
                blend_by_error: curve.as_ref().zip(r.error_vs_builtin).and_then(|(c, e)| c.by_error(e)),
                blend_by_sweeps: curve.as_ref().zip(r.placement_sweeps()).and_then(|(c, s)| c.by_sweeps(s)),
                ..r
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn record(model: &str, simulation: u32, step: u32, contacts: u32, sweeps: u32) -> StepRecord {
        let stats = StepStats {
            run_id: 1,
            model: model.into(),
            used_model: model.into(),
            simulation,
            step,
            contacts,
            persisting_contacts: contacts / 2,
            sweeps,
            converged: sweeps < 1000,
            fallback: false,
            fallbacks_total: 0,
            final_residual: 0.0,
            warm_error_normal_mse: sweeps as f32,
            warm_error_normal_max: 0.0,
            warm_error_tangent_mse: 0.0,
            warm_error_tangent_max: 0.0,
            solve_us: 10.0 * sweeps as f32,
            step_us: 100.0,
            warm_start_us: 1.0,
            kinetic_energy: 0.0,
            max_speed: 0.0,
            builtin_sweeps: 0,
            builtin_measured: false,
            natural_max: 0.0,
            natural_rms: 0.0,
            penetration_max: 0.0,
            penetration_mean: 0.0,
            pile_height: 0.0,
            pile_spread: 0.0,
            ..StepStats::default()
        };
        StepRecord { stats, residuals: (0..sweeps).map(|i| 1.0 / (i + 1) as f32).collect() }
    }

    #[test]
    fn phases_scale_with_the_simulations_length_unless_given() {
        let mut a = Aggregate::new();
        assert_eq!(a.boundaries(), DEFAULT_PHASE_BOUNDARIES, "no records yet");
        for step in 0..40 {
            a.add(record("builtin", 0, step, 4, 8));
        }
        // 40 steps: a late phase of 16 steps, as 150-end is of 250.
        assert_eq!(a.boundaries(), [16, 24]);
        assert_eq!(a.phase_ranges().last().unwrap().label(), "24-end");
        for step in 40..250 {
            a.add(record("builtin", 1, step, 4, 8));
        }
        assert_eq!(a.boundaries(), DEFAULT_PHASE_BOUNDARIES, "the thesis's at 250 steps");
        a.phase_boundaries = Some(vec![10]);
        assert_eq!(a.boundaries(), [10]);
    }

    #[test]
    fn a_models_error_split_is_summed_over_its_measured_steps() {
        let mut agg = Aggregate::new();
        let split = ErrorSplit {
            model_smooth: 2.0,
            builtin_smooth: 8.0,
            model_left: 1.0,
            model_left_natural: 0.01,
            builtin_left_natural: 0.02,
            n: 4,
            steps: 1,
            ..Default::default()
        };
        for step in 0..3 {
            let mut r = record("gnn", 0, step, 4, 8);
            // The first step was not measured (a run without --error-split reads the same).
            r.stats.set_split((step > 0).then_some(&split), 8);
            agg.add(r);
            agg.add(record("builtin", 0, step, 4, 8));
        }
        let summaries = agg.summaries();
        let of = |m: &str| summaries.iter().find(|s| s.model == m).unwrap().split;
        assert_eq!(of("builtin"), None);
        let gnn = of("gnn").unwrap();
        assert_eq!((gnn.n, gnn.model_smooth, gnn.builtin_smooth, gnn.model_left), (8, 4.0, 16.0, 2.0));
        assert_eq!(gnn.removed().0, 0.5);
        assert_eq!((gnn.steps, gnn.left_natural()), (2, (0.01f32 as f64, 0.02f32 as f64)));
    }

    #[test]
    fn same_states_pair_each_step_with_builtin_on_it() {
        let mut a = Aggregate::new();
        // Simulation 0: 100 sweeps where builtin needs 200; simulation 1: 300 where it needs 200.
        for (simulation, own, builtin) in [(0, 40, 120), (0, 60, 80), (1, 300, 200)] {
            let mut r = record("m", simulation, a.records("m").count() as u32, 10, own);
            (r.stats.builtin_sweeps, r.stats.builtin_measured) = (builtin, true);
            a.add(r);
        }
        let paired = a.summaries()[0].same_states.unwrap();
        assert_eq!(paired, Paired { ratio: 1.0, worst_simulation: 1, worst_ratio: 1.5 });
        // One step that did not measure builtin: no figure rather than a partial one.
        a.add(record("m", 1, 7, 10, 5));
        assert_eq!(a.summaries()[0].same_states, None);
    }

    #[test]
    fn settle_step_is_where_every_body_stays_slow() {
        assert_eq!(settle_step(&[0.0, 3.0, 0.05, 2.0, 0.09, 0.1, 0.02], 0.1), 4);
        assert_eq!(settle_step(&[], 0.1), 0);
        assert_eq!(settle_step(&[0.01, 0.02], 0.1), 0);
        assert_eq!(settle_step(&[0.01, 5.0], 0.1), 2, "still moving at the end: nothing settled");
        assert_eq!(settle_step(&[f32::NAN], 0.1), 1, "NaN is not slow");
    }

    #[test]
    fn summaries_count_sweeps_caps_and_ratios_exactly() {
        let mut a = Aggregate::new();
        // builtin: 2 simulations x 4 steps, sweeps 10 each -> 80 total.
        for sim in 0..2 {
            for step in 0..4 {
                a.add(record("builtin", sim, step, 20, 10));
            }
        }
        // none: sweeps 30, one step hits the cap (1000).
        for sim in 0..2 {
            for step in 0..4 {
                a.add(record("none", sim, step, 20, if (sim, step) == (1, 3) { 1000 } else { 30 }));
            }
        }
        let s = a.summaries();
        let builtin = s.iter().find(|m| m.model == "builtin").unwrap();
        let none = s.iter().find(|m| m.model == "none").unwrap();
        assert_eq!(builtin.all.total_sweeps, 80);
        assert_eq!(builtin.ratio_to_builtin, Some(1.0));
        assert_eq!(none.all.total_sweeps, 7 * 30 + 1000);
        assert_eq!(none.ratio_to_builtin, Some(1210.0 / 80.0));
        assert_eq!(none.all.cap_hits, 1);
        assert_eq!(none.all.median_sweeps, 30.0);
        assert_eq!(none.all.mean_sweeps, 1210.0 / 8.0);
        assert_eq!(none.simulations, 2);
        assert_eq!(none.persisting_share, 0.5);
        assert_eq!(builtin.all.median_solve_us, 100.0);
        // Nothing moves: every step is settled.
        assert_eq!(builtin.settled.steps, 8);
        assert_eq!(builtin.falling.steps, 0);
    }

    #[test]
    fn per_step_bands_and_convergence_curves() {
        let mut a = Aggregate::new();
        for (sim, sweeps) in [(0, 10), (1, 20), (2, 30), (3, 40), (4, 50)] {
            a.add(record("copy", sim, 0, 5, sweeps));
        }
        let band = a.per_step("copy", |r| r.sweeps as f64);
        assert_eq!(band, vec![Band { step: 0, p10: 14.0, median: 30.0, p90: 46.0 }]);
        let within = a.converged_within("copy", 50);
        assert_eq!(within[9], (10, 0.2));
        assert_eq!(within[49], (50, 1.0));
        let conv = a.convergence("copy", 100);
        assert_eq!(conv.len(), 50);
        assert_eq!(conv[0], (1, 1.0));
        // After 20 sweeps: solves of 10 keep 1/10; the others are at 1/20.
        assert_eq!(conv[19].1, (1.0f32 / 20.0) as f64);
    }

    #[test]
    fn model_order_follows_the_contract_then_names_and_parameters() {
        let mut a = Aggregate::new();
        for m in ["zeta", "blend:10", "blend:0.75", "builtin", "blend:0.5", "none", "blend", "alpha:x"] {
            a.add(record(m, 0, 0, 1, 1));
        }
        let order = a.model_order();
        let pos = |m: &str| order.iter().position(|o| o == m).unwrap();
        assert!(pos("none") < pos("builtin"));
        assert_eq!(&order[order.len() - 2..], ["alpha:x", "zeta"], "unknown names last, by name");
        if msgs::models::model("blend").is_some() {
            assert!(pos("builtin") < pos("blend"));
        }
        assert!(
            pos("blend") < pos("blend:0.5")
                && pos("blend:0.5") < pos("blend:0.75")
                && pos("blend:0.75") < pos("blend:10")
        );
    }

    #[test]
    fn repeated_steps_replace_earlier_records() {
        let mut a = Aggregate::new();
        a.add(record("x", 0, 0, 1, 5));
        a.add(record("x", 0, 0, 1, 7));
        assert_eq!(a.records("x").count(), 1);
        assert_eq!(a.records("x").next().unwrap().sweeps, 7);
    }
}
