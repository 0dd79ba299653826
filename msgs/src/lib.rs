//! Deep Contact messages: the plain-old-data types every node exchanges, the topic names, and the
//! CBOR codec used on zenoh and in recordings.
//!
//! Every message is a [`Frame`]: a fixed-size header plus a slice of fixed-size items. The same
//! layout serves both transports:
//! - iceoryx2 publishes the header as the sample's user header and the items as a shared-memory
//!   slice, written and read in place (no serialisation at all);
//! - zenoh and MCAP carry `CBOR { version, header, items: bytes }` where the items are one byte
//!   string (little-endian, packed) — 100x faster than a CBOR array of structs.
//!
//! All element types are `#[repr(C)]`, have no padding (checked by `bytemuck::Pod`) and carry an
//! explicit iceoryx2 type name so that every crate agrees on the shared-memory type identity.

mod codec;
pub mod control;
pub mod curve;
pub mod flags;
pub mod models;
mod names;
pub mod problem;
pub mod shard;
mod stats;
pub mod topics;

pub use codec::{
    decode, decode_header, decode_reader, encode, encode_into, CodecError, MAX_FRAME_BYTES, OLDEST_WIRE_VERSION,
    WIRE_VERSION,
};
pub use control::{ControlDetails, DetailsError, NodeNotice, RunParams, RunSummary, SceneInfo};
pub use names::id_text;
pub use problem::{ProblemBodies, ProblemBody, ProblemContact, ProblemContacts, ProblemHeader};
pub use stats::{Accuracy, ErrorSplit, StepStats};
pub use topics::{is_replayed, FrameKind, HasStep, REPLAYED_RUN};

use bytemuck::{Pod, Zeroable};
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::fmt::Debug;

/// A header type: fixed size, plain data, serde for CBOR, zero-copy for iceoryx2.
pub trait FrameHeader:
    Pod + ZeroCopySend + Default + Debug + Serialize + DeserializeOwned + Send + Sync + 'static
{
}
impl<T> FrameHeader for T where
    T: Pod + ZeroCopySend + Default + Debug + Serialize + DeserializeOwned + Send + Sync + 'static
{
}

/// An item type of a frame's slice: fixed size, plain data, zero-copy for iceoryx2.
pub trait FrameItem: Pod + ZeroCopySend + Default + Debug + Send + Sync + 'static {}
impl<T> FrameItem for T where T: Pod + ZeroCopySend + Default + Debug + Send + Sync + 'static {}

/// An owned message: a header and its items.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Frame<H, T> {
    pub header: H,
    pub items: Vec<T>,
}

impl<H, T> Frame<H, T> {
    pub fn new(header: H, items: Vec<T>) -> Self {
        Self { header, items }
    }
}

/// Fixed-length, zero-padded UTF-8 name used inside POD headers (model names, grid channels).
pub type Name16 = [u8; 16];

/// Packs `s` into a [`Name16`], truncating at 16 bytes on a character boundary.
pub fn name16(s: &str) -> Name16 {
    let mut out = [0u8; 16];
    let mut end = s.len().min(16);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    out[..end].copy_from_slice(&s.as_bytes()[..end]);
    out
}

/// Reads a [`Name16`] back as a string (up to the first zero byte).
pub fn name16_str(n: &Name16) -> &str {
    let end = n.iter().position(|&b| b == 0).unwrap_or(16);
    std::str::from_utf8(&n[..end]).unwrap_or("<invalid utf-8>")
}

/// Most seeds one list may name. A run announces its whole seed list in its run start (CBOR,
/// up to 9 bytes a seed: under 1 MB at this bound), and the metrics, the recorder and the
/// evaluation keep state per simulation; a run of this many simulations of the thesis scene
/// (250 steps, ~1 ms a step) already takes about seven hours.
pub const MAX_SEEDS: u64 = 100_000;

/// Largest seed: seeds are simulation ids, a `u32` in every message header ([`StepHeader`]).
pub const MAX_SEED: u64 = u32::MAX as u64;

/// Parses a seed list: `N`, `A..B` (exclusive), `A..=B`, or a comma list of those; sorted,
/// without repeats. Seeds are simulation ids, shared by the simulator and the evaluation: each
/// is at most [`MAX_SEED`], and a list names at most [`MAX_SEEDS`] (counted before any is stored).
pub fn parse_seeds(s: &str) -> Result<Vec<u64>, String> {
    let num = |t: &str| t.trim().parse::<u64>().map_err(|_| format!("`{s}`: expected N, A..B, A..=B or a comma list"));
    let seed = |v: u64| match v {
        0..=MAX_SEED => Ok(v),
        _ => Err(format!("`{s}`: seed {v} is above {MAX_SEED} (seeds are u32 simulation ids)")),
    };
    // Each part as an inclusive range, checked and counted before anything is allocated.
    let mut ranges = Vec::new();
    let mut count = 0u64;
    for part in s.split(',').filter(|p| !p.trim().is_empty()) {
        let (a, b) = if let Some((a, b)) = part.split_once("..=") {
            (seed(num(a)?)?, seed(num(b)?)?)
        } else if let Some((a, b)) = part.split_once("..") {
            let (a, b) = (seed(num(a)?)?, num(b)?);
            if b <= a {
                return Err(format!("`{s}`: empty range"));
            }
            (a, seed(b - 1)?)
        } else {
            let v = seed(num(part)?)?;
            (v, v)
        };
        if b < a {
            return Err(format!("`{s}`: empty range"));
        }
        count += b - a + 1;
        if count > MAX_SEEDS {
            return Err(format!("`{s}`: more than {MAX_SEEDS} seeds (the limit of one seed list)"));
        }
        ranges.push(a..=b);
    }
    if ranges.is_empty() {
        return Err(format!("`{s}`: no seeds"));
    }
    let mut out: Vec<u64> = ranges.into_iter().flatten().collect();
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

/// The over-relaxation factor a message records: 0 — not recorded (a message from before the
/// field existed, or a zeroed header) — is plain projected Gauss-Seidel, 1.
pub fn recorded_relaxation(value: f32) -> f32 {
    if value > 0.0 {
        value
    } else {
        1.0
    }
}

/// Identifies the simulation step a message belongs to, so nodes can match streams and drop stale data.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::StepHeader")]
pub struct StepHeader {
    /// Identifies one run of a graph (all simulations of one launch).
    pub run_id: u64,
    /// Index of the simulation within the run (usually its seed).
    pub simulation: u32,
    /// Step index within the simulation, starting at 0.
    pub step: u32,
}

/// Shape of a body, stored as a `u32` in [`Body::shape`].
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Shape {
    Ball = 0,
    Box = 1,
    Polygon = 2,
    Wall = 3,
}

impl Shape {
    pub fn from_u32(v: u32) -> Option<Shape> {
        match v {
            0 => Some(Shape::Ball),
            1 => Some(Shape::Box),
            2 => Some(Shape::Polygon),
            3 => Some(Shape::Wall),
            _ => None,
        }
    }
}

/// One rigid body's state at the end of a step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::Body")]
pub struct Body {
    pub id: u32,
    /// A [`Shape`] as `u32`.
    pub shape: u32,
    /// Radius in `size[0]` for balls; half extents for boxes and walls.
    pub size: [f32; 2],
    pub mass: f32,
    pub inertia: f32,
    pub x: f32,
    pub y: f32,
    pub angle: f32,
    pub vx: f32,
    pub vy: f32,
    pub omega: f32,
}

/// One contact point with the impulses the solver found for it.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::Contact")]
pub struct Contact {
    pub body_a: u32,
    pub body_b: u32,
    /// Identifies the contact feature within the pair, so persisting contacts can be matched.
    pub feature: u32,
    pub x: f32,
    pub y: f32,
    /// Unit normal from body a to body b.
    pub nx: f32,
    pub ny: f32,
    /// Penetration depth (positive when overlapping).
    pub penetration: f32,
    pub friction: f32,
    pub normal_impulse: f32,
    pub tangent_impulse: f32,
}

/// Most channels a grid can carry (the names live in a fixed-size header).
pub const MAX_GRID_CHANNELS: usize = 8;

/// Geometry and channel names of a [`Grid`]; the items are `f32` values, channel-major:
/// `data[c * width * height + row * width + col]`, column along x, row along y, node `(row, col)` at
/// `origin + (col, row) * spacing`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::GridHeader")]
pub struct GridHeader {
    pub step: StepHeader,
    /// World position of node (row 0, col 0).
    pub origin: [f32; 2],
    pub spacing: f32,
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    /// Text strings on the wire (see [`names`]).
    #[serde(with = "names::text_array")]
    pub channel_names: [Name16; MAX_GRID_CHANNELS],
}

impl GridHeader {
    /// Number of `f32` values the items must hold.
    pub fn len(&self) -> usize {
        self.channels as usize * self.width as usize * self.height as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn channel_name(&self, c: usize) -> &str {
        name16_str(&self.channel_names[c])
    }
    /// The same header with another size.
    pub fn with_size(mut self, width: u32, height: u32) -> GridHeader {
        self.width = width;
        self.height = height;
        self
    }
    /// Index of the channel called `name`.
    pub fn channel(&self, name: &str) -> Option<usize> {
        (0..self.channels as usize).find(|&c| self.channel_name(c) == name)
    }
}

/// The wire form of [`StepStats`] (the one definition of the step statistics: field meanings
/// there); the items are the residual after each sweep (at most [`MAX_RESIDUALS`]). Names are
/// text strings on the wire.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::SolveStatsHeader")]
pub struct SolveStatsHeader {
    pub step: StepHeader,
    #[serde(with = "names::text")]
    pub model: Name16,
    #[serde(with = "names::text")]
    pub used_model: Name16,
    pub contacts: u32,
    pub persisting_contacts: u32,
    pub sweeps: u32,
    pub converged: u32,
    pub fallback: u32,
    pub fallbacks_total: u32,
    pub final_residual: f32,
    pub warm_error_normal_mse: f32,
    pub warm_error_normal_max: f32,
    pub warm_error_tangent_mse: f32,
    pub warm_error_tangent_max: f32,
    pub solve_us: f32,
    pub step_us: f32,
    pub warm_start_us: f32,
    pub kinetic_energy: f32,
    pub max_speed: f32,
    /// Absent in recordings made before it existed: read as "not measured".
    #[serde(default)]
    pub builtin_sweeps: u32,
    #[serde(default)]
    pub builtin_measured: u32,
    /// The natural residual of the final impulses (max over rows, RMS); 0 in recordings made
    /// before it existed.
    #[serde(default)]
    pub natural_max: f32,
    #[serde(default)]
    pub natural_rms: f32,
    /// The position pass's leftover overlap (max, mean) and the pile's centre-of-mass height and
    /// spread; 0 in recordings made before they existed.
    #[serde(default)]
    pub penetration_max: f32,
    #[serde(default)]
    pub penetration_mean: f32,
    #[serde(default)]
    pub pile_height: f32,
    #[serde(default)]
    pub pile_spread: f32,
    /// The warm-start error split (`dc-sim --error-split`; field meanings in [`StepStats`]); 0 in
    /// recordings made before it existed and where not measured.
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

/// Most residuals a [`SolveStatsHeader`] frame carries (one per sweep; longer solves keep the first ones).
pub const MAX_RESIDUALS: usize = 1000;

/// What a [`Control`] message announces.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ControlKind {
    RunStart = 1,
    RunEnd = 2,
    SimulationStart = 3,
    SimulationEnd = 4,
    /// Asks every node of the graph to finish cleanly.
    Shutdown = 5,
    /// The launcher saw a node die; details: [`NodeNotice`].
    NodeDown = 6,
    /// A restarted node is running again; details: [`NodeNotice`].
    NodeUp = 7,
}

impl ControlKind {
    pub fn from_u32(v: u32) -> Option<ControlKind> {
        match v {
            1 => Some(ControlKind::RunStart),
            2 => Some(ControlKind::RunEnd),
            3 => Some(ControlKind::SimulationStart),
            4 => Some(ControlKind::SimulationEnd),
            5 => Some(ControlKind::Shutdown),
            6 => Some(ControlKind::NodeDown),
            7 => Some(ControlKind::NodeUp),
            _ => None,
        }
    }
}

/// A control message; its items are the CBOR bytes of its typed details (see [`control`]),
/// possibly empty.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable, ZeroCopySend, Serialize, Deserialize)]
#[type_name("dc::Control")]
pub struct Control {
    pub step: StepHeader,
    /// A [`ControlKind`] as `u32`.
    pub kind: u32,
    /// Number of steps (simulation start) or simulations (run start) announced.
    pub count: u32,
}

impl Control {
    pub fn kind(&self) -> Option<ControlKind> {
        ControlKind::from_u32(self.kind)
    }
}

/// Owned message types, one per topic kind.
pub type Bodies = Frame<StepHeader, Body>;
pub type Contacts = Frame<StepHeader, Contact>;
pub type Grid = Frame<GridHeader, f32>;
pub type SolveStats = Frame<SolveStatsHeader, f32>;
pub type ControlMsg = Frame<Control, u8>;

impl Grid {
    /// A zero grid with the given geometry and channel names.
    pub fn zeros(step: StepHeader, origin: [f32; 2], spacing: f32, width: u32, height: u32, channels: &[&str]) -> Grid {
        assert!(channels.len() <= MAX_GRID_CHANNELS, "at most {MAX_GRID_CHANNELS} grid channels");
        let mut channel_names = [[0u8; 16]; MAX_GRID_CHANNELS];
        for (slot, name) in channel_names.iter_mut().zip(channels) {
            *slot = name16(name);
        }
        let header =
            GridHeader { step, origin, spacing, width, height, channels: channels.len() as u32, channel_names };
        let len = header.len();
        Frame::new(header, vec![0.0; len])
    }

    /// The values of channel `c` (row-major, `width * height`).
    pub fn channel_data(&self, c: usize) -> &[f32] {
        let n = self.header.width as usize * self.header.height as usize;
        &self.items[c * n..(c + 1) * n]
    }

    pub fn channel_data_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.header.width as usize * self.header.height as usize;
        &mut self.items[c * n..(c + 1) * n]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn element_layouts_are_packed_and_stable() {
        // Sizes are part of the wire and shared-memory format; a change here is a version bump.
        assert_eq!(std::mem::size_of::<StepHeader>(), 16);
        assert_eq!(std::mem::size_of::<Body>(), 48);
        assert_eq!(std::mem::size_of::<Contact>(), 44);
        assert_eq!(std::mem::size_of::<GridHeader>(), 168);
        assert_eq!(std::mem::size_of::<Control>(), 24);
        assert_eq!(std::mem::size_of::<SolveStatsHeader>() % 8, 0);
    }

    #[test]
    fn iceoryx2_type_names_are_explicit() {
        unsafe {
            assert_eq!(<Body as ZeroCopySend>::type_name(), "dc::Body");
            assert_eq!(<GridHeader as ZeroCopySend>::type_name(), "dc::GridHeader");
        }
    }

    #[test]
    fn seed_lists_parse() {
        assert_eq!(parse_seeds("0..3").unwrap(), [0, 1, 2]);
        assert_eq!(parse_seeds("5,1..=2,1").unwrap(), [1, 2, 5]);
        assert!(parse_seeds("3..3").is_err());
        assert!(parse_seeds("x").is_err());
        assert!(parse_seeds("").is_err());
    }

    #[test]
    fn seed_lists_beyond_their_bounds_are_refused_before_allocating() {
        assert_eq!(parse_seeds("0..100000").unwrap().len(), 100_000);
        assert_eq!(parse_seeds("4294967295").unwrap(), [MAX_SEED]);
        assert_eq!(parse_seeds("4294967290..4294967296").unwrap().len(), 6);
        let e = parse_seeds("0..400000000").unwrap_err();
        assert!(e.contains("more than 100000 seeds"), "{e}");
        let e = parse_seeds("0..4294967296").unwrap_err();
        assert!(e.contains("more than 100000 seeds"), "{e}");
        let e = parse_seeds("0..60000,100000..=160000").unwrap_err();
        assert!(e.contains("more than 100000 seeds"), "{e}");
        let e = parse_seeds("0..=18446744073709551615").unwrap_err();
        assert!(e.contains("above 4294967295"), "{e}");
        assert!(parse_seeds("4294967296").unwrap_err().contains("above 4294967295"));
        assert!(parse_seeds("0..4294967297").unwrap_err().contains("above 4294967295"));
    }

    #[test]
    fn name16_truncates_on_char_boundary() {
        let n = name16("normal_impulse_and_more");
        assert_eq!(name16_str(&n), "normal_impulse_a");
        let n = name16("ééééééééé"); // 18 bytes, boundary at 16
        assert_eq!(name16_str(&n), "éééééééé");
    }

    #[test]
    fn grid_channels_are_addressed_channel_major() {
        let mut g = Grid::zeros(StepHeader::default(), [0.0, 0.0], 0.5, 3, 2, &["a", "b"]);
        g.channel_data_mut(1)[4] = 7.0;
        assert_eq!(g.items[6 + 4], 7.0);
        assert_eq!(g.header.channel("b"), Some(1));
        assert_eq!(g.header.channel("c"), None);
    }
}
