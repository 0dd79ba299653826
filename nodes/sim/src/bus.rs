//! The simulator as a node of the bus: its publishers, the inboxes of models that another node
//! serves (grids, per-contact warm starts), and a run whose outputs go to the bus, paced if asked.

use crate::error::SimError;
use crate::problem::Problem;
use crate::run::{RunSink, RunSpec, StepOutput};
use crate::source::{BusSource, Inbox, SharedSource, SourceHandle, StepFrame, Waits};
use crate::warm::{ContactWarmSource, ModelFiles, ModelSpec, ProblemSender, Served, WarmStarter};
use msgs::{ControlMsg, RunSummary, StepHeader};
use std::cell::RefCell;
use std::rc::Rc;
use std::time::{Duration, Instant};

/// A bus failure on `topic`, as the run reports it.
fn bus_error(topic: &str, e: runtime::Error) -> SimError {
    SimError::Output(format!("{topic}: {e}"))
}

/// The warm-start frames (grids, or per-contact warm starts) and control subscribers of a run whose
/// model reads another node, as its source reads them.
struct BusInbox<H: msgs::FrameHeader, T: msgs::FrameItem> {
    frames: runtime::Subscriber<H, T>,
    control: runtime::Subscriber<msgs::Control, u8>,
    shutdown: runtime::ShutdownSignal,
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> BusInbox<H, T> {
    /// The subscriber of `topic` with a control subscriber of its own (our own control messages
    /// arrive there too; the step loop drains it).
    fn open(node: &runtime::Node, topic: msgs::topics::Topic<H, T>) -> Result<Self, SimError> {
        Ok(BusInbox {
            frames: node.subscriber(topic).map_err(|e| bus_error(topic.name, e))?,
            control: node.subscriber(msgs::topics::CONTROL).map_err(|e| bus_error(msgs::topics::CONTROL.name, e))?,
            shutdown: node.shutdown_signal(),
        })
    }
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> Inbox<msgs::Frame<H, T>> for BusInbox<H, T> {
    fn topic(&self) -> &str {
        self.frames.topic()
    }
    fn try_frame(&mut self) -> Result<Option<msgs::Frame<H, T>>, String> {
        self.frames.try_recv().map(|g| g.map(|g| g.into_frame())).map_err(|e| e.to_string())
    }
    fn frame_timeout(&mut self, timeout: Duration) -> Result<Option<msgs::Frame<H, T>>, String> {
        self.frames.recv_timeout(timeout).map(|g| g.map(|g| g.into_frame())).map_err(|e| e.to_string())
    }
    fn try_control(&mut self) -> Result<Option<ControlMsg>, String> {
        self.control.try_recv().map(|c| c.map(|c| c.into_frame())).map_err(|e| e.to_string())
    }
    fn shutdown(&self) -> bool {
        self.shutdown.is_set()
    }
}

type ProblemPublishers =
    (runtime::Publisher<StepHeader, msgs::ProblemBody>, runtime::Publisher<msgs::ProblemHeader, msgs::ProblemContact>);

/// The simulator's publishers.
pub struct Publishers {
    bodies: runtime::Publisher<StepHeader, msgs::Body>,
    contacts: runtime::Publisher<StepHeader, msgs::Contact>,
    stats: runtime::Publisher<msgs::SolveStatsHeader, f32>,
    control: runtime::Publisher<msgs::Control, u8>,
    /// With --publish-problem, or for `gnn-node` (which sends the problem before the solve).
    problem: Option<Rc<RefCell<ProblemPublishers>>>,
    /// `control` as read, between steps: a shutdown published from outside the graph (`dc topic
    /// pub control shutdown`) ends the run at the next step, as the launcher's Ctrl-C does.
    commands: runtime::Subscriber<msgs::Control, u8>,
}

impl Publishers {
    /// Opens the node's publishers; `problems`: also `problem/bodies` and `problem/contacts`.
    pub fn open(node: &runtime::Node, problems: bool) -> Result<Publishers, runtime::Error> {
        Ok(Publishers {
            bodies: node.publisher(msgs::topics::BODIES)?,
            contacts: node.publisher(msgs::topics::CONTACTS)?,
            stats: node.publisher(msgs::topics::SOLVE_STATS)?,
            control: node.publisher(msgs::topics::CONTROL)?,
            problem: if problems {
                let pair =
                    (node.publisher(msgs::topics::PROBLEM_BODIES)?, node.publisher(msgs::topics::PROBLEM_CONTACTS)?);
                Some(Rc::new(RefCell::new(pair)))
            } else {
                None
            },
            commands: node.subscriber(msgs::topics::CONTROL)?,
        })
    }
}

/// Publishes a step's problem (bodies first: a reader pairs them by step).
fn publish_problem(pubs: &mut ProblemPublishers, p: &Problem) -> Result<(), SimError> {
    pubs.0.publish(&p.header.step, &p.bodies).map_err(|e| bus_error("problem/bodies", e))?;
    pubs.1.publish(&p.header, &p.contacts).map_err(|e| bus_error("problem/contacts", e))
}

/// What the step loop drains between steps: the source of a model that reads another node.
trait Drain {
    fn between_steps(&self, run_id: u64, simulation: u32, step: u32);
}

impl<F: StepFrame, I: Inbox<F>> Drain for SharedSource<I, F> {
    fn between_steps(&self, run_id: u64, simulation: u32, step: u32) {
        self.borrow_mut().between_steps(run_id, simulation, step);
    }
}

/// A run's outputs go to the bus; between steps the grid source (if any) drains its inbox.
struct BusSink<'a> {
    pubs: &'a mut Publishers,
    node: &'a runtime::Node,
    source: Option<Box<dyn Drain>>,
    run_id: u64,
    /// Publish each step's problem after it (--publish-problem; `gnn-node` sends it itself).
    publish_problem: bool,
    /// `--step-period`, and when the next step is due.
    pace: Option<(Duration, Instant)>,
}

impl RunSink for BusSink<'_> {
    fn control(&mut self, msg: &ControlMsg) -> Result<(), SimError> {
        self.pubs.control.publish_frame(msg).map_err(|e| bus_error("control", e))
    }
    fn before_step(&mut self, simulation: u32, step: u32) -> bool {
        if let Some((period, due)) = &mut self.pace {
            let now = Instant::now();
            if *due > now && !runtime::sleep_unless_shutdown(self.node, *due - now) {
                return false;
            }
            // Late steps do not bunch up to catch up: the next is due a period after this one.
            *due = (*due + *period).max(Instant::now());
        }
        // Every control frame is taken (the node's own too): the queue never holds its writers back.
        while let Ok(Some(c)) = self.pubs.commands.try_recv() {
            self.node.observe_control(c.header());
        }
        if self.node.is_shutdown() {
            return false;
        }
        if let Some(source) = &self.source {
            source.between_steps(self.run_id, simulation, step);
        }
        true
    }
    fn step(&mut self, out: &StepOutput<'_>) -> Result<(), SimError> {
        // The problem first: it is what the step started from.
        if let (true, Some(pubs), Some(p)) = (self.publish_problem, &self.pubs.problem, out.problem) {
            publish_problem(&mut pubs.borrow_mut(), p)?;
        }
        self.pubs.bodies.publish(&out.header, out.bodies).map_err(|e| bus_error("bodies", e))?;
        self.pubs.contacts.publish(&out.header, out.contacts).map_err(|e| bus_error("contacts", e))?;
        self.pubs.stats.publish(&out.stats.to_header(), out.residuals).map_err(|e| bus_error("stats/solve", e))
    }
}

/// How the node runs each model: the waits of a served model, the files of learned ones, the
/// fallback, what it publishes beside the step, its pace.
pub struct NodeRun {
    pub waits: Waits,
    pub files: ModelFiles,
    /// The seed of the models' own randomness (`random`).
    pub seed: u64,
    /// The local model standing in when a served warm start is late.
    pub fallback: ModelSpec,
    /// Publish each step's problem (--publish-problem).
    pub publish_problem: bool,
    /// Start a step no sooner than this after the previous one (--step-period).
    pub step_period: Option<Duration>,
}

/// One run on the bus: every seed of `spec` with the warm-start model `model`.
pub fn run(
    node: &runtime::Node,
    pubs: &mut Publishers,
    model: ModelSpec,
    spec: &RunSpec,
    how: &NodeRun,
) -> Result<RunSummary, SimError> {
    // The grid subscriber exists only during a grid-based run: a grid producer publishes with
    // back-pressure, and a subscriber nobody reads (another model's run) would fill up and stall
    // the producer, which stalls the simulator in turn (a deadlock seen in `dc eval`). In lockstep
    // at most one grid is outstanding, so the loop cannot fill it.
    let simulations: Vec<u32> = spec.seeds.iter().map(|&s| s as u32).collect();
    let (served, source): (Served, Option<Box<dyn Drain>>) = match (model.grid_topic(), model.kind.warm_topic()) {
        (Some(topic), _) => {
            let source = Rc::new(RefCell::new(BusSource::new(BusInbox::open(node, topic)?, how.waits, simulations)));
            (Served { grid: Some(Box::new(SourceHandle(source.clone()))), contact: None }, Some(Box::new(source)))
        }
        (None, Some(warm_topic)) => {
            let inbox = BusInbox::open(node, warm_topic)?;
            let source = Rc::new(RefCell::new(BusSource::new(inbox, how.waits, simulations)));
            let pubs = pubs.problem.clone().ok_or_else(|| {
                SimError::Output(format!(
                    "model `{}` sends problems, but the node opened no problem publishers",
                    model.name()
                ))
            })?;
            let send: ProblemSender =
                Box::new(move |p| publish_problem(&mut pubs.borrow_mut(), p).map_err(|e| e.to_string()));
            let contact = Some((send, Box::new(SourceHandle(source.clone())) as Box<dyn ContactWarmSource>));
            (Served { grid: None, contact }, Some(Box::new(source)))
        }
        (None, _) => (Served::default(), None),
    };
    let built = model.build_with(how.seed, served, &how.files)?;
    let mut warm = WarmStarter::new(built, how.fallback.build(how.seed)?);
    let publish_problem = how.publish_problem && !model.kind.sends_problems();
    let pace = how.step_period.map(|p| (p, Instant::now()));
    let mut sink = BusSink { pubs, node, source, run_id: spec.run_id, publish_problem, pace };
    crate::run::run(spec, &mut warm, &mut sink)
}
