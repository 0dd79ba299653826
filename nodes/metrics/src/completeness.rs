//! What a run announced (control messages) against what arrived, so a report on a partial run
//! says what is missing instead of quietly averaging what is there.

use msgs::{Control, ControlKind};
use std::collections::BTreeMap;

#[derive(Debug, Default, Clone)]
struct RunInfo {
    model: Option<String>,
    simulations_announced: Option<u32>,
    ended: bool,
}

#[derive(Debug, Default, Clone)]
struct SimInfo {
    steps_announced: Option<u32>,
    steps_ended: Option<u32>,
    steps_seen: u32,
}

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
                    Ok(msgs::ControlDetails::RunStart(p)) => Some(p.model),
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

    /// Records a step's statistics.
    pub fn step(&mut self, run_id: u64, simulation: u32, model: &str) {
        let run = self.runs.entry(run_id).or_default();
        run.model.get_or_insert_with(|| model.to_string());
        self.sims.entry((run_id, simulation)).or_default().steps_seen += 1;
    }

    /// Runs whose end was announced.
    pub fn runs_ended(&self) -> usize {
        self.runs.values().filter(|r| r.ended).count()
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
        let p = msgs::RunParams {
            scene: "ball-box".into(),
            n: 100,
            seeds: vec![0],
            steps: 2,
            model: model.into(),
            fallback: "builtin".into(),
            tolerance: 1e-4,
            max_sweeps: 1000,
            sampler: "native".into(),
            dt: 0.01,
        };
        msgs::ControlMsg::run_start(StepHeader::default(), &p).items
    }

    #[test]
    fn complete_run_has_nothing_missing() {
        let mut k = Completeness::default();
        k.control(&c(1, 0, ControlKind::RunStart, 1), &started("none"));
        k.control(&c(1, 0, ControlKind::SimulationStart, 2), &[]);
        k.step(1, 0, "none");
        k.step(1, 0, "none");
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
        for _ in 0..120 {
            k.step(1, 7, "builtin");
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
}
