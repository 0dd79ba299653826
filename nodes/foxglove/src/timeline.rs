//! Simulation time for viz files: every frame of a recording stamped with the time of its step,
//! step x dt from its run's parameters, so Foxglove's file mode plays the physics at real speed.
//!
//! The timeline starts at 0 and lays the runs end to end in the order their run starts were
//! recorded; within a run, its simulations end to end in the order of its seeds:
//!
//! `time(run, simulation, step) = origin(run) + (index of simulation in seeds x steps + step) x dt_ns`
//!
//! with `dt_ns` = dt in whole nanoseconds (`round(dt x 1e9)`, so consecutive steps are exactly
//! `dt_ns` apart) and `origin(run)` = the sum of the earlier runs' spans (`seeds x steps x dt_ns`).
//! Frames of a run without parameters (a recording that missed its run start, or one made before
//! run starts carried dt) keep their recorded log time.

use msgs::{Control, ControlKind, RunParams, StepHeader};
use std::collections::BTreeMap;

/// One run's place on the timeline.
#[derive(Debug, Clone, PartialEq)]
struct Span {
    origin_ns: u64,
    dt_ns: u64,
    steps: u32,
    seeds: Vec<u64>,
}

impl Span {
    fn len_ns(&self) -> u64 {
        self.seeds.len() as u64 * u64::from(self.steps) * self.dt_ns
    }
}

/// A time step in whole nanoseconds; `None` for a step that is not positive and finite.
pub fn dt_ns(dt: f32) -> Option<u64> {
    let ns = (f64::from(dt) * 1e9).round();
    (ns.is_finite() && ns >= 1.0).then_some(ns as u64)
}

/// The runs of a recording laid end to end in simulation time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Timeline {
    runs: BTreeMap<u64, Span>,
    end_ns: u64,
}

impl Timeline {
    /// Places run `run_id` after the runs added so far. False when its dt is unusable or the run
    /// was added already (the first run start counts).
    pub fn add_run(&mut self, run_id: u64, params: &RunParams) -> bool {
        let Some(dt_ns) = dt_ns(params.dt) else { return false };
        if self.runs.contains_key(&run_id) {
            return false;
        }
        let span = Span { origin_ns: self.end_ns, dt_ns, steps: params.steps, seeds: params.seeds.clone() };
        self.end_ns += span.len_ns();
        self.runs.insert(run_id, span);
        true
    }

    /// The runs on the timeline.
    pub fn runs(&self) -> usize {
        self.runs.len()
    }

    /// The time step of run `run_id` in nanoseconds, if the run is on the timeline.
    pub fn dt_ns(&self, run_id: u64) -> Option<u64> {
        self.runs.get(&run_id).map(|s| s.dt_ns)
    }

    /// The simulation time of step `h`; `None` when its run is not on the timeline or its
    /// simulation is not one of the run's seeds.
    pub fn step_time(&self, h: &StepHeader) -> Option<u64> {
        let span = self.runs.get(&h.run_id)?;
        let index = span.seeds.iter().position(|&s| s == u64::from(h.simulation))? as u64;
        Some(span.origin_ns + (index * u64::from(span.steps) + u64::from(h.step)) * span.dt_ns)
    }

    /// The simulation time of a control message: a run start at its run's origin, a run end at
    /// its run's end, a simulation start / end at its step; `None` for the others (node notices
    /// belong to no run) and for runs not on the timeline.
    pub fn control_time(&self, c: &Control) -> Option<u64> {
        let span = self.runs.get(&c.step.run_id)?;
        match c.kind()? {
            ControlKind::RunStart => Some(span.origin_ns),
            ControlKind::RunEnd => Some(span.origin_ns + span.len_ns()),
            ControlKind::SimulationStart | ControlKind::SimulationEnd => self.step_time(&c.step),
            ControlKind::NodeDown | ControlKind::NodeUp | ControlKind::Shutdown => None,
        }
    }
}

/// Where the times of a viz file come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamp {
    /// Simulation time from the run's parameters.
    Simulation,
    /// The recorded log time (no parameters for the frame's run).
    LogTime,
    /// The latest time stamped so far (a control message of no run, e.g. a node notice).
    Latest,
}

/// Stamps the frames of a recording as they are read: simulation time where the timeline knows
/// the run, the recorded log time otherwise (said once, with `tracing::warn`).
#[derive(Debug, Default)]
pub struct FileClock {
    timeline: Timeline,
    latest_ns: u64,
    warned: bool,
    /// Frames stamped, per source of their time.
    pub simulation: u64,
    pub log_time: u64,
    pub latest: u64,
}

impl FileClock {
    pub fn new(timeline: Timeline) -> FileClock {
        FileClock { timeline, ..FileClock::default() }
    }

    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }

    /// The time of a frame of step `h` recorded at `log_time`.
    pub fn step(&mut self, h: &StepHeader, log_time: u64) -> u64 {
        match self.timeline.step_time(h) {
            Some(t) => self.stamp(Stamp::Simulation, t),
            None => self.fall_back(h, log_time),
        }
    }

    /// The time of a control message recorded at `log_time`.
    pub fn control(&mut self, c: &Control, log_time: u64) -> u64 {
        if let Some(t) = self.timeline.control_time(c) {
            return self.stamp(Stamp::Simulation, t);
        }
        match c.kind() {
            Some(ControlKind::NodeDown | ControlKind::NodeUp | ControlKind::Shutdown) => {
                self.stamp(Stamp::Latest, self.latest_ns)
            }
            _ => self.fall_back(&c.step, log_time),
        }
    }

    fn fall_back(&mut self, h: &StepHeader, log_time: u64) -> u64 {
        if !self.warned {
            self.warned = true;
            let why = if self.timeline.dt_ns(h.run_id).is_some() {
                format!("simulation {} is not among the run's seeds", h.simulation)
            } else {
                "the recording has no run start with a time step (dt) for it".to_string()
            };
            tracing::warn!(
                run_id = h.run_id,
                "stamping the frames of run {} with their recorded log time, not simulation time: {why}",
                h.run_id
            );
        }
        self.stamp(Stamp::LogTime, log_time)
    }

    fn stamp(&mut self, how: Stamp, t: u64) -> u64 {
        match how {
            Stamp::Simulation => self.simulation += 1,
            Stamp::LogTime => self.log_time += 1,
            Stamp::Latest => self.latest += 1,
        }
        self.latest_ns = self.latest_ns.max(t);
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(seeds: Vec<u64>, steps: u32, dt: f32) -> RunParams {
        RunParams { seeds, steps, dt, model: "builtin".into(), ..Default::default() }
    }

    fn at(run_id: u64, simulation: u32, step: u32) -> StepHeader {
        StepHeader { run_id, simulation, step }
    }

    #[test]
    fn dt_is_rounded_to_whole_nanoseconds() {
        assert_eq!(dt_ns(0.01), Some(10_000_000), "0.01f32 is 9,999,999.78 ns");
        assert_eq!(dt_ns(1.0 / 60.0), Some(16_666_668), "1/60 as f32 is 16,666,667.54 ns");
        assert_eq!(dt_ns(0.0), None);
        assert_eq!(dt_ns(-0.01), None);
        assert_eq!(dt_ns(f32::NAN), None);
    }

    #[test]
    fn runs_and_their_simulations_are_laid_end_to_end() {
        let mut t = Timeline::default();
        assert!(t.add_run(7, &params(vec![5, 3], 100, 0.01)));
        assert!(t.add_run(2, &params(vec![0], 10, 0.02)));
        assert!(!t.add_run(7, &params(vec![0], 1, 1.0)), "the first run start counts");
        let ms = 1_000_000;
        assert_eq!(t.step_time(&at(7, 5, 0)), Some(0));
        assert_eq!(t.step_time(&at(7, 5, 99)), Some(990 * ms));
        assert_eq!(t.step_time(&at(7, 3, 0)), Some(1000 * ms), "the second seed follows the first");
        assert_eq!(t.step_time(&at(2, 0, 1)), Some(2000 * ms + 20 * ms), "the second run follows the first");
        assert_eq!(t.step_time(&at(7, 4, 0)), None, "not a seed of the run");
        assert_eq!(t.step_time(&at(9, 0, 0)), None, "no parameters");

        let c = |h: StepHeader, kind: ControlKind| Control { step: h, kind: kind as u32, count: 0 };
        assert_eq!(t.control_time(&c(at(7, 0, 0), ControlKind::RunStart)), Some(0));
        assert_eq!(t.control_time(&c(at(7, 0, 0), ControlKind::RunEnd)), Some(2000 * ms));
        assert_eq!(t.control_time(&c(at(7, 3, 100), ControlKind::SimulationEnd)), Some(2000 * ms));
        assert_eq!(t.control_time(&c(at(7, 0, 0), ControlKind::NodeDown)), None);
    }

    #[test]
    fn frames_of_unknown_runs_keep_their_log_time() {
        let mut t = Timeline::default();
        t.add_run(1, &params(vec![0], 10, 0.5));
        let mut clock = FileClock::new(t);
        assert_eq!(clock.step(&at(1, 0, 3), 123), 1_500_000_000);
        assert_eq!(clock.step(&at(2, 0, 3), 456), 456);
        let notice = Control { step: StepHeader::default(), kind: ControlKind::NodeDown as u32, count: 0 };
        assert_eq!(clock.control(&notice, 789), 1_500_000_000, "a notice goes at the latest time");
        assert_eq!((clock.simulation, clock.log_time, clock.latest), (1, 1, 1));
    }
}
