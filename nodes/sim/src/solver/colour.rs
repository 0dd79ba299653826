//! Coloured sweeps on every core, as Box2D v3 (`solver_set.c`, `constraint_graph.c`), PhysX and
//! rapier's parallel solver do it: the rows are split into colours, no two rows of a colour on
//! the same moving body, and a colour's rows are updated on all threads at once.
//!
//! The colour order fixes the arithmetic: the rows of a colour touch disjoint moving bodies, so
//! updating them at once or one after another gives the same bits, and every sum (a sweep's
//! squared change, the natural residual's) is taken over fixed chunks of rows, in chunk order,
//! whatever the thread count. A solve in the colour order is therefore the same on 1 thread as
//! on 16, and a solve that cannot have its threads (the pool is busy with another solve) runs on
//! the calling thread alone and gets the same answer.
//!
//! Rows are coloured greedily in the top-down order (highest contact first), so each colour is a
//! set of rows spread over the whole pile, visited top-down; a row that finds no free colour among
//! [`MAX_COLOURS`] goes to an overflow set swept by one thread (Box2D's overflow constraints). A
//! row on no moving body (both bodies static or kinematic) never moves anything and takes colour 0.
//!
//! Threads meet at a spin barrier between phases (a colour's updates, NNCG's momentum step per
//! colour, the natural residual): a condition variable's wake-up costs more than a colour's work
//! on a 1,000-body pile. Waiting threads spin briefly, then yield, so an oversubscribed machine
//! still makes progress.

use super::rows::{ContactRow, Impulse, SolverBody};
use super::setting::{Momentum, StopRule};
use super::sweep::{
    momentum_row, natural_residual_rows, pull, push, relative_of, update_row, Prepared, SolveParams, SolveReport,
    SweepChange, Velocities, TRAIL_SWEEPS,
};
use rapier2d::math::Vec2;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Colours a row may take; a row with all of them used by its bodies' rows goes to the overflow.
pub const MAX_COLOURS: usize = 32;

/// Rows per chunk: the unit of work a thread takes and of every partial sum.
pub const CHUNK: usize = 32;

/// Below this many rows a solve in the colour order runs on the calling thread alone (same bits:
/// only the time differs): the barriers would cost more than the rows.
pub const PARALLEL_FROM_ROWS: usize = 256;

/// Bands of the colour order (see [`Colouring::colour`]): one. Cutting the pile into bands
/// costs sweeps at 1,000 bodies (NNCG 2,842 -> 3,326 with 3 bands, 3,724 with 6, on the same
/// problems) and halves what the threads buy (more, smaller phases): docs/solvers.md.
pub(super) const BANDS: usize = 1;

/// The most threads `--threads` accepts.
pub const MAX_THREADS: usize = 1024;

/// Why the sweep threads could not be had.
#[derive(Debug, thiserror::Error)]
pub enum ThreadsError {
    #[error("{0} sweep threads: at least 1 is needed")]
    Zero(usize),
    #[error("{0} sweep threads: at most {MAX_THREADS}")]
    TooMany(usize),
    #[error("cannot start {threads} sweep threads: {why}")]
    Start { threads: usize, why: String },
    #[error("the process's sweep threads were already set to {0}")]
    AlreadySet(usize),
}

/// The threads a solve in the colour order may run on: a pool of its own (shared by clones), or
/// none (one thread). Whoever finds the pool busy runs on its own thread: the same answer.
#[derive(Clone)]
pub struct SweepThreads {
    threads: usize,
    pub(super) pool: Option<Arc<Mutex<rayon::ThreadPool>>>,
}

impl std::fmt::Debug for SweepThreads {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SweepThreads({})", self.threads)
    }
}

impl SweepThreads {
    /// `threads` threads (1: the calling thread, no pool).
    pub fn new(threads: usize) -> Result<SweepThreads, ThreadsError> {
        if threads == 0 {
            return Err(ThreadsError::Zero(threads));
        }
        if threads > MAX_THREADS {
            return Err(ThreadsError::TooMany(threads));
        }
        let pool = if threads == 1 {
            None
        } else {
            let pool = rayon::ThreadPoolBuilder::new()
                // The calling thread is the first of them.
                .num_threads(threads - 1)
                .thread_name(|i| format!("dc-sweep-{i}"))
                .build()
                .map_err(|e| ThreadsError::Start { threads, why: e.to_string() })?;
            Some(Arc::new(Mutex::new(pool)))
        };
        Ok(SweepThreads { threads, pool })
    }

    /// One thread: the calling one.
    pub fn single() -> SweepThreads {
        SweepThreads { threads: 1, pool: None }
    }

    pub fn threads(&self) -> usize {
        self.threads
    }
}

/// The machine's cores (1 where it cannot say).
pub fn machine_cores() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

static PROCESS_THREADS: OnceLock<SweepThreads> = OnceLock::new();

/// Sets the process's sweep threads (`--threads`), once, before the first solve; every solver
/// without threads of its own uses them.
pub fn set_process_threads(threads: usize) -> Result<(), ThreadsError> {
    let made = SweepThreads::new(threads)?;
    PROCESS_THREADS.set(made).map_err(|_| ThreadsError::AlreadySet(process_threads().threads()))
}

/// The process's sweep threads: those set by [`set_process_threads`], else the machine's cores
/// (one thread if a pool cannot be made).
pub fn process_threads() -> &'static SweepThreads {
    PROCESS_THREADS.get_or_init(|| {
        SweepThreads::new(machine_cores()).unwrap_or_else(|e| {
            tracing::warn!("{e}; the colour order runs on one thread");
            SweepThreads::single()
        })
    })
}

/// The rows in colour order and the colours' bounds, with the buffers that make them.
#[derive(Debug, Default, Clone)]
pub(super) struct Colouring {
    /// Colour `k`'s rows are positions `bounds[k]..bounds[k + 1]` of the visit order.
    bounds: Vec<usize>,
    /// Per colour: whether it is an overflow (swept by one thread).
    serial: Vec<bool>,
    /// Sweep chunks (positions of the visit order), colour after colour.
    chunks: Vec<Range<usize>>,
    /// Colour `k`'s chunks are `chunks[colour_chunks[k]]`.
    colour_chunks: Vec<Range<usize>>,
    used: Vec<u64>,
    colour_of: Vec<u8>,
    sorted: Vec<u32>,
}

impl Colouring {
    /// Colours the rows of `visit` (already in the top-down order) greedily and reorders `visit`
    /// colour by colour, each colour keeping the top-down order. With `bands` > 1 the visit
    /// order is first cut into that many bands of consecutive rows (top to bottom), each band
    /// coloured on its own and swept before the next: the load of a pile then travels down
    /// `bands` stages within one sweep, at the price of more phases.
    #[allow(clippy::needless_range_loop)]
    pub fn colour(&mut self, rows: &[ContactRow], bodies: &[SolverBody], visit: &mut [u32], bands: usize) {
        self.used.clear();
        self.used.resize(bodies.len(), 0);
        self.sorted.clear();
        self.sorted.resize(visit.len(), 0);
        self.bounds.clear();
        self.bounds.push(0);
        self.serial.clear();
        let band_rows = visit.len().div_ceil(bands.max(1)).max(1);
        for (band, members) in visit.chunks(band_rows).enumerate() {
            let offset = band * band_rows;
            self.colour_of.clear();
            let mut counts = [0usize; MAX_COLOURS + 1];
            for &i in members {
                let r = &rows[i as usize];
                let ends = [r.body_a as usize, r.body_b as usize].map(|b| bodies[b].moves().then_some(b));
                let taken = ends.iter().flatten().fold(0u64, |m, &b| m | self.used[b]);
                let free = (!taken).trailing_zeros() as usize;
                let colour = if free < MAX_COLOURS {
                    for &b in ends.iter().flatten() {
                        self.used[b] |= 1 << free;
                    }
                    free
                } else {
                    MAX_COLOURS
                };
                self.colour_of.push(colour as u8);
                counts[colour] += 1;
            }
            // The next band is coloured afresh.
            for &i in members {
                let r = &rows[i as usize];
                self.used[r.body_a as usize] = 0;
                self.used[r.body_b as usize] = 0;
            }
            // A stable counting sort by colour.
            let mut start = [0usize; MAX_COLOURS + 2];
            for k in 0..=MAX_COLOURS {
                start[k + 1] = start[k] + counts[k];
            }
            let mut next = start;
            for (&i, &colour) in members.iter().zip(&self.colour_of) {
                self.sorted[offset + next[colour as usize]] = i;
                next[colour as usize] += 1;
            }
            for k in 0..=MAX_COLOURS {
                if counts[k] > 0 {
                    self.bounds.push(offset + start[k + 1]);
                    self.serial.push(k == MAX_COLOURS);
                }
            }
        }
        visit.copy_from_slice(&self.sorted);
        self.chunks.clear();
        self.colour_chunks.clear();
        for k in 0..self.colours() {
            let first = self.chunks.len();
            let (lo, hi) = (self.bounds[k], self.bounds[k + 1]);
            self.chunks.extend((lo..hi).step_by(CHUNK).map(|s| s..(s + CHUNK).min(hi)));
            self.colour_chunks.push(first..self.chunks.len());
        }
    }

    /// How many colours (the overflow counted as one).
    pub fn colours(&self) -> usize {
        self.bounds.len().saturating_sub(1)
    }

    /// Each colour's rows (positions of the visit order).
    #[cfg(test)]
    pub fn colour_rows(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        self.bounds.windows(2).map(|w| w[0]..w[1])
    }

    /// Rows in the overflow (0 when every row found a colour).
    #[cfg(test)]
    pub fn overflow_rows(&self) -> usize {
        self.serial.iter().zip(self.bounds.windows(2)).filter(|(s, _)| **s).map(|(_, w)| w[1] - w[0]).sum()
    }

    /// Worker `t` of `n`'s chunks of colour `k` (the overflow's all go to worker 0).
    fn share(&self, k: usize, t: usize, n: usize) -> Range<usize> {
        let all = self.colour_chunks[k].clone();
        if self.serial[k] {
            return if t == 0 { all } else { all.start..all.start };
        }
        let m = all.len();
        all.start + m * t / n..all.start + m * (t + 1) / n
    }
}

/// The bodies of a solve in the colour order, renumbered by first appearance in the visit order
/// (colour 0 goes top-down through the whole pile), so that the bodies one thread moves lie
/// together in memory: in the world's order (spawn order, random in height) nearly every cache
/// line would hold bodies of both threads' parts of the pile, and bounce between the cores.
#[derive(Debug, Default, Clone)]
pub(super) struct Layout {
    local_of: Vec<u32>,
    global_of: Vec<u32>,
    pub bodies: Vec<SolverBody>,
}

impl Layout {
    /// Copies the bodies of `prepared`'s rows into [`Self::bodies`] in their new order and
    /// points the rows at them.
    pub fn gather(&mut self, prepared: &mut [Prepared], bodies: &[SolverBody]) {
        const NONE: u32 = u32::MAX;
        self.local_of.clear();
        self.local_of.resize(bodies.len(), NONE);
        self.global_of.clear();
        self.bodies.clear();
        for c in prepared.iter_mut() {
            for end in [&mut c.a, &mut c.b] {
                let global = *end;
                if self.local_of[global] == NONE {
                    self.local_of[global] = self.global_of.len() as u32;
                    self.global_of.push(global as u32);
                    self.bodies.push(bodies[global]);
                }
                *end = self.local_of[global] as usize;
            }
        }
    }

    /// Writes the solved bodies back in the world's order.
    pub fn scatter(&self, bodies: &mut [SolverBody]) {
        for (&global, body) in self.global_of.iter().zip(&self.bodies) {
            bodies[global as usize] = *body;
        }
    }
}

/// The body velocities as the threads of a coloured sweep see them: shared, each thread writing
/// only the moving bodies of its own rows (disjoint within a colour), none writing a static
/// body (which rows of one colour may share).
struct SharedBodies(*mut SolverBody);

impl Velocities for SharedBodies {
    #[inline(always)]
    fn relative(&self, c: &Prepared) -> Vec2 {
        // SAFETY: the row's bodies exist (checked when the rows were prepared); within a phase
        // no other thread writes them (the colouring), and phases are separated by barriers.
        let (a, b) = unsafe { (&*self.0.add(c.a), &*self.0.add(c.b)) };
        relative_of(a, b, c)
    }

    #[inline(always)]
    fn apply(&mut self, c: &Prepared, p: Vec2) {
        // SAFETY: as above; a moving body of a row is written only by the thread updating that
        // row, and no row of the same colour moves it.
        unsafe {
            if c.moves[0] {
                pull(&mut *self.0.add(c.a), c.ra, p);
            }
            if c.moves[1] {
                push(&mut *self.0.add(c.b), c.rb, p);
            }
        }
    }
}

/// A slice the threads share, each element written by one thread in a phase.
struct Shared<T>(*mut T);

impl<T> Shared<T> {
    /// SAFETY: the caller owns element `i` in this phase (or only reads it while nobody writes).
    #[allow(clippy::mut_from_ref)]
    unsafe fn at(&self, i: usize) -> &mut T {
        &mut *self.0.add(i)
    }
}

// SAFETY: the raw pointers are only dereferenced under the phase discipline described above.
unsafe impl<T> Sync for Shared<T> {}
unsafe impl<T> Send for Shared<T> {}
unsafe impl Sync for SharedBodies {}
unsafe impl Send for SharedBodies {}

/// A sense-reversing spin barrier; poisoned when a thread panics, so the others stop waiting.
struct SpinBarrier {
    threads: usize,
    arrived: AtomicUsize,
    generation: AtomicUsize,
    poisoned: AtomicBool,
}

impl SpinBarrier {
    fn new(threads: usize) -> SpinBarrier {
        SpinBarrier {
            threads,
            arrived: AtomicUsize::new(0),
            generation: AtomicUsize::new(0),
            poisoned: AtomicBool::new(false),
        }
    }

    fn wait(&self) {
        if self.threads == 1 {
            return;
        }
        let generation = self.generation.load(Ordering::Acquire);
        if self.arrived.fetch_add(1, Ordering::AcqRel) + 1 == self.threads {
            self.arrived.store(0, Ordering::Relaxed);
            self.generation.fetch_add(1, Ordering::Release);
            return;
        }
        let mut spins = 0u32;
        while self.generation.load(Ordering::Acquire) == generation {
            assert!(!self.poisoned.load(Ordering::Relaxed), "another sweep thread panicked");
            if spins < 2_000 {
                std::hint::spin_loop();
                spins += 1;
            } else {
                std::thread::yield_now();
            }
        }
    }
}

/// Poisons the barrier when its thread unwinds.
struct PoisonOnPanic<'a>(&'a SpinBarrier);

impl Drop for PoisonOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.poisoned.store(true, Ordering::Relaxed);
        }
    }
}

/// The buffers of a solve in the colour order, in the visit order.
pub(super) struct ColouredSolve<'a> {
    pub prepared: &'a [Prepared],
    pub colouring: &'a Colouring,
    pub work: &'a mut [Impulse],
    pub trail: &'a mut [[Impulse; TRAIL_SWEEPS]],
    pub direction: &'a mut [Impulse],
    pub bodies: &'a mut [SolverBody],
}

/// The sweeps of a solve in the colour order (the warm start already applied), on `threads`
/// where the pool is free and the rows many, else on this thread: the same bits either way.
/// The stopping rule's residual after every sweep is appended to `residuals`.
pub(super) fn sweep_coloured(
    solve: ColouredSolve<'_>,
    params: &SolveParams,
    softness: f32,
    deadline: Option<Instant>,
    threads: &SweepThreads,
    residuals: &mut Vec<f32>,
) -> SolveReport {
    let pool = match (&threads.pool, solve.prepared.len() >= PARALLEL_FROM_ROWS) {
        (Some(pool), true) => pool.try_lock().ok(),
        _ => None,
    };
    // The calling thread leads (its cache holds the rows it just prepared); the pool's threads,
    // one fewer, take the other parts.
    let n = pool.as_ref().map_or(1, |pool| pool.current_num_threads() + 1);
    // Written by the threads through the job's pointers; they outlive it.
    let mut sweep_partials = vec![SweepChange::default(); solve.colouring.chunks.len()];
    let mut residual_partials = vec![(0.0f32, 0.0f64); solve.colouring.chunks.len()];
    let job = Job {
        prepared: solve.prepared,
        colouring: solve.colouring,
        work: Shared(solve.work.as_mut_ptr()),
        trail: Shared(solve.trail.as_mut_ptr()),
        direction: Shared(solve.direction.as_mut_ptr()),
        bodies: SharedBodies(solve.bodies.as_mut_ptr()),
        sweep_partials: Shared(sweep_partials.as_mut_ptr()),
        residual_partials: Shared(residual_partials.as_mut_ptr()),
        params,
        softness,
        deadline,
        time_up: AtomicBool::new(false),
        barrier: SpinBarrier::new(n),
    };
    match pool {
        Some(pool) => {
            let job = &job;
            pool.in_place_scope(|scope| {
                for t in 1..n {
                    scope.spawn(move |_| {
                        job.work(t, n, None);
                    });
                }
                job.work(0, n, Some(residuals))
            })
        }
        None => job.work(0, 1, Some(residuals)),
    }
    .expect("the leading thread reports")
}

/// One solve's shared state: what every thread reads, and the pointers it writes through.
struct Job<'a> {
    prepared: &'a [Prepared],
    colouring: &'a Colouring,
    work: Shared<Impulse>,
    trail: Shared<[Impulse; TRAIL_SWEEPS]>,
    direction: Shared<Impulse>,
    bodies: SharedBodies,
    sweep_partials: Shared<SweepChange>,
    residual_partials: Shared<(f32, f64)>,
    params: &'a SolveParams,
    softness: f32,
    deadline: Option<Instant>,
    /// Set by the leading thread before the last barrier of a sweep: the budget is spent.
    time_up: AtomicBool,
    barrier: SpinBarrier,
}

// SAFETY: the pointers are written under the phase discipline (one writer per element a phase).
unsafe impl Sync for Job<'_> {}

impl Job<'_> {
    /// Thread `t` of `n`: every sweep's phases, in step with the others. Each thread takes the
    /// same decisions (all from the same partial sums, in the same order, and the leader's
    /// clock); the leader (`t == 0`, the calling thread) appends each sweep's residual to
    /// `residuals` and reports.
    fn work(&self, t: usize, n: usize, mut residuals: Option<&mut Vec<f32>>) -> Option<SolveReport> {
        let _poison = PoisonOnPanic(&self.barrier);
        let leader = t == 0;
        let params = self.params;
        let colours = self.colouring.colours();
        let restart = match params.momentum {
            Momentum::None => None,
            Momentum::Nncg { restart } => Some(restart as f64),
        };
        let relaxed = params.relaxation != 1.0;
        let mut bodies = SharedBodies(self.bodies.0);
        let mut report = SolveReport::default();
        let mut previous_squared = 0.0f64;
        let mut sweeps = 0u32;
        // Every phase gives a thread the same rows (its share of each colour: the colours go
        // top-down, so its part of the pile), so that the bodies it moves stay in its cache.
        let my_chunks = || (0..colours).flat_map(|k| self.colouring.share(k, t, n));
        if params.max_sweeps == 0 || super::deadline::past(self.deadline) {
            return leader.then_some(report);
        }
        loop {
            let slot = sweeps as usize % TRAIL_SWEEPS;
            for k in 0..colours {
                for chunk in self.colouring.share(k, t, n) {
                    let mut change = SweepChange::default();
                    for i in self.colouring.chunks[chunk].clone() {
                        let c = &self.prepared[i];
                        // SAFETY: row i is this thread's in this phase.
                        let (l, trail) = unsafe { (self.work.at(i), self.trail.at(i)) };
                        let d = if relaxed {
                            update_row::<true, _>(&mut bodies, c, l, self.softness, params.relaxation)
                        } else {
                            update_row::<false, _>(&mut bodies, c, l, self.softness, 1.0)
                        };
                        trail[slot] = d;
                        change.add(d);
                    }
                    // SAFETY: chunk `chunk` is this thread's.
                    unsafe { *self.sweep_partials.at(chunk) = change };
                }
                self.barrier.wait();
            }
            let change = (0..self.colouring.chunks.len())
                // SAFETY: read after the barrier, written by nobody in this phase.
                .map(|k| unsafe { *self.sweep_partials.at(k) })
                .fold(SweepChange::default(), SweepChange::merge);
            if let Some(restart) = restart {
                // The first sweep has no earlier change: it starts the direction.
                let beta = if sweeps == 0 || previous_squared == 0.0 {
                    f64::INFINITY
                } else {
                    change.squared / previous_squared
                };
                if beta.is_nan() || beta > restart {
                    for chunk in my_chunks() {
                        for i in self.colouring.chunks[chunk].clone() {
                            // SAFETY: row i is this thread's in this phase.
                            unsafe { *self.direction.at(i) = Impulse::default() };
                        }
                    }
                } else {
                    for k in 0..colours {
                        for chunk in self.colouring.share(k, t, n) {
                            for i in self.colouring.chunks[chunk].clone() {
                                // SAFETY: row i is this thread's in this phase.
                                let (l, p, dx) =
                                    unsafe { (self.work.at(i), self.direction.at(i), self.trail.at(i)[slot]) };
                                momentum_row(&mut bodies, &self.prepared[i], l, p, dx, beta as f32);
                            }
                        }
                        self.barrier.wait();
                    }
                }
                previous_squared = change.squared;
            }
            sweeps += 1;
            let residual = match params.stop {
                StopRule::Change => {
                    if leader {
                        self.time_up.store(super::deadline::past(self.deadline), Ordering::Relaxed);
                    }
                    self.barrier.wait();
                    change.max
                }
                StopRule::Natural | StopRule::Relative => {
                    for chunk in my_chunks() {
                        let rows = self.colouring.chunks[chunk].clone();
                        // SAFETY: the impulses are read, nobody writes them in this phase.
                        let work = unsafe { std::slice::from_raw_parts(self.work.0.add(rows.start), rows.len()) };
                        let partial = natural_residual_rows(&self.prepared[rows], work, &bodies, self.softness);
                        // SAFETY: chunk `chunk` is this thread's.
                        unsafe { *self.residual_partials.at(chunk) = partial };
                    }
                    if leader {
                        self.time_up.store(super::deadline::past(self.deadline), Ordering::Relaxed);
                    }
                    self.barrier.wait();
                    report.natural = self.natural_of_partials();
                    report.natural.max
                }
            };
            let time_up = self.time_up.load(Ordering::Relaxed);
            if let Some(residuals) = residuals.as_deref_mut() {
                residuals.push(residual);
            }
            report.final_residual = residual;
            report.sweeps = sweeps;
            if residual <= params.tolerance {
                report.converged = true;
                break;
            }
            if sweeps >= params.max_sweeps || time_up {
                break;
            }
        }
        leader.then_some(report)
    }

    /// The natural residual from the chunks' partials, in chunk order.
    fn natural_of_partials(&self) -> super::sweep::NaturalResidual {
        let (mut max, mut squared) = (0.0f32, 0.0f64);
        for k in 0..self.colouring.chunks.len() {
            // SAFETY: read after the barrier.
            let (m, s) = unsafe { *self.residual_partials.at(k) };
            max = max.max(m);
            squared += s;
        }
        super::sweep::NaturalResidual { max, rms: (squared / (2 * self.prepared.len().max(1)) as f64).sqrt() as f32 }
    }
}
