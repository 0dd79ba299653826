//! Topic names in one place, each typed with the frame it carries.

use crate::*;
use std::marker::PhantomData;

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
/// Run and simulation start/end, shutdown requests.
pub const CONTROL: Topic<Control, u8> = Topic::new("control");
/// Per-step summary for live plots (metrics).
pub const METRICS_STEP: Topic<SolveStatsHeader, f32> = Topic::new("metrics/step");
/// Plumbing benchmark and test topics (dc-bench-bus).
pub const BENCH_BODIES: Topic<StepHeader, Body> = Topic::new("bench/bodies");
pub const BENCH_GRID: Topic<GridHeader, f32> = Topic::new("bench/grid");
pub const BENCH_ECHO: Topic<StepHeader, Body> = Topic::new("bench/echo");
pub const BENCH_GRID_ECHO: Topic<GridHeader, f32> = Topic::new("bench/grid-echo");

/// Every topic name a graph may use, for validation of launch files.
pub const ALL: &[&str] = &[
    BODIES.name,
    CONTACTS.name,
    SOLVE_STATS.name,
    GRID_BODIES.name,
    GRID_CONTACTS.name,
    GRID_UNET.name,
    CONTROL.name,
    METRICS_STEP.name,
    BENCH_BODIES.name,
    BENCH_GRID.name,
    BENCH_ECHO.name,
    BENCH_GRID_ECHO.name,
];
