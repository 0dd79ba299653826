//! What a warm-start model is: the [`WarmStartModel`] trait, what it may read
//! ([`WarmStartInput`], only what its [`Needs`] ask for), why it may give no answer
//! ([`Unavailable`]), and the [`WarmStarter`] that falls back to another model when it does.
//!
//! The world fills the input; a model never calls back into the world. Models that read a
//! grid or a node's answer over the bus get it through a [`GridSource`] or a
//! [`ContactWarmSource`], which own the deadline.

use crate::contact::{ContactPoint, ImpulseHistory};
use crate::problem::Problem;
use crate::solver::rows::{ContactRow, Impulse, SolverBody};

/// What a model reads beyond the step's contacts and their history; the world computes each
/// part only for models that ask for it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Needs {
    /// The step's velocity problem as data ([`WarmStartInput::problem`]).
    pub problem: bool,
    /// The solver's rows and bodies ([`WarmStartInput::rows`]).
    pub rows: bool,
    /// The step's exact solution ([`WarmStartInput::exact`]): only the evaluation's references.
    pub exact: bool,
}

impl Needs {
    /// The step's problem as data.
    pub const PROBLEM: Needs = Needs { problem: true, rows: false, exact: false };
    /// The solver's rows and bodies.
    pub const ROWS: Needs = Needs { problem: false, rows: true, exact: false };
    /// The step's exact solution.
    pub const EXACT: Needs = Needs { problem: false, rows: false, exact: true };

    /// Everything either asks for.
    pub fn union(self, other: Needs) -> Needs {
        Needs {
            problem: self.problem || other.problem,
            rows: self.rows || other.rows,
            exact: self.exact || other.exact,
        }
    }
}

/// The solver's view of the step: its rows, its bodies (velocities after external forces,
/// inverse masses) and its relative compliance.
#[derive(Debug, Clone, Copy)]
pub struct StepRows<'a> {
    /// One row per contact, in the contacts' order.
    pub rows: &'a [ContactRow],
    /// Per body id.
    pub bodies: &'a [SolverBody],
    /// `SolveParams::compliance` of the run (0: rigid).
    pub compliance: f32,
}

/// What a model may look at to produce a warm start.
pub struct WarmStartInput<'a> {
    /// Run id of the graph.
    pub run_id: u64,
    /// Simulation index (its seed).
    pub simulation: u32,
    /// Step being solved.
    pub step: u32,
    /// The step's contacts, sorted by key; one impulse per contact is expected.
    pub contacts: &'a [ContactPoint],
    /// Final impulses of the two previous steps.
    pub history: &'a ImpulseHistory,
    /// The step's velocity problem, when the model needs it ([`Needs::problem`]).
    pub problem: Option<&'a Problem>,
    /// The solver's rows and bodies, when the model needs them ([`Needs::rows`]).
    pub rows: Option<StepRows<'a>>,
    /// The step's problem solved from builtin's warm start to the oracle's tolerance, one impulse
    /// per contact, when the model needs it ([`Needs::exact`]). The oracle *is* the solve: only
    /// the evaluation's reference models read it.
    pub exact: Option<&'a [Impulse]>,
}

/// A step once done (solved, integrated, positions corrected), for a model that works ahead
/// ([`WarmStartModel::after_step`]).
pub struct SolvedStep<'a> {
    pub run_id: u64,
    pub simulation: u32,
    pub step: u32,
    /// The step's problem as solved, when the model asked for it ([`Needs::problem`]).
    pub problem: Option<&'a Problem>,
    /// The solution, one impulse per contact in the problem's order.
    pub impulses: &'a [Impulse],
    /// The bodies after the step (velocities integrated, positions corrected), per body id.
    pub bodies: &'a [crate::body::BodyState],
    /// The step's contacts as the position pass measures them, one per contact...
    pub geometry: &'a [crate::solver::PositionRow],
    /// ... at these poses (after the position pass), per body id.
    pub poses: &'a [crate::solver::PoseBody],
    /// What external forces add to a dynamic body's velocity in one step (`dt * g`).
    pub gravity_dt: [f32; 2],
}

/// Why a model gave no warm start this step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unavailable(pub String);

/// A source of warm starts. One implementation per model; adding one never touches the solver.
pub trait WarmStartModel {
    /// The model's name (in statistics).
    fn name(&self) -> &str;

    /// Called before the first step of every simulation.
    fn begin_simulation(&mut self, _simulation: u32, _seed: u64) {}

    /// What the model reads beyond contacts and history (nothing by default).
    fn needs(&self) -> Needs {
        Needs::default()
    }

    /// Writes one impulse per contact of `input` into `out` (zeroed beforehand), or says why it
    /// cannot this step.
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable>;

    /// Called once the step is done: a model that predicts the next step's warm start off the
    /// critical path sends its input here (nothing by default).
    fn after_step(&mut self, _done: &SolvedStep<'_>) {}
}

/// The exact solution of the step, or why a reference model has none.
pub fn exact_solution<'a>(input: &WarmStartInput<'a>) -> Result<&'a [Impulse], Unavailable> {
    input.exact.ok_or_else(|| Unavailable("no exact solution: the world was not asked for it".into()))
}

/// The step's problem as data, or why a model that reads it has none.
pub fn step_problem<'a>(input: &WarmStartInput<'a>) -> Result<&'a Problem, Unavailable> {
    input.problem.ok_or_else(|| Unavailable("the world did not capture the step's problem".into()))
}

/// Delivers the impulse grid computed from step `step` of simulation `simulation`, or `None` when
/// it is late (the source owns the deadline) or will never come.
pub trait GridSource {
    /// The grid of `(simulation, step)`, waiting up to the source's deadline.
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid>;
}

impl<F> GridSource for F
where
    F: FnMut(u64, u32, u32) -> Option<msgs::Grid>,
{
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Grid> {
        self(run_id, simulation, step)
    }
}

/// Delivers the per-contact warm start a node computed from step `step`'s own problem, or `None`
/// when it is late (the source owns the deadline) or will never come.
pub trait ContactWarmSource {
    /// The warm start of `(simulation, step)`, waiting up to the source's deadline.
    fn warm(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Contacts>;
}

/// A model and the model that stands in when it is unavailable, with the fallback count.
pub struct WarmStarter {
    /// The model asked for.
    pub model: Box<dyn WarmStartModel>,
    /// The stand-in (a local model, never unavailable in practice).
    pub fallback: Box<dyn WarmStartModel>,
    fallbacks_total: u32,
}

impl WarmStarter {
    /// `model`, falling back to `fallback`.
    pub fn new(model: Box<dyn WarmStartModel>, fallback: Box<dyn WarmStartModel>) -> WarmStarter {
        WarmStarter { model, fallback, fallbacks_total: 0 }
    }

    /// Resets per-simulation state (models and the fallback count).
    pub fn begin_simulation(&mut self, simulation: u32, seed: u64) {
        self.fallbacks_total = 0;
        self.model.begin_simulation(simulation, seed);
        self.fallback.begin_simulation(simulation, seed);
    }

    /// What the model and its fallback read.
    pub fn needs(&self) -> Needs {
        self.model.needs().union(self.fallback.needs())
    }

    /// Fallbacks in this simulation so far.
    pub fn fallbacks_total(&self) -> u32 {
        self.fallbacks_total
    }

    /// The name of the model that gave the warm start: the fallback's when it fell back.
    pub fn used_name(&self, fell_back: bool) -> &str {
        if fell_back {
            self.fallback.name()
        } else {
            self.model.name()
        }
    }

    /// Tells the model the step is done (see [`WarmStartModel::after_step`]).
    pub fn after_step(&mut self, done: &SolvedStep<'_>) {
        self.model.after_step(done);
    }

    /// Runs the model, or the fallback when it is unavailable; returns whether it fell back.
    pub fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> bool {
        out.fill(Impulse::default());
        // A start that is not finite (a model that overflowed, a damaged served frame) would
        // poison the solve: the step falls back, counted, like a missing one.
        let checked = self.model.warm_start(input, out).and_then(|()| {
            match out.iter().filter(|i| !(i.normal.is_finite() && i.tangent.is_finite())).count() {
                0 => Ok(()),
                n => Err(Unavailable(format!("{n} of {} warm starts are not finite", out.len()))),
            }
        });
        match checked {
            Ok(()) => false,
            Err(Unavailable(why)) => {
                tracing::debug!(model = self.model.name(), step = input.step, "fallback: {why}");
                self.fallbacks_total += 1;
                out.fill(Impulse::default());
                if let Err(Unavailable(why)) = self.fallback.warm_start(input, out) {
                    // A fallback that fails too leaves the zero guess: still a valid start.
                    tracing::warn!(model = self.fallback.name(), "fallback unavailable too: {why}");
                    out.fill(Impulse::default());
                }
                true
            }
        }
    }
}

/// Runs models on hand-made steps (step 2, body 0 fixed), for the models' unit tests.
#[cfg(test)]
pub(crate) mod harness {
    use super::*;
    use crate::contact::ContactKey;

    /// Runs `model` on `contacts` after the given history; no rows, no exact solution.
    pub(crate) fn guess(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
    ) -> Vec<Impulse> {
        run_step(model, contacts, history, None, None)
    }

    /// Runs `model` on `contacts`; the step's exact solution is `exact`.
    pub(crate) fn guess_with_exact(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        exact: &[Impulse],
    ) -> Vec<Impulse> {
        run_step(model, contacts, history, Some(exact), None)
    }

    /// Runs `model` on `contacts` with the solver's `rows` and `bodies` and its `compliance`:
    /// the models that solve the step's own problem.
    pub(crate) fn guess_on_rows(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        rows: &[ContactRow],
        bodies: &[SolverBody],
        compliance: f32,
    ) -> Vec<Impulse> {
        run_step(model, contacts, history, None, Some(StepRows { rows, bodies, compliance }))
    }

    /// The contact of ball `body_b` on the floor (body 0) at `x`, feature `feature`.
    pub(crate) fn floor_contact(body_b: u32, feature: u32, x: f32) -> ContactPoint {
        ContactPoint {
            key: ContactKey { body_a: 0, body_b, feature },
            point: rapier2d::math::Vec2::new(x, 0.0),
            normal: rapier2d::math::Vec2::Y,
            penetration: 0.0,
            friction: 0.5,
        }
    }

    fn run_step(
        model: &mut dyn WarmStartModel,
        contacts: &[ContactPoint],
        history: &ImpulseHistory,
        exact: Option<&[Impulse]>,
        rows: Option<StepRows<'_>>,
    ) -> Vec<Impulse> {
        let input = WarmStartInput { run_id: 0, simulation: 0, step: 2, contacts, history, problem: None, rows, exact };
        let mut out = vec![Impulse::default(); contacts.len()];
        model.warm_start(&input, &mut out).unwrap();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::harness::floor_contact;
    use super::*;

    /// A model that answers NaN for its first contact (a network that overflowed).
    struct Overflowing;

    impl WarmStartModel for Overflowing {
        fn name(&self) -> &str {
            "overflowing"
        }
        fn warm_start(&mut self, _: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
            out.fill(Impulse { normal: 1.0, tangent: 0.0 });
            out[0].normal = f32::NAN;
            Ok(())
        }
    }

    /// The stand-in: a constant start.
    struct Half;

    impl WarmStartModel for Half {
        fn name(&self) -> &str {
            "half"
        }
        fn warm_start(&mut self, _: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
            out.fill(Impulse { normal: 0.5, tangent: 0.0 });
            Ok(())
        }
    }

    /// A model's non-finite warm start never reaches the solver: the step falls back, counted.
    #[test]
    fn a_non_finite_warm_start_falls_back_and_is_counted() {
        let contacts = [floor_contact(1, 0, 0.0), floor_contact(2, 0, 1.0)];
        let history = ImpulseHistory::default();
        let input = WarmStartInput {
            run_id: 0,
            simulation: 0,
            step: 2,
            contacts: &contacts,
            history: &history,
            problem: None,
            rows: None,
            exact: None,
        };
        let mut warm = WarmStarter::new(Box::new(Overflowing), Box::new(Half));
        let mut out = vec![Impulse::default(); contacts.len()];
        assert!(warm.warm_start(&input, &mut out), "did not fall back");
        assert_eq!(warm.fallbacks_total(), 1);
        assert!(out.iter().all(|i| *i == Impulse { normal: 0.5, tangent: 0.0 }), "the stand-in's start: {out:?}");
    }
}
