//! The per-step solver statistics, defined once: [`StepStats`] is what the simulator measures,
//! what the metrics node aggregates and writes as CSV, and what the Foxglove bridge shows as JSON
//! (all through serde); [`SolveStatsHeader`] is its fixed-size wire form.

use crate::{name16, name16_str, SolveStatsHeader, StepHeader};
use serde::{Deserialize, Serialize};

/// One step's solve, as the simulator reported it. A field this build does not know is refused
/// (a renamed column would otherwise leave its field at the default, silently).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepStats {
    /// The run (a text string in JSON and CSV: ids exceed 2^53, which JavaScript numbers lose).
    #[serde(with = "crate::id_text")]
    pub run_id: u64,
    pub simulation: u32,
    pub step: u32,
    /// The warm-start model that was asked for.
    pub model: String,
    /// The model actually used (differs from `model` on a fallback).
    pub used_model: String,
    pub contacts: u32,
    /// Contacts that persisted from the previous step (matched by body pair and feature).
    pub persisting_contacts: u32,
    pub sweeps: u32,
    /// Whether the solve reached the tolerance before the sweep cap.
    pub converged: bool,
    /// Whether the model's warm start was late or missing and `used_model` stood in.
    pub fallback: bool,
    /// Fallbacks in this simulation so far.
    pub fallbacks_total: u32,
    /// Largest impulse change of the last sweep.
    pub final_residual: f32,
    /// Mean squared error of the warm start's normal impulses vs the solution.
    pub warm_error_normal_mse: f32,
    /// Largest absolute error of the warm start's normal impulses.
    pub warm_error_normal_max: f32,
    pub warm_error_tangent_mse: f32,
    pub warm_error_tangent_max: f32,
    /// Wall time of the velocity solve only, microseconds.
    pub solve_us: f32,
    /// Wall time of the whole step (collision, warm start, solve, integrate), microseconds.
    pub step_us: f32,
    /// Wall time spent obtaining the warm start (including waiting for a grid), microseconds.
    pub warm_start_us: f32,
    /// Kinetic energy (linear + rotational) of the dynamic bodies after the step, J.
    pub kinetic_energy: f32,
    /// Largest speed of a dynamic body after the step, m/s.
    pub max_speed: f32,
    /// Sweeps builtin's warm start needs on this same step's problem (`dc-sim --shadow-builtin`:
    /// solved on scratch velocities; the step's own sweeps when builtin was the model used).
    /// Paired with `sweeps`, it separates what a warm start saves on the states it meets from
    /// how its run's trajectory differs from builtin's.
    #[serde(default)]
    pub builtin_sweeps: u32,
    /// Whether `builtin_sweeps` was measured (absent in statistics written before it existed).
    #[serde(default)]
    pub builtin_measured: bool,
    /// The natural residual of the final impulses, whatever the stopping rule: the largest
    /// change one projected Jacobi step would still make (impulse units), and its RMS over the
    /// rows' normal and tangent parts (0 where not recorded).
    #[serde(default)]
    pub natural_max: f32,
    #[serde(default)]
    pub natural_rms: f32,
    /// Overlap left after the position pass: the largest over contacts and the mean over
    /// contacts (m; 0 without contacts or where not recorded).
    #[serde(default)]
    pub penetration_max: f32,
    #[serde(default)]
    pub penetration_mean: f32,
    /// The dynamic bodies' centre of mass height (m) and their spread about it (mass-weighted RMS
    /// distance from it, m), after the step: the pile's shape, compared across runs by phase
    /// (trajectories diverge, so no per-body comparison).
    #[serde(default)]
    pub pile_height: f32,
    #[serde(default)]
    pub pile_spread: f32,
    /// The warm start's error against the step's exact solution, split (`dc-sim --error-split`,
    /// [`ErrorSplit`]): the contacts summed over (0: not measured), the sweep budget the `left`
    /// sums were measured with, and sums of squares over the step's contacts (impulse units,
    /// normal and tangent together) of the model's and builtin's smooth and rough error parts
    /// and of what the budget's sweeps leave from each start; then the RMS natural residual those
    /// sweeps leave from each start (solver-independent, and blind to which of a jammed pile's
    /// many solutions a start heads for: the same-states comparison at a budget).
    #[serde(default)]
    pub split_contacts: u32,
    #[serde(default)]
    pub split_budget: u32,
    #[serde(default)]
    pub split_model_smooth: f32,
    #[serde(default)]
    pub split_model_rough: f32,
    #[serde(default)]
    pub split_builtin_smooth: f32,
    #[serde(default)]
    pub split_builtin_rough: f32,
    #[serde(default)]
    pub split_model_left: f32,
    #[serde(default)]
    pub split_builtin_left: f32,
    #[serde(default)]
    pub split_model_left_natural: f32,
    #[serde(default)]
    pub split_builtin_left_natural: f32,
}

impl StepStats {
    /// The statistics of a `stats/solve` header.
    pub fn from_header(h: &SolveStatsHeader) -> StepStats {
        StepStats {
            run_id: h.step.run_id,
            simulation: h.step.simulation,
            step: h.step.step,
            model: name16_str(&h.model).to_string(),
            used_model: name16_str(&h.used_model).to_string(),
            contacts: h.contacts,
            persisting_contacts: h.persisting_contacts,
            sweeps: h.sweeps,
            converged: h.converged != 0,
            fallback: h.fallback != 0,
            fallbacks_total: h.fallbacks_total,
            final_residual: h.final_residual,
            warm_error_normal_mse: h.warm_error_normal_mse,
            warm_error_normal_max: h.warm_error_normal_max,
            warm_error_tangent_mse: h.warm_error_tangent_mse,
            warm_error_tangent_max: h.warm_error_tangent_max,
            solve_us: h.solve_us,
            step_us: h.step_us,
            warm_start_us: h.warm_start_us,
            kinetic_energy: h.kinetic_energy,
            max_speed: h.max_speed,
            builtin_sweeps: h.builtin_sweeps,
            builtin_measured: h.builtin_measured != 0,
            natural_max: h.natural_max,
            natural_rms: h.natural_rms,
            penetration_max: h.penetration_max,
            penetration_mean: h.penetration_mean,
            pile_height: h.pile_height,
            pile_spread: h.pile_spread,
            split_contacts: h.split_contacts,
            split_budget: h.split_budget,
            split_model_smooth: h.split_model_smooth,
            split_model_rough: h.split_model_rough,
            split_builtin_smooth: h.split_builtin_smooth,
            split_builtin_rough: h.split_builtin_rough,
            split_model_left: h.split_model_left,
            split_builtin_left: h.split_builtin_left,
            split_model_left_natural: h.split_model_left_natural,
            split_builtin_left_natural: h.split_builtin_left_natural,
        }
    }

    /// The wire header (model names truncated to 16 bytes).
    pub fn to_header(&self) -> SolveStatsHeader {
        SolveStatsHeader {
            step: self.step_header(),
            model: name16(&self.model),
            used_model: name16(&self.used_model),
            contacts: self.contacts,
            persisting_contacts: self.persisting_contacts,
            sweeps: self.sweeps,
            converged: self.converged as u32,
            fallback: self.fallback as u32,
            fallbacks_total: self.fallbacks_total,
            final_residual: self.final_residual,
            warm_error_normal_mse: self.warm_error_normal_mse,
            warm_error_normal_max: self.warm_error_normal_max,
            warm_error_tangent_mse: self.warm_error_tangent_mse,
            warm_error_tangent_max: self.warm_error_tangent_max,
            solve_us: self.solve_us,
            step_us: self.step_us,
            warm_start_us: self.warm_start_us,
            kinetic_energy: self.kinetic_energy,
            max_speed: self.max_speed,
            builtin_sweeps: self.builtin_sweeps,
            builtin_measured: self.builtin_measured as u32,
            natural_max: self.natural_max,
            natural_rms: self.natural_rms,
            penetration_max: self.penetration_max,
            penetration_mean: self.penetration_mean,
            pile_height: self.pile_height,
            pile_spread: self.pile_spread,
            split_contacts: self.split_contacts,
            split_budget: self.split_budget,
            split_model_smooth: self.split_model_smooth,
            split_model_rough: self.split_model_rough,
            split_builtin_smooth: self.split_builtin_smooth,
            split_builtin_rough: self.split_builtin_rough,
            split_model_left: self.split_model_left,
            split_builtin_left: self.split_builtin_left,
            split_model_left_natural: self.split_model_left_natural,
            split_builtin_left_natural: self.split_builtin_left_natural,
        }
    }

    pub fn step_header(&self) -> StepHeader {
        StepHeader { run_id: self.run_id, simulation: self.simulation, step: self.step }
    }

    /// The step's warm-start error split, where it was measured (a step without contacts has
    /// nothing to split).
    pub fn split(&self) -> Option<ErrorSplit> {
        (self.split_contacts > 0).then_some(ErrorSplit {
            model_smooth: self.split_model_smooth as f64,
            model_rough: self.split_model_rough as f64,
            builtin_smooth: self.split_builtin_smooth as f64,
            builtin_rough: self.split_builtin_rough as f64,
            model_left: self.split_model_left as f64,
            builtin_left: self.split_builtin_left as f64,
            model_left_natural: self.split_model_left_natural as f64,
            builtin_left_natural: self.split_builtin_left_natural as f64,
            n: self.split_contacts as u64,
            steps: 1,
        })
    }

    /// Stores a step's split (`None`: not measured) measured with `budget` sweeps.
    pub fn set_split(&mut self, split: Option<&ErrorSplit>, budget: u32) {
        let s = split.copied().unwrap_or_default();
        self.split_contacts = s.n as u32;
        self.split_budget = if s.n > 0 { budget } else { 0 };
        self.split_model_smooth = s.model_smooth as f32;
        self.split_model_rough = s.model_rough as f32;
        self.split_builtin_smooth = s.builtin_smooth as f32;
        self.split_builtin_rough = s.builtin_rough as f32;
        self.split_model_left = s.model_left as f32;
        self.split_builtin_left = s.builtin_left as f32;
        self.split_model_left_natural = s.model_left_natural as f32;
        self.split_builtin_left_natural = s.builtin_left_natural as f32;
    }
}

/// Which part of builtin's error a model's warm start removes, on the model's own steps: the
/// model's and builtin's warm-start error against the step's exact solution, each split as the
/// `smooth-error` / `rough-error` references split it (the part a few passes of averaging over
/// the contact graph keeps — pile-wide — and the rest — local), and what the budget's sweeps leave
/// of each (the part slow for the solver), as sums of squares over the contacts (impulse units,
/// normal and tangent together). Sums add over steps and seeds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ErrorSplit {
    pub model_smooth: f64,
    pub model_rough: f64,
    pub builtin_smooth: f64,
    pub builtin_rough: f64,
    /// What the budget's sweeps leave of each start's error: the error after K sweeps from the
    /// model's start and from builtin's, on the same step.
    pub model_left: f64,
    pub builtin_left: f64,
    /// The RMS natural residual those sweeps leave from the model's start and from builtin's,
    /// summed over the steps (what the run's accuracy is measured on, here on the same steps).
    pub model_left_natural: f64,
    pub builtin_left_natural: f64,
    /// Contacts summed over.
    pub n: u64,
    /// Steps summed over.
    pub steps: u64,
}

impl ErrorSplit {
    /// Adds another step's or seed's sums.
    pub fn add(&mut self, other: &ErrorSplit) {
        self.model_smooth += other.model_smooth;
        self.model_rough += other.model_rough;
        self.builtin_smooth += other.builtin_smooth;
        self.builtin_rough += other.builtin_rough;
        self.model_left += other.model_left;
        self.builtin_left += other.builtin_left;
        self.model_left_natural += other.model_left_natural;
        self.builtin_left_natural += other.builtin_left_natural;
        self.n += other.n;
        self.steps += other.steps;
    }

    /// The sum of the splits measured among `steps` (None when none was).
    pub fn over<'a>(steps: impl IntoIterator<Item = &'a StepStats>) -> Option<ErrorSplit> {
        steps.into_iter().filter_map(StepStats::split).fold(None, |acc, s| {
            let mut total = acc.unwrap_or_default();
            total.add(&s);
            Some(total)
        })
    }

    fn rms(&self, sum: f64) -> f64 {
        (sum / self.n.max(1) as f64).sqrt()
    }

    /// RMS of the model's smooth and rough error parts.
    pub fn model_rms(&self) -> (f64, f64) {
        (self.rms(self.model_smooth), self.rms(self.model_rough))
    }

    /// RMS of builtin's smooth and rough error parts on the same steps.
    pub fn builtin_rms(&self) -> (f64, f64) {
        (self.rms(self.builtin_smooth), self.rms(self.builtin_rough))
    }

    /// RMS of the error the budget's sweeps leave from the model's start and from builtin's.
    pub fn left_rms(&self) -> (f64, f64) {
        (self.rms(self.model_left), self.rms(self.builtin_left))
    }

    /// The mean over the steps of the RMS natural residual the sweeps leave from the model's
    /// start and from builtin's: the budget's same-states comparison.
    pub fn left_natural(&self) -> (f64, f64) {
        let steps = self.steps.max(1) as f64;
        (self.model_left_natural / steps, self.builtin_left_natural / steps)
    }

    /// The fractions of builtin's smooth and rough error (RMS) the model removes.
    pub fn removed(&self) -> (f64, f64) {
        let ((ms, mr), (bs, br)) = (self.model_rms(), self.builtin_rms());
        let frac = |m: f64, b: f64| if b > 0.0 { 1.0 - m / b } else { 0.0 };
        (frac(ms, bs), frac(mr, br))
    }
}

/// How accurate a model's steps were, whatever stopped their solves (means over the steps with
/// contacts): the natural residual after the solve (RMS and max over rows, impulse units), the
/// overlap the position pass left (max and mean over contacts, m), and the dynamic bodies' mean
/// kinetic energy in the last step-range phase (the settled pile's jitter, J). NaN where no step
/// had contacts; 0 for statistics recorded before these existed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Accuracy {
    pub natural_rms: f64,
    pub natural_max: f64,
    pub penetration_max: f64,
    pub penetration_mean: f64,
    pub late_kinetic_energy: f64,
}

impl Accuracy {
    /// Over `steps`; the late phase starts at step `late_from`.
    pub fn of<'a>(steps: impl Iterator<Item = &'a StepStats>, late_from: u32) -> Accuracy {
        let mut sums = [0.0f64; 4];
        let (mut n, mut late, mut late_n) = (0usize, 0.0f64, 0usize);
        for r in steps {
            if r.step >= late_from {
                late += r.kinetic_energy as f64;
                late_n += 1;
            }
            if r.contacts == 0 {
                continue;
            }
            for (sum, v) in sums.iter_mut().zip([r.natural_rms, r.natural_max, r.penetration_max, r.penetration_mean]) {
                *sum += v as f64;
            }
            n += 1;
        }
        let mean = |sum: f64, n: usize| if n == 0 { f64::NAN } else { sum / n as f64 };
        Accuracy {
            natural_rms: mean(sums[0], n),
            natural_max: mean(sums[1], n),
            penetration_max: mean(sums[2], n),
            penetration_mean: mean(sums[3], n),
            late_kinetic_energy: mean(late, late_n),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip() {
        let s = StepStats {
            run_id: u64::MAX - 3,
            simulation: 4,
            step: 17,
            model: "unet".into(),
            used_model: "builtin".into(),
            contacts: 300,
            persisting_contacts: 290,
            sweeps: 1000,
            converged: false,
            fallback: true,
            fallbacks_total: 2,
            final_residual: 2e-4,
            warm_error_normal_mse: 0.5,
            solve_us: 1234.5,
            max_speed: 3.0,
            builtin_sweeps: 870,
            builtin_measured: true,
            split_contacts: 300,
            split_budget: 8,
            split_model_smooth: 0.25,
            split_builtin_left: 1.5,
            split_builtin_left_natural: 0.01,
            ..StepStats::default()
        };
        assert_eq!(StepStats::from_header(&s.to_header()), s);
    }

    #[test]
    fn a_split_is_stored_and_summed_over_the_steps_that_measured_it() {
        let split = ErrorSplit {
            model_smooth: 1.0,
            model_rough: 4.0,
            builtin_smooth: 4.0,
            builtin_rough: 4.0,
            model_left: 0.5,
            builtin_left: 2.0,
            model_left_natural: 0.25,
            builtin_left_natural: 0.5,
            n: 4,
            steps: 1,
        };
        let mut measured = StepStats { contacts: 4, ..StepStats::default() };
        measured.set_split(Some(&split), 8);
        assert_eq!((measured.split(), measured.split_budget), (Some(split), 8));
        let unmeasured = StepStats { contacts: 9, ..StepStats::default() };
        assert_eq!(unmeasured.split(), None);
        assert_eq!(ErrorSplit::over([&unmeasured]), None);
        let total = ErrorSplit::over([&measured, &unmeasured, &measured]).unwrap();
        assert_eq!(total.n, 8);
        // RMS over the 8 contacts: sqrt(2/8) smooth, sqrt(8/8) rough; builtin's sqrt(8/8) both.
        assert_eq!(total.model_rms(), (0.5, 1.0));
        assert_eq!(total.removed(), (0.5, 0.0));
        assert_eq!(total.left_rms(), (0.125f64.sqrt(), 0.5f64.sqrt()));
        // The natural residual left is a mean over the two measured steps.
        assert_eq!((total.steps, total.left_natural()), (2, (0.25, 0.5)));
        // An unmeasured step stores nothing.
        measured.set_split(None, 8);
        assert_eq!((measured.split(), measured.split_budget), (None, 0));
    }

    #[test]
    fn json_has_a_text_run_id() {
        let s = StepStats { run_id: 1796139974837132098, ..StepStats::default() };
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains(r#""run_id":"1796139974837132098""#), "{json}");
        assert_eq!(serde_json::from_str::<StepStats>(&json).unwrap(), s);
    }
}
