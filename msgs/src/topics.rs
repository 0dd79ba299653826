//! The topic table: every topic of a graph with its name, header and item types, frame kind and
//! purpose, in one place. Nodes open ports through the typed [`Topic`] constants; the recorder,
//! replay, the Foxglove bridge and launch-file validation look topics up in [`TABLE`].

use crate::*;
use std::marker::PhantomData;

/// The frame type of a topic: which header and item types its frames have.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum FrameKind {
    /// `Frame<StepHeader, Body>`.
    Bodies,
    /// `Frame<StepHeader, Contact>`.
    Contacts,
    /// `Frame<GridHeader, f32>`.
    Grid,
    /// `Frame<SolveStatsHeader, f32>`.
    SolveStats,
    /// `Frame<Control, u8>`.
    Control,
    /// `Frame<StepHeader, ProblemBody>`.
    ProblemBodies,
    /// `Frame<ProblemHeader, ProblemContact>`.
    ProblemContacts,
}

impl FrameKind {
    pub const ALL: [FrameKind; 7] = [
        FrameKind::Bodies,
        FrameKind::Contacts,
        FrameKind::Grid,
        FrameKind::SolveStats,
        FrameKind::Control,
        FrameKind::ProblemBodies,
        FrameKind::ProblemContacts,
    ];

    /// The frame type of a known topic.
    pub fn of_topic(topic: &str) -> Option<FrameKind> {
        info(topic).map(|t| t.kind)
    }

    /// The name written in recordings' channel metadata (`type`).
    pub fn type_name(self) -> &'static str {
        match self {
            FrameKind::Bodies => "dc::Bodies",
            FrameKind::Contacts => "dc::Contacts",
            FrameKind::Grid => "dc::Grid",
            FrameKind::SolveStats => "dc::SolveStats",
            FrameKind::Control => "dc::ControlMsg",
            FrameKind::ProblemBodies => "dc::ProblemBodies",
            FrameKind::ProblemContacts => "dc::ProblemContacts",
        }
    }

    pub fn from_type_name(name: &str) -> Option<FrameKind> {
        FrameKind::ALL.into_iter().find(|k| k.type_name() == name)
    }

    /// Header and item type names, for channel metadata and `dc-record info`.
    pub fn parts(self) -> (&'static str, &'static str) {
        match self {
            FrameKind::Bodies => ("dc::StepHeader", "dc::Body"),
            FrameKind::Contacts => ("dc::StepHeader", "dc::Contact"),
            FrameKind::Grid => ("dc::GridHeader", "f32"),
            FrameKind::SolveStats => ("dc::SolveStatsHeader", "f32"),
            FrameKind::Control => ("dc::Control", "u8"),
            FrameKind::ProblemBodies => ("dc::StepHeader", "dc::ProblemBody"),
            FrameKind::ProblemContacts => ("dc::ProblemHeader", "dc::ProblemContact"),
        }
    }

    /// The (run, simulation, step) a payload belongs to, decoding its header only.
    pub fn step_of(self, payload: &[u8]) -> Result<StepHeader, CodecError> {
        Ok(match self {
            FrameKind::Bodies | FrameKind::Contacts | FrameKind::ProblemBodies => decode_header::<StepHeader>(payload)?,
            FrameKind::ProblemContacts => decode_header::<ProblemHeader>(payload)?.step,
            FrameKind::Grid => decode_header::<GridHeader>(payload)?.step,
            FrameKind::SolveStats => decode_header::<SolveStatsHeader>(payload)?.step,
            FrameKind::Control => decode_header::<Control>(payload)?.step,
        })
    }

    /// Decodes a payload fully (version, header, item length) and drops it: is it a valid frame?
    pub fn validate(self, payload: &[u8]) -> Result<(), CodecError> {
        fn check<H: FrameHeader, T: FrameItem>(payload: &[u8]) -> Result<(), CodecError> {
            decode::<H, T>(payload).map(drop)
        }
        with_frame_types!(self, check(payload))
    }
}

/// Calls the generic function `f::<H, T>(args...)` with the header and item types of a
/// [`FrameKind`]: the one place that maps kinds to types for code that does the same with every
/// kind (a subscriber, a publisher, a decoder of each topic's frames).
#[macro_export]
macro_rules! with_frame_types {
    ($kind:expr, $f:ident ( $($arg:expr),* $(,)? )) => {
        match $kind {
            $crate::topics::FrameKind::Bodies => $f::<$crate::StepHeader, $crate::Body>($($arg),*),
            $crate::topics::FrameKind::Contacts => $f::<$crate::StepHeader, $crate::Contact>($($arg),*),
            $crate::topics::FrameKind::Grid => $f::<$crate::GridHeader, f32>($($arg),*),
            $crate::topics::FrameKind::SolveStats => $f::<$crate::SolveStatsHeader, f32>($($arg),*),
            $crate::topics::FrameKind::Control => $f::<$crate::Control, u8>($($arg),*),
            $crate::topics::FrameKind::ProblemBodies => $f::<$crate::StepHeader, $crate::ProblemBody>($($arg),*),
            $crate::topics::FrameKind::ProblemContacts => {
                $f::<$crate::ProblemHeader, $crate::ProblemContact>($($arg),*)
            }
        }
    };
}

/// Ties a frame type to its [`FrameKind`], so that the table below is checked by the compiler.
pub trait KindOf {
    const KIND: FrameKind;
}
impl KindOf for Bodies {
    const KIND: FrameKind = FrameKind::Bodies;
}
impl KindOf for Contacts {
    const KIND: FrameKind = FrameKind::Contacts;
}
impl KindOf for Grid {
    const KIND: FrameKind = FrameKind::Grid;
}
impl KindOf for SolveStats {
    const KIND: FrameKind = FrameKind::SolveStats;
}
impl KindOf for ControlMsg {
    const KIND: FrameKind = FrameKind::Control;
}
impl KindOf for ProblemBodies {
    const KIND: FrameKind = FrameKind::ProblemBodies;
}
impl KindOf for ProblemContacts {
    const KIND: FrameKind = FrameKind::ProblemContacts;
}

/// The mark `dc play --into-live` sets on the run id of every frame it publishes into a live
/// graph (the top bit; the simulator's clock-derived run ids stay far below it), so that the
/// graph's metrics and recorder keep a replayed run apart from their own.
pub const REPLAYED_RUN: u64 = 1 << 63;

/// Whether a run id carries [`REPLAYED_RUN`].
pub fn is_replayed(run_id: u64) -> bool {
    run_id & REPLAYED_RUN != 0
}

/// A header that carries the (run, simulation, step) of its frame.
pub trait HasStep {
    fn step_header(&self) -> StepHeader;
    fn step_header_mut(&mut self) -> &mut StepHeader;
}
impl HasStep for StepHeader {
    fn step_header(&self) -> StepHeader {
        *self
    }
    fn step_header_mut(&mut self) -> &mut StepHeader {
        self
    }
}
impl HasStep for GridHeader {
    fn step_header(&self) -> StepHeader {
        self.step
    }
    fn step_header_mut(&mut self) -> &mut StepHeader {
        &mut self.step
    }
}
impl HasStep for SolveStatsHeader {
    fn step_header(&self) -> StepHeader {
        self.step
    }
    fn step_header_mut(&mut self) -> &mut StepHeader {
        &mut self.step
    }
}
impl HasStep for ProblemHeader {
    fn step_header(&self) -> StepHeader {
        self.step
    }
    fn step_header_mut(&mut self) -> &mut StepHeader {
        &mut self.step
    }
}
impl HasStep for Control {
    fn step_header(&self) -> StepHeader {
        self.step
    }
    fn step_header_mut(&mut self) -> &mut StepHeader {
        &mut self.step
    }
}

/// A topic: its name on the bus and, in its type, the header and item types of its frames.
#[derive(Debug)]
pub struct Topic<H, T> {
    pub name: &'static str,
    _frame: PhantomData<fn() -> (H, T)>,
}

impl<H, T> Clone for Topic<H, T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<H, T> Copy for Topic<H, T> {}

impl<H, T> Topic<H, T> {
    pub const fn new(name: &'static str) -> Self {
        Topic { name, _frame: PhantomData }
    }
}

impl<H, T> Topic<H, T>
where
    Frame<H, T>: KindOf,
{
    /// The table row of this topic.
    pub const fn row(self, about: &'static str) -> TopicInfo {
        TopicInfo { name: self.name, kind: <Frame<H, T> as KindOf>::KIND, about }
    }
}

/// One row of the topic table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicInfo {
    pub name: &'static str,
    pub kind: FrameKind,
    /// Who publishes it and what it carries.
    pub about: &'static str,
}

/// Body states at the end of every step (sim).
pub const BODIES: Topic<StepHeader, Body> = Topic::new("bodies");
/// Contacts with their final impulses, every step (sim).
pub const CONTACTS: Topic<StepHeader, Contact> = Topic::new("contacts");
/// Solver statistics, every step (sim).
pub const SOLVE_STATS: Topic<SolveStatsHeader, f32> = Topic::new("stats/solve");
/// Bodies splatted to a grid: vx, vy, omega, mass, inertia (sph).
pub const GRID_BODIES: Topic<GridHeader, f32> = Topic::new("grid/bodies");
/// Contact impulses splatted to a grid: normal, tangent — the "grid" warm-start model (sph).
pub const GRID_CONTACTS: Topic<GridHeader, f32> = Topic::new("grid/contacts");
/// Predicted impulse grids from the U-Net (unet).
pub const GRID_UNET: Topic<GridHeader, f32> = Topic::new("grid/unet");
/// Run and simulation start/end, shutdown requests, node down/up notices.
pub const CONTROL: Topic<Control, u8> = Topic::new("control");
/// The step's velocity problem: bodies (sim, with `--publish-problem`).
pub const PROBLEM_BODIES: Topic<StepHeader, ProblemBody> = Topic::new("problem/bodies");
/// The step's velocity problem: contact rows with builtin's warm start and the reference solution.
pub const PROBLEM_CONTACTS: Topic<ProblemHeader, ProblemContact> = Topic::new("problem/contacts");
/// The contact-graph network's warm start of a step: its contacts (keys, in the problem's order)
/// with the predicted impulses (the `dc-gnn` node, for the `gnn-node` model).
pub const WARM_GNN: Topic<StepHeader, Contact> = Topic::new("warm/gnn");
/// An external model's warm start of a step (the `external:NAME` model; any process of the
/// graph that answers `problem/*`, see docs/external.md): the step's contacts, keys in the
/// problem's order, with the predicted impulses.
pub const WARM_EXTERNAL: Topic<StepHeader, Contact> = Topic::new("warm/external");
/// Per-step summary for live plots (metrics).
pub const METRICS_STEP: Topic<SolveStatsHeader, f32> = Topic::new("metrics/step");
/// Plumbing benchmark and test topics (dc-bench-bus).
pub const BENCH_BODIES: Topic<StepHeader, Body> = Topic::new("bench/bodies");
pub const BENCH_GRID: Topic<GridHeader, f32> = Topic::new("bench/grid");
pub const BENCH_ECHO: Topic<StepHeader, Body> = Topic::new("bench/echo");
pub const BENCH_GRID_ECHO: Topic<GridHeader, f32> = Topic::new("bench/grid-echo");

/// Every topic a graph may use.
pub const TABLE: &[TopicInfo] = &[
    BODIES.row("sim: body states at the end of every step"),
    CONTACTS.row("sim: contacts with their final impulses, every step"),
    SOLVE_STATS.row("sim: solver statistics of every step, residual per sweep as items"),
    GRID_BODIES.row("sph: bodies (and the step's impulses) splatted to a grid"),
    GRID_CONTACTS.row("sph: contact impulses splatted to a grid (the `grid` warm start)"),
    GRID_UNET.row("unet: predicted impulse grid of the next step"),
    CONTROL.row("sim, launcher: run/simulation start and end, shutdown, node down/up"),
    PROBLEM_BODIES.row("sim (--publish-problem): bodies of the step's velocity problem"),
    PROBLEM_CONTACTS.row("sim (--publish-problem): contact rows, builtin's warm start, the reference solution"),
    WARM_GNN.row("gnn (the dc-gnn node): per-contact warm start of the step whose problem it read"),
    WARM_EXTERNAL
        .row("an external model's server (`external:NAME`): per-contact warm start of the step whose problem it read"),
    METRICS_STEP.row("metrics: per-step summary [cumulative sweeps, sweeps] for live plots"),
    BENCH_BODIES.row("dc-bench-bus: body frames"),
    BENCH_GRID.row("dc-bench-bus: grid frames"),
    BENCH_ECHO.row("dc-bench-bus: echoed body frames"),
    BENCH_GRID_ECHO.row("dc-bench-bus: echoed grid frames"),
];

/// The table row of `topic`.
pub fn info(topic: &str) -> Option<&'static TopicInfo> {
    TABLE.iter().find(|t| t.name == topic)
}

/// Every topic name, in table order.
pub fn names() -> impl Iterator<Item = &'static str> {
    TABLE.iter().map(|t| t.name)
}

/// Every topic name, comma-separated (for error messages).
pub fn names_list() -> String {
    names().collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_names_are_unique_and_known() {
        let mut seen = std::collections::BTreeSet::new();
        for t in TABLE {
            assert!(seen.insert(t.name), "{} twice", t.name);
            assert_eq!(FrameKind::of_topic(t.name), Some(t.kind));
        }
        assert_eq!(FrameKind::of_topic("nope"), None);
    }

    #[test]
    fn type_names_round_trip() {
        for k in FrameKind::ALL {
            assert_eq!(FrameKind::from_type_name(k.type_name()), Some(k));
        }
    }

    #[test]
    fn step_is_read_from_every_header_kind() {
        let s = StepHeader { run_id: 9, simulation: 2, step: 5 };
        let grid = Grid::zeros(s, [0.0; 2], 1.0, 2, 2, &["a"]);
        assert_eq!(FrameKind::Grid.step_of(&encode(&grid).unwrap()).unwrap(), s);
        let c = ControlMsg::simple(s, ControlKind::SimulationEnd, 0);
        assert_eq!(FrameKind::Control.step_of(&encode(&c).unwrap()).unwrap(), s);
        assert!(FrameKind::Bodies.validate(&encode(&c).unwrap()).is_err());
    }
}
