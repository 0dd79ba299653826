//! Warm starts from another node — grids (the SPH node's `grid/contacts`, the U-Net's
//! `grid/unet`) for grid-based models, per-contact impulses (the `dc-gnn` node's `warm/gnn`) for
//! `gnn-node` — with the fault handling a graph needs: the launcher's node-down / node-up notices
//! on `control` say whether the producer is there; a step waits for its frame up to the deadline
//! (lockstep: up to `lockstep_timeout`, after which the producer counts as lost), at once falls
//! back while the producer is down, and after it came back waits at most `resume_patience` until
//! frames flow again.
//!
//! [`Inbox`] is what the state machine reads; `dc-sim` implements it with bus subscribers, the
//! tests with scripted queues.

use crate::warm::{ContactWarmSource, GridSource};
use msgs::{ControlDetails, ControlKind, ControlMsg, Grid, StepHeader};
use std::cmp::Ordering;
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

/// A frame that belongs to one step.
pub trait StepFrame {
    fn step(&self) -> StepHeader;
}

impl StepFrame for Grid {
    fn step(&self) -> StepHeader {
        self.header.step
    }
}

impl StepFrame for msgs::Contacts {
    fn step(&self) -> StepHeader {
        self.header
    }
}

/// The messages a source reads: frames of one topic, and control.
pub trait Inbox<F> {
    /// The frames' topic (notices name the topics a dead node published).
    fn topic(&self) -> &str;
    /// A waiting frame, if any.
    fn try_frame(&mut self) -> Result<Option<F>, String>;
    /// A frame, waiting up to `timeout`.
    fn frame_timeout(&mut self, timeout: Duration) -> Result<Option<F>, String>;
    /// A waiting control message, if any.
    fn try_control(&mut self) -> Result<Option<ControlMsg>, String>;
    /// Whether the node was asked to stop (a lockstep wait must not outlive it).
    fn shutdown(&self) -> bool;
}

/// Whether the node producing our frames is there, as the launcher's notices tell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Producer {
    /// Running: wait up to the deadline (lockstep: up to `lockstep_timeout`).
    Up,
    /// Its node died: no wait, every step falls back.
    Down,
    /// Back (or lost without a notice): wait at most `resume_patience` until a grid arrives. Its
    /// restart may miss the grid of the step in flight, so an unbounded wait could hang forever.
    Resuming,
}

/// How long a source waits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waits {
    /// `None`: lockstep (wait for every grid).
    pub deadline: Option<Duration>,
    pub lockstep_timeout: Duration,
    pub resume_patience: Duration,
}

/// The frame of a step from an inbox, waiting as [`Waits`] and the producer's state say; later
/// frames are kept for their step. The step loop calls [`BusSource::between_steps`] every step
/// so that frames of other simulators sharing the producer, frames of steps that needed none and
/// our own control messages never fill a queue (the producer would stall on it while another
/// simulator waits for its reply).
pub struct BusSource<I, F> {
    inbox: I,
    producer: Producer,
    waits: Waits,
    /// Simulation ids of this simulator: several simulators may share one producer.
    simulations: BTreeSet<u32>,
    pending: Option<F>,
}

/// The longest single wait, so that notices and shutdown are seen while waiting.
const POLL: Duration = Duration::from_millis(20);

impl<F: StepFrame, I: Inbox<F>> BusSource<I, F> {
    pub fn new(inbox: I, waits: Waits, simulations: impl IntoIterator<Item = u32>) -> Self {
        BusSource {
            inbox,
            producer: Producer::Up,
            waits,
            simulations: simulations.into_iter().collect(),
            pending: None,
        }
    }

    pub fn producer(&self) -> Producer {
        self.producer
    }

    /// Applies the launcher's notices about the node that publishes our topic.
    fn read_control(&mut self) {
        loop {
            let c = match self.inbox.try_control() {
                Ok(Some(c)) => c,
                Ok(None) => return,
                Err(e) => {
                    tracing::warn!("control subscriber: {e}");
                    return;
                }
            };
            if !matches!(c.header.kind(), Some(ControlKind::NodeDown | ControlKind::NodeUp)) {
                continue;
            }
            let (notice, up) = match c.details() {
                Ok(ControlDetails::NodeDown(n)) => (n, false),
                Ok(ControlDetails::NodeUp(n)) => (n, true),
                Ok(_) => continue,
                Err(e) => {
                    tracing::warn!("control: dropped a notice whose details do not decode: {e}");
                    continue;
                }
            };
            let topic = self.inbox.topic();
            if !notice.publishes.iter().any(|t| t == topic) {
                continue;
            }
            if up {
                tracing::info!(node = notice.node, topic, "warm-start producer back: resuming");
                self.producer = Producer::Resuming;
            } else {
                tracing::warn!(node = notice.node, topic, "warm-start producer down: falling back until it returns");
                self.producer = Producer::Down;
            }
        }
    }

    /// Before step `step` of `simulation`: reads the notices, and takes every frame waiting,
    /// keeping only the newest of ours that this step or a later one can use.
    pub fn between_steps(&mut self, run_id: u64, simulation: u32, step: u32) {
        self.read_control();
        loop {
            let got = match self.inbox.try_frame() {
                Ok(Some(g)) => g,
                Ok(None) => return,
                Err(e) => {
                    tracing::warn!(topic = self.inbox.topic(), "subscriber: {e}");
                    return;
                }
            };
            // Step k is warm-started from the frame of step k - 1 (grids) or k (per contact).
            let h = got.step();
            if !self.is_ours(run_id, &h) || (h.simulation, h.step) < (simulation, step.saturating_sub(1)) {
                continue;
            }
            self.producer = Producer::Up;
            self.pending = Some(got);
        }
    }

    fn is_ours(&self, run_id: u64, h: &StepHeader) -> bool {
        (run_id == 0 || h.run_id == run_id) && self.simulations.contains(&h.simulation)
    }

    /// How long a step may wait now; `None` is unbounded (lockstep with the producer up).
    fn wait_limit(&self) -> Option<Duration> {
        let patience = self.waits.resume_patience;
        match (self.producer, self.waits.deadline) {
            (Producer::Down, _) => Some(Duration::ZERO),
            (Producer::Resuming, d) => Some(d.map_or(patience, |d| d.min(patience))),
            (Producer::Up, Some(d)) => Some(d),
            (Producer::Up, None) => None,
        }
    }

    /// The frame made of step `step` of `simulation`, or `None` (late, producer down or lost).
    pub fn frame(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<F> {
        // Simulations run in increasing id order, so (simulation, step) orders the stream.
        let want = (simulation, step);
        let key = |h: StepHeader| (h.simulation, h.step);
        if let Some(p) = self.pending.take() {
            match key(p.step()).cmp(&want) {
                Ordering::Equal => return Some(p),
                Ordering::Greater => {
                    self.pending = Some(p);
                    return None;
                }
                Ordering::Less => {}
            }
        }
        let start = Instant::now();
        loop {
            self.read_control();
            let waited = start.elapsed();
            let slice = match self.wait_limit() {
                Some(limit) => match limit.checked_sub(waited) {
                    Some(left) if !left.is_zero() => left.min(POLL),
                    _ => return None,
                },
                None => {
                    if self.inbox.shutdown() {
                        return None;
                    }
                    if waited >= self.waits.lockstep_timeout {
                        tracing::warn!(
                            simulation, step, waited = ?waited, topic = self.inbox.topic(),
                            "nothing within --lockstep-timeout: its producer counts as lost; falling back"
                        );
                        self.producer = Producer::Resuming;
                        return None;
                    }
                    POLL.min(self.waits.lockstep_timeout - waited)
                }
            };
            let got = match self.inbox.frame_timeout(slice) {
                Ok(Some(g)) => g,
                Ok(None) => continue,
                Err(e) => {
                    tracing::warn!(topic = self.inbox.topic(), "subscriber: {e}");
                    return None;
                }
            };
            if !self.is_ours(run_id, &got.step()) {
                continue; // another run's leftovers, or another simulator's frame
            }
            // Frames flow again: back to waiting for each one.
            self.producer = Producer::Up;
            match key(got.step()).cmp(&want) {
                Ordering::Less => continue, // stale: its step was already solved
                // A wait can overrun its limit (an event wait is not exact below a millisecond):
                // a frame that came after the deadline is late, as if it had not come.
                Ordering::Equal if self.wait_limit().is_some_and(|limit| start.elapsed() > limit) => return None,
                Ordering::Equal => return Some(got),
                Ordering::Greater => {
                    self.pending = Some(got);
                    return None;
                }
            }
        }
    }
}

/// A source shared by the warm-start model (which asks for frames) and the step loop (which
/// drains the inbox between steps).
pub type SharedSource<I, F> = std::rc::Rc<std::cell::RefCell<BusSource<I, F>>>;

/// The warm-start model's handle on a shared source.
pub struct SourceHandle<I, F>(pub SharedSource<I, F>);

impl<I: Inbox<Grid>> GridSource for SourceHandle<I, Grid> {
    fn grid(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<Grid> {
        self.0.borrow_mut().frame(run_id, simulation, step)
    }
}

impl<I: Inbox<msgs::Contacts>> ContactWarmSource for SourceHandle<I, msgs::Contacts> {
    fn warm(&mut self, run_id: u64, simulation: u32, step: u32) -> Option<msgs::Contacts> {
        self.0.borrow_mut().frame(run_id, simulation, step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::{NodeNotice, StepHeader};
    use std::collections::VecDeque;

    /// A scripted inbox: grids arrive when the test says; waiting returns at once with what is
    /// queued (time still passes: the source measures real time, in milliseconds here).
    #[derive(Default)]
    struct Script {
        grids: VecDeque<Grid>,
        controls: VecDeque<ControlMsg>,
        waits: usize,
        shutdown: bool,
        /// How long a wait takes before it hands over a queued grid (a wait that overruns).
        delay: Duration,
    }

    impl Inbox<Grid> for Script {
        fn topic(&self) -> &str {
            msgs::topics::GRID_CONTACTS.name
        }
        fn try_frame(&mut self) -> Result<Option<Grid>, String> {
            Ok(self.grids.pop_front())
        }
        fn frame_timeout(&mut self, timeout: Duration) -> Result<Option<Grid>, String> {
            self.waits += 1;
            match self.grids.pop_front() {
                Some(g) => {
                    std::thread::sleep(self.delay);
                    Ok(Some(g))
                }
                None => {
                    std::thread::sleep(timeout);
                    Ok(None)
                }
            }
        }
        fn try_control(&mut self) -> Result<Option<ControlMsg>, String> {
            Ok(self.controls.pop_front())
        }
        fn shutdown(&self) -> bool {
            self.shutdown
        }
    }

    fn grid(run_id: u64, simulation: u32, step: u32) -> Grid {
        Grid::zeros(StepHeader { run_id, simulation, step }, [0.0; 2], 1.0, 1, 1, &["normal", "tangent"])
    }

    fn notice(up: bool, topic: &str) -> ControlMsg {
        let n = NodeNotice {
            node: "sph".into(),
            host: "local".into(),
            publishes: vec![topic.into()],
            status: "signal 9".into(),
        };
        ControlMsg::node_notice(up, &n)
    }

    fn source(deadline: Option<Duration>) -> BusSource<Script, Grid> {
        let waits =
            Waits { deadline, lockstep_timeout: Duration::from_millis(60), resume_patience: Duration::from_millis(30) };
        BusSource::new(Script::default(), waits, [0, 1])
    }

    fn step_of(g: &Option<Grid>) -> Option<(u32, u32)> {
        g.as_ref().map(|g| (g.header.step.simulation, g.header.step.step))
    }

    #[test]
    fn lockstep_returns_the_grid_of_the_step_and_skips_stale_and_foreign_ones() {
        let mut s = source(None);
        s.inbox.grids.extend([grid(7, 0, 2), grid(8, 0, 4), grid(7, 5, 4), grid(7, 0, 4)]);
        assert_eq!(step_of(&s.frame(7, 0, 4)), Some((0, 4)), "stale (step 2), other run and other simulator skipped");
        // A later grid is kept for its own step.
        s.inbox.grids.push_back(grid(7, 0, 6));
        assert_eq!(s.frame(7, 0, 5), None);
        assert_eq!(step_of(&s.frame(7, 0, 6)), Some((0, 6)));
    }

    #[test]
    fn producer_down_falls_back_at_once_then_up_waits_only_the_patience() {
        let mut s = source(None);
        s.inbox.controls.push_back(notice(false, msgs::topics::GRID_CONTACTS.name));
        let t = Instant::now();
        assert_eq!(s.frame(7, 0, 1), None);
        assert_eq!(s.producer(), Producer::Down);
        assert_eq!(s.inbox.waits, 0, "no wait while the producer is down");
        assert!(t.elapsed() < Duration::from_millis(30));
        // Back: a step waits at most the patience (30 ms), not the lockstep timeout.
        s.inbox.controls.push_back(notice(true, msgs::topics::GRID_CONTACTS.name));
        assert_eq!(s.frame(7, 0, 2), None);
        assert_eq!(s.producer(), Producer::Resuming);
        assert!(s.inbox.waits >= 1);
        // A grid arrives: unbounded (lockstep) waits again.
        s.inbox.grids.push_back(grid(7, 0, 3));
        assert_eq!(step_of(&s.frame(7, 0, 3)), Some((0, 3)));
        assert_eq!(s.producer(), Producer::Up);
    }

    #[test]
    fn notices_about_other_topics_and_undecodable_ones_change_nothing() {
        let mut s = source(Some(Duration::ZERO));
        s.inbox.controls.push_back(notice(false, msgs::topics::GRID_UNET.name));
        let mut junk = notice(false, msgs::topics::GRID_CONTACTS.name);
        junk.items = b"\xffjunk".to_vec();
        s.inbox.controls.push_back(junk);
        s.inbox.controls.push_back(ControlMsg::simple(StepHeader::default(), ControlKind::RunStart, 1));
        assert_eq!(s.frame(7, 0, 1), None);
        assert_eq!(s.producer(), Producer::Up);
    }

    #[test]
    fn lockstep_timeout_counts_the_producer_as_lost() {
        let mut s = source(None);
        let t = Instant::now();
        assert_eq!(s.frame(7, 0, 1), None);
        assert!(t.elapsed() >= Duration::from_millis(60), "waited the lockstep timeout");
        assert_eq!(s.producer(), Producer::Resuming);
    }

    #[test]
    fn a_deadline_bounds_the_wait_and_shutdown_ends_a_lockstep_wait() {
        let mut s = source(Some(Duration::from_millis(5)));
        assert_eq!(s.frame(7, 0, 1), None);
        assert_eq!(s.producer(), Producer::Up, "a late grid is not a lost producer");
        let mut s = source(None);
        s.inbox.shutdown = true;
        assert_eq!(s.frame(7, 0, 1), None);
        assert_eq!(s.inbox.waits, 0);
    }

    /// A frame that a wait hands over only after the deadline is late: the step falls back, and
    /// the producer still counts as up (lockstep takes it whenever it comes).
    #[test]
    fn a_frame_that_comes_after_the_deadline_is_late() {
        let mut s = source(Some(Duration::from_millis(5)));
        s.inbox.delay = Duration::from_millis(20);
        s.inbox.grids.push_back(grid(7, 0, 1));
        assert_eq!(s.frame(7, 0, 1), None);
        assert_eq!(s.producer(), Producer::Up);
        let mut s = source(None);
        s.inbox.delay = Duration::from_millis(20);
        s.inbox.grids.push_back(grid(7, 0, 1));
        assert_eq!(step_of(&s.frame(7, 0, 1)), Some((0, 1)));
    }

    #[test]
    fn between_steps_keeps_the_newest_usable_grid() {
        let mut s = source(None);
        s.producer = Producer::Resuming;
        s.inbox.grids.extend([grid(7, 0, 1), grid(7, 0, 3), grid(7, 1, 0), grid(9, 0, 5)]);
        s.between_steps(7, 0, 5);
        assert!(s.inbox.grids.is_empty(), "drained");
        assert_eq!(s.producer(), Producer::Up);
        assert_eq!(step_of(&s.pending), Some((1, 0)));
        assert_eq!(s.inbox.waits, 0);
    }
}
