//! What a run announced (control messages) against what arrived, so a report on a partial run
//! says what is missing instead of quietly averaging what is there.

use msgs::{Control, ControlKind};
use std::collections::{BTreeMap, HashMap};

#[derive(Debug, Default, Clone)]
struct RunInfo {
    model: Option<String>,
    /// The run's sweep cap (from its run start's parameters).
    max_sweeps: Option<u32>,
    /// The run's solver, in words (from its run start's parameters).
    solver: Option<String>,
    simulations_announced: Option<u32>,
    ended: bool,
}

#[derive(Debug, Default, Clone)]
struct SimInfo {
    steps_announced: Option<u32>,
    steps_ended: Option<u32>,
    steps_seen: u32,
    /// Steps whose statistics arrived (a second copy of one is dropped).
    seen: std::collections::BTreeSet<u32>,
}

/// `PGS, tolerance 0.0001, cap 1000`, or with `projected SOR 1.4` and `compliance 0.01` where
/// the run used them; a run that names its solver and stopping rule (`sor:1.4/down, natural
/// residual`) says them.
fn solver_in_words(p: &msgs::RunParams) -> String {
    let relaxation = msgs::recorded_relaxation(p.relaxation);
    let mut words = if !p.solver.is_empty() {
        p.solver.clone()
    } else if relaxation != 1.0 {
        format!("projected SOR {relaxation}")
    } else {
        "PGS".to_string()
    };
    match p.stop.as_str() {
        "" => {}
        "natural" => words += ", natural residual",
        rule => words += &format!(", {rule} rule"),
    }
    if p.compliance > 0.0 {
        words += &format!(", compliance {}", p.compliance);
    }
    words + &format!(", tolerance {}, cap {}", p.tolerance, p.max_sweeps)
}

/// The sweep bound of a step whose run's cap is unknown (no run start seen): far above any cap a
/// run uses, far below the forged 2^32 - 1.
pub const UNKNOWN_CAP_BOUND: u32 = 1_000_000;

/// Tracks run and simulation starts and ends, and the steps seen per simulation.
#[derive(Debug, Default)]
pub struct Completeness {
    runs: BTreeMap<u64, RunInfo>,
    sims: BTreeMap<(u64, u32), SimInfo>,
}

impl Completeness {
    /// Records a control message; `details` are its item bytes (a run start names its model).
    pub fn control(&mut self, c: &Control, details: &[u8]) {
        // Launcher notices (node down / up) and shutdowns belong to no run.
        if !matches!(
            c.kind(),
            Some(
                ControlKind::RunStart | ControlKind::RunEnd | ControlKind::SimulationStart | ControlKind::SimulationEnd
            )
        ) {
            return;
        }
        let run = self.runs.entry(c.step.run_id).or_default();
        match c.kind() {
            Some(ControlKind::RunStart) => {
                run.simulations_announced = Some(c.count);
                run.model = match msgs::control::details_of(c, details) {
                    Ok(msgs::ControlDetails::RunStart(p)) => {
                        run.max_sweeps = Some(p.max_sweeps);
                        run.solver = Some(solver_in_words(&p));
                        Some(p.model)
                    }
                    other => {
                        tracing::warn!("control: a run start whose details do not decode: {other:?}");
                        None
                    }
                };
            }
            Some(ControlKind::RunEnd) => run.ended = true,
            Some(ControlKind::SimulationStart) => {
                self.sims.entry((c.step.run_id, c.step.simulation)).or_default().steps_announced = Some(c.count);
            }
            Some(ControlKind::SimulationEnd) => {
                self.sims.entry((c.step.run_id, c.step.simulation)).or_default().steps_ended = Some(c.count);
            }
            _ => {}
        }
    }

    /// Whether a step's statistics are possible for what its run announced: sweeps within the
    /// run's cap, finite non-negative measurements, flags 0 or 1, persisting <= contacts, a step
    /// inside its simulation's announced length and not seen before. The reason otherwise (the
    /// caller logs and drops it, so a forged or corrupt frame cannot move a report's totals).
    pub fn implausible(&self, h: &msgs::SolveStatsHeader) -> Option<String> {
        let id = (h.step.run_id, h.step.simulation);
        match self.runs.get(&h.step.run_id).and_then(|r| r.max_sweeps) {
            Some(cap) if h.sweeps > cap => return Some(format!("{} sweeps, above the run's cap {cap}", h.sweeps)),
            None if h.sweeps > UNKNOWN_CAP_BOUND => {
                return Some(format!(
                    "{} sweeps in run {}, whose start was not seen, above {UNKNOWN_CAP_BOUND}",
                    h.sweeps, h.step.run_id
                ))
            }
            _ => {}
        }
        let measured = [
            ("final_residual", h.final_residual),
            ("warm_error_normal_mse", h.warm_error_normal_mse),
            ("warm_error_normal_max", h.warm_error_normal_max),
            ("warm_error_tangent_mse", h.warm_error_tangent_mse),
            ("warm_error_tangent_max", h.warm_error_tangent_max),
            ("solve_us", h.solve_us),
            ("step_us", h.step_us),
            ("warm_start_us", h.warm_start_us),
            ("kinetic_energy", h.kinetic_energy),
            ("max_speed", h.max_speed),
            ("natural_max", h.natural_max),
            ("natural_rms", h.natural_rms),
            ("penetration_max", h.penetration_max),
            ("penetration_mean", h.penetration_mean),
            ("pile_spread", h.pile_spread),
            ("split_model_smooth", h.split_model_smooth),
            ("split_model_rough", h.split_model_rough),
            ("split_builtin_smooth", h.split_builtin_smooth),
            ("split_builtin_rough", h.split_builtin_rough),
            ("split_model_left", h.split_model_left),
            ("split_builtin_left", h.split_builtin_left),
            ("split_model_left_natural", h.split_model_left_natural),
            ("split_builtin_left_natural", h.split_builtin_left_natural),
        ];
        if !h.pile_height.is_finite() {
            return Some(format!("pile_height = {}", h.pile_height));
        }
        if let Some((name, v)) = measured.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            return Some(format!("{name} = {v}"));
        }
        if h.converged > 1 || h.fallback > 1 {
            return Some(format!("flags converged = {}, fallback = {} (0 or 1)", h.converged, h.fallback));
        }
        if h.persisting_contacts > h.contacts {
            return Some(format!("{} persisting of {} contacts", h.persisting_contacts, h.contacts));
        }
        if h.split_contacts > h.contacts {
            return Some(format!("an error split over {} of {} contacts", h.split_contacts, h.contacts));
        }
        let sim = self.sims.get(&id);
        if let Some(steps) = sim.and_then(|s| s.steps_announced) {
            if h.step.step >= steps {
                return Some(format!("step {} of a simulation announced with {steps} steps", h.step.step));
            }
        }
        if sim.is_some_and(|s| s.seen.contains(&h.step.step)) {
            return Some(format!("step {} of simulation {} arrived twice", h.step.step, h.step.simulation));
        }
        None
    }

    /// The live path's checks over the steps of a file (`--from-steps`), in order: the index
    /// of the first impossible step and why, or `None`. A step seen twice is impossible too, so
    /// a duplicated row cannot overwrite or double an earlier one.
    pub fn first_implausible<'a>(steps: impl IntoIterator<Item = &'a msgs::StepStats>) -> Option<(usize, String)> {
        // Per model: a run has one model, but a file may hold models under one run id.
        let mut seen: HashMap<&str, Completeness> = HashMap::new();
        for (i, s) in steps.into_iter().enumerate() {
            let model = seen.entry(s.model.as_str()).or_default();
            if let Some(why) = model.implausible(&s.to_header()) {
                return Some((i, why));
            }
            model.step(s.run_id, s.simulation, s.step, &s.model);
        }
        None
    }

    /// Records a step's statistics.
    pub fn step(&mut self, run_id: u64, simulation: u32, step: u32, model: &str) {
        let run = self.runs.entry(run_id).or_default();
        run.model.get_or_insert_with(|| model.to_string());
        let sim = self.sims.entry((run_id, simulation)).or_default();
        sim.steps_seen += 1;
        sim.seen.insert(step);
    }

    /// Runs whose end was announced.
    pub fn runs_ended(&self) -> usize {
        self.runs.values().filter(|r| r.ended).count()
    }

    /// The solvers the runs announced, in words, each once (a report compares models only under
    /// one solver; more than one is worth a reader's notice).
    pub fn solvers(&self) -> Vec<String> {
        let set: std::collections::BTreeSet<&String> = self.runs.values().filter_map(|r| r.solver.as_ref()).collect();
        set.into_iter().cloned().collect()
    }

    /// Everything announced but not received, one sentence each; empty for a complete run.
    pub fn missing(&self) -> Vec<String> {
        let mut out = Vec::new();
        let label = |id: &u64| match self.runs.get(id).and_then(|r| r.model.clone()) {
            Some(m) => format!("run {id} (model {m})"),
            None => format!("run {id}"),
        };
        for (id, run) in &self.runs {
            if run.simulations_announced.is_none() {
                out.push(format!("{}: no run start seen (the metrics node started late?)", label(id)));
            }
            if !run.ended {
                out.push(format!("{}: no run end (the simulator stopped or died before finishing)", label(id)));
            }
            let sims: Vec<_> = self.sims.iter().filter(|((r, _), _)| r == id).collect();
            if let Some(n) = run.simulations_announced {
                let ended = sims.iter().filter(|(_, s)| s.steps_ended.is_some()).count();
                if ended < n as usize {
                    out.push(format!("{}: {ended} of {n} announced simulations finished", label(id)));
                }
            }
            for ((_, sim), s) in sims {
                let expected = s.steps_ended.or(s.steps_announced);
                match (s.steps_ended, expected) {
                    (None, Some(e)) => out.push(format!(
                        "{}: simulation {sim} has {} of {e} steps and no end",
                        label(id),
                        s.steps_seen
                    )),
                    (Some(e), _) if s.steps_seen < e => out.push(format!(
                        "{}: simulation {sim}: {} of {e} steps' statistics arrived",
                        label(id),
                        s.steps_seen
                    )),
                    _ => {}
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::StepHeader;

    fn c(run_id: u64, simulation: u32, kind: ControlKind, count: u32) -> Control {
        Control { step: StepHeader { run_id, simulation, step: 0 }, kind: kind as u32, count }
    }

    /// The details of a run start of `model`.
    fn started(model: &str) -> Vec<u8> {
        let p =
            msgs::RunParams { seeds: vec![0], steps: 2, model: model.into(), max_sweeps: 1000, ..Default::default() };
        msgs::ControlMsg::run_start(StepHeader::default(), &p).items
    }

    #[test]
    fn runs_say_their_solver() {
        let mut k = Completeness::default();
        k.control(&c(1, 0, ControlKind::RunStart, 1), &started("builtin"));
        let p = msgs::RunParams {
            model: "builtin".into(),
            tolerance: 1e-4,
            max_sweeps: 1000,
            compliance: 0.01,
            relaxation: 1.4,
            ..Default::default()
        };
        k.control(&c(2, 0, ControlKind::RunStart, 1), &msgs::ControlMsg::run_start(StepHeader::default(), &p).items);
        let named =
            msgs::RunParams { solver: "nncg/down".into(), stop: "natural".into(), compliance: 0.0, ..p.clone() };
        k.control(
            &c(3, 0, ControlKind::RunStart, 1),
            &msgs::ControlMsg::run_start(StepHeader::default(), &named).items,
        );
        assert_eq!(
            k.solvers(),
            vec![
                "PGS, tolerance 0, cap 1000",
                "nncg/down, natural residual, tolerance 0.0001, cap 1000",
                "projected SOR 1.4, compliance 0.01, tolerance 0.0001, cap 1000"
            ]
        );
    }

    #[test]
    fn complete_run_has_nothing_missing() {
        let mut k = Completeness::default();
        k.control(&c(1, 0, ControlKind::RunStart, 1), &started("none"));
        k.control(&c(1, 0, ControlKind::SimulationStart, 2), &[]);
        k.step(1, 0, 0, "none");
        k.step(1, 0, 1, "none");
        k.control(&c(1, 0, ControlKind::SimulationEnd, 2), &[]);
        k.control(&c(1, 0, ControlKind::RunEnd, 1), &[]);
        assert!(k.missing().is_empty(), "{:?}", k.missing());
        assert_eq!(k.runs_ended(), 1);
    }

    #[test]
    fn a_sim_that_died_is_named_with_its_missing_steps() {
        let mut k = Completeness::default();
        k.control(&c(1, 0, ControlKind::RunStart, 2), &started("builtin"));
        k.control(&c(1, 7, ControlKind::SimulationStart, 250), &[]);
        for step in 0..120 {
            k.step(1, 7, step, "builtin");
        }
        let m = k.missing();
        assert!(
            m.contains(
                &"run 1 (model builtin): no run end (the simulator stopped or died before finishing)".to_string()
            ),
            "{m:?}"
        );
        assert!(m.contains(&"run 1 (model builtin): 0 of 2 announced simulations finished".to_string()), "{m:?}");
        assert!(
            m.contains(&"run 1 (model builtin): simulation 7 has 120 of 250 steps and no end".to_string()),
            "{m:?}"
        );
    }

    #[test]
    fn impossible_statistics_are_named_and_possible_ones_pass() {
        let mut k = Completeness::default();
        k.control(&c(1, 0, ControlKind::RunStart, 1), &started("builtin"));
        k.control(&c(1, 0, ControlKind::SimulationStart, 250), &[]);
        let good = msgs::SolveStatsHeader {
            step: StepHeader { run_id: 1, simulation: 0, step: 3 },
            sweeps: 1000,
            contacts: 10,
            persisting_contacts: 9,
            converged: 1,
            ..Default::default()
        };
        assert_eq!(k.implausible(&good), None);
        let bad = |f: &dyn Fn(&mut msgs::SolveStatsHeader)| {
            let mut h = good;
            f(&mut h);
            k.implausible(&h).expect("refused")
        };
        assert!(bad(&|h| h.sweeps = u32::MAX).contains("above the run's cap 1000"));
        assert!(bad(&|h| h.solve_us = f32::NAN).contains("solve_us = NaN"));
        assert!(bad(&|h| h.split_model_left = -1.0).contains("split_model_left = -1"));
        assert!(bad(&|h| h.split_contacts = 11).contains("an error split over 11 of 10 contacts"));
        assert!(bad(&|h| h.warm_error_normal_mse = -1.0).contains("warm_error_normal_mse"));
        assert!(bad(&|h| h.converged = 7).contains("0 or 1"));
        assert!(bad(&|h| h.persisting_contacts = 11).contains("persisting"));
        assert!(bad(&|h| h.step.step = 250).contains("announced with 250 steps"));
        k.step(1, 0, 3, "builtin");
        assert!(k.implausible(&good).unwrap().contains("arrived twice"));
        // A run whose start was not seen: only the far bound applies.
        let other =
            msgs::SolveStatsHeader { step: StepHeader { run_id: 2, simulation: 0, step: 0 }, sweeps: 5000, ..good };
        assert_eq!(k.implausible(&other), None);
        assert!(k.implausible(&msgs::SolveStatsHeader { sweeps: UNKNOWN_CAP_BOUND + 1, ..other }).is_some());
    }
}
