//! Particle -> grid (scatter with a smoothing kernel) and grid -> particle (bilinear sampling).
//!
//! Two normalisations ([`Mode`]):
//! - [`Mode::Sph`], the thesis's: each particle's weights over the nodes it reaches are normalised to
//!   sum to 1, so the particle's value is *spread* over them (~50 nodes for h = 0.5, res = 0.125)
//!   and a node holds a fraction of it. Conserves the total (sum over nodes = sum over particles),
//!   which is what a density field wants, but the value read back at the particle is a few percent
//!   of the original: the thesis's impulses shrank below 20% and its warm starts were near 0.
//! - [`Mode::Preserving`], the default: a normalised SPH *gather* (Shepard interpolation), node value
//!   `sum_p W(|x - p|) X_p / sum_p W(|x - p|)` over the particles within h. Every node is a weighted
//!   average of nearby particle values, so an isolated particle's value comes back exactly and a
//!   smooth field comes back with its scale; nodes that no particle reaches are 0, and the summed
//!   weight (the optional `weight` channel) tells them apart from true zeros.
//!
//! Two neighbour searches ([`Search`]) give identical grids: a k-d tree over the grid nodes (the
//! thesis's algorithm, kiddo's immutable tree, built once per geometry) and a direct scan of the
//! index window `[x - h, x + h] x [y - h, y + h]` (each row cut to its chord), which the regular
//! grid makes trivial. The window is the default: `dc-sph bench` measures it 2-3x faster at 1,000
//! and 10,000 particles, because the tree's answer is a heap-allocated list per particle found by
//! recursion while the window is two loops over a handful of rows.
//!
//! Speed (the scatter runs every step in the loop): particles are visited in node order (a
//! counting sort) so the accumulator stays in cache, each node's values plus its weight form one
//! power-of-two block updated with SSE, and the per-frame work allocates nothing.

use crate::geometry::GridGeometry;
use crate::kernel::{Kernel, KernelKind};
// Re-exported: `sph::transfer::Mode` was defined here before it moved beside the kernels.
use crate::error::SphError;
pub use crate::mode::Mode;
use crate::particles::{ParticleSet, WEIGHT_CHANNEL};
use crate::scatter;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use msgs::{Grid, GridHeader, StepHeader};
use std::fmt;
use std::str::FromStr;

/// How the nodes within reach of a particle are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Search {
    /// Scan the rows and columns of the particle's bounding square (default, faster).
    IndexWindow,
    /// Range query on a k-d tree of the node positions (the thesis's algorithm).
    KdTree,
}

impl fmt::Display for Search {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Search::IndexWindow => "window",
            Search::KdTree => "kdtree",
        })
    }
}

impl FromStr for Search {
    type Err = SphError;
    /// `window` or `kdtree`.
    fn from_str(s: &str) -> Result<Search, SphError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "window" | "index-window" => Ok(Search::IndexWindow),
            "kdtree" | "kiddo" => Ok(Search::KdTree),
            _ => Err(SphError::BadParameter(format!("unknown search `{s}` (window, kdtree)"))),
        }
    }
}

/// Parameters of a transfer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransferConfig {
    /// Smoothing kernel (default Poly6, the thesis's).
    pub kernel: KernelKind,
    /// Support radius (default 0.5, the thesis's).
    pub h: f32,
    /// Normalisation (default [`Mode::Preserving`]).
    pub mode: Mode,
    /// Neighbour search (default [`Search::IndexWindow`]).
    pub search: Search,
    /// Whether grids get a last `weight` channel with each node's summed kernel weight.
    pub weight_channel: bool,
}

impl Default for TransferConfig {
    fn default() -> Self {
        TransferConfig {
            kernel: KernelKind::Poly6,
            h: 0.5,
            mode: Mode::Preserving,
            search: Search::IndexWindow,
            weight_channel: false,
        }
    }
}

/// What a scatter did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SplatReport {
    /// Particles that reached the grid.
    pub splatted: usize,
    /// Particles farther than half the kernel support outside the grid's rectangle, skipped.
    pub outside: usize,
}

/// Below this fraction of `W(0)` a node's summed weight counts as "no particle within reach": in
/// preserving mode the node is then 0 rather than a ratio of two denormals.
const EMPTY_WEIGHT_FRACTION: f32 = 1e-7;

/// Fewest particles per thread: below it a band's work (~0.1 us per particle) is not worth a
/// thread start (~20-50 us).
const MIN_PARTICLES_PER_BAND: usize = 2_000;

/// A particle -> grid transfer for one geometry: the kernel, the cached k-d tree of the nodes and
/// scratch buffers, reused from frame to frame (nothing is allocated per frame after the first
/// but the threads' start-up).
pub struct Transfer {
    config: TransferConfig,
    geometry: GridGeometry,
    kernel: Kernel,
    tree: Option<ImmutableKdTree<f32, u32, 2, 32>>,
    /// Threads the index-window scatter may use (bands of rows).
    threads: usize,
    /// Whether the CPU has AVX2 + FMA (checked once).
    avx: bool,
    /// Node-major accumulator in blocks of `N` (channels + 1 rounded up to a power of two): a
    /// node's C channel sums, then its summed weight, then zeros (for 7 channels one 32-byte block
    /// per node), so one particle's writes to a node land in one cache line.
    acc: Vec<f32>,
    /// The current particle's nodes and weights (k-d tree search).
    neighbours: Vec<(u32, f32)>,
    /// Per band: window offsets and weights of the current particle.
    scratch: Vec<Vec<f32>>,
    /// Particles inside the grid in node order, with the counting sort's buckets and keys.
    order: Vec<u32>,
    rows: Vec<u32>,
    particle_rows: Vec<u32>,
    /// Positions and values (`N` per particle, weight slot 1) of `order`, packed, so that the
    /// scatter reads them sequentially.
    sorted_positions: Vec<[f32; 2]>,
    sorted_values: Vec<f32>,
}

impl Transfer {
    /// A transfer onto `geometry`; fails on a non-positive `h` or an empty grid.
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(spacing > 0)` on purpose: NaN is refused too
    pub fn new(config: TransferConfig, geometry: GridGeometry) -> Result<Transfer, SphError> {
        let kernel = config.kernel.with_support(config.h)?;
        if geometry.nodes() == 0 || !(geometry.spacing > 0.0) {
            return Err(SphError::BadParameter(format!("empty grid {geometry:?}")));
        }
        let tree = match config.search {
            Search::KdTree => Some(ImmutableKdTree::new_from_slice(&geometry.node_positions())),
            Search::IndexWindow => None,
        };
        Ok(Transfer {
            config,
            geometry,
            kernel,
            tree,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            avx: scatter::has_avx(),
            acc: Vec::new(),
            neighbours: Vec::new(),
            scratch: Vec::new(),
            order: Vec::new(),
            rows: Vec::new(),
            particle_rows: Vec::new(),
            sorted_positions: Vec::new(),
            sorted_values: Vec::new(),
        })
    }

    /// Limits the index-window scatter to `threads` threads (default: the available cores; it
    /// uses one per [`MIN_PARTICLES_PER_BAND`] particles at most). The grid does not depend on it.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
    }

    /// Threads the index-window scatter may use.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The configuration.
    pub fn config(&self) -> &TransferConfig {
        &self.config
    }

    /// The grid geometry.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// The kernel with its support radius.
    pub fn kernel(&self) -> &Kernel {
        &self.kernel
    }

    /// Whether every grid cell containing a particle has all four corners within `h` of it
    /// (`h > sqrt(2) * spacing`): then bilinear sampling at a particle only reads nodes it reached,
    /// and preserving mode returns an isolated particle's value exactly.
    pub fn covers_cells(&self) -> bool {
        self.config.h > std::f32::consts::SQRT_2 * self.geometry.spacing
    }

    /// Channel names of the grids this transfer writes for `particles`: theirs, plus `weight` when
    /// configured.
    pub fn channel_names<'a>(&self, particles: &'a ParticleSet) -> Vec<&'a str> {
        let mut names = particles.channels();
        if self.config.weight_channel {
            names.push(WEIGHT_CHANNEL);
        }
        names
    }

    /// Number of `f32` values [`Transfer::splat`] writes for `channels` particle channels.
    pub fn output_len(&self, channels: usize) -> usize {
        (channels + self.config.weight_channel as usize) * self.geometry.nodes()
    }

    /// Scatters `particles` onto the grid, writing channel-major values (`out[c * nodes + node]`,
    /// the layout of `msgs::Grid`) into `out`, which must hold [`Transfer::output_len`] values.
    /// Particles outside the grid are skipped and counted. The weight channel, when configured,
    /// holds each node's summed kernel weight (normalised per particle in sph mode).
    pub fn splat(&mut self, particles: &ParticleSet, out: &mut [f32]) -> Result<SplatReport, SphError> {
        let c_count = particles.channel_count();
        let expected = self.output_len(c_count);
        if out.len() != expected {
            return Err(SphError::OutputLength { expected, got: out.len() });
        }
        if c_count > msgs::MAX_GRID_CHANNELS {
            return Err(SphError::TooManyChannels(c_count));
        }
        // Each node's block is a power-of-two array (channels + weight, zero-padded), so the
        // per-node update is whole SIMD registers: 7 channels + weight = 8 lanes = 1 AVX FMA.
        let stride = (c_count + 1).next_power_of_two().max(2);
        let report = self.order_by_row(particles.positions());
        match stride {
            2 => self.splat_sorted::<2>(particles, out),
            4 => self.splat_sorted::<4>(particles, out),
            8 => self.splat_sorted::<8>(particles, out),
            _ => self.splat_sorted::<16>(particles, out),
        }
        Ok(report)
    }

    /// Scatters `particles` into a new grid for `step`.
    pub fn splat_grid(&mut self, step: StepHeader, particles: &ParticleSet) -> Result<(Grid, SplatReport), SphError> {
        let header = self.geometry.header(step, &self.channel_names(particles))?;
        let mut grid = Grid::new(header, vec![0.0; header.len()]);
        let report = self.splat(particles, &mut grid.items)?;
        Ok((grid, report))
    }

    /// After [`Transfer::order_by_row`]: packs the particles in node order, scatters them into
    /// blocks of `N` (>= channels + 1) and writes the output channels.
    fn splat_sorted<const N: usize>(&mut self, particles: &ParticleSet, out: &mut [f32]) {
        let c_count = particles.channel_count();
        self.sorted_positions.clear();
        self.sorted_values.clear();
        for &i in &self.order {
            let i = i as usize;
            self.sorted_positions.push(particles.positions()[i]);
            // The values plus a 1 in the weight slot: the weight accumulates like a channel.
            let mut v = [0.0f32; N];
            // (An element loop: `copy_from_slice` of a run-time length is a memcpy call.)
            for (d, &x) in v.iter_mut().zip(particles.particle_values(i)) {
                *d = x;
            }
            v[c_count] = 1.0;
            self.sorted_values.extend_from_slice(&v);
        }
        let nodes = self.geometry.nodes();
        self.acc.resize(nodes * N, 0.0);
        let empty = EMPTY_WEIGHT_FRACTION * self.kernel.eval(0.0);
        let out_channels = c_count + self.config.weight_channel as usize;
        if self.tree.is_some() {
            self.acc.fill(0.0);
            for i in 0..self.sorted_positions.len() {
                let [x, y] = self.sorted_positions[i];
                let v: [f32; N] = self.sorted_values[i * N..(i + 1) * N].try_into().expect("N values");
                self.scatter_kdtree::<N>(x, y, &v);
            }
            let mut outs: Vec<&mut [f32]> = out.chunks_exact_mut(nodes).take(out_channels).collect();
            scatter::finish_band(&mut self.acc, N, c_count, self.config.mode, empty, &mut outs);
            return;
        }
        self.splat_window::<N>(c_count, out_channels, empty, out);
    }

    /// The index-window scatter: bands of rows with about equal particle counts, one thread
    /// each, every band zeroing, filling and finishing its own rows.
    fn splat_window<const N: usize>(&mut self, c_count: usize, out_channels: usize, empty: f32, out: &mut [f32]) {
        let g = self.geometry;
        let side = scatter::window_side(self.kernel.support() / g.spacing);
        let particles = self.sorted_positions.len();
        let bands = self.threads.min(particles / MIN_PARTICLES_PER_BAND).min(g.height / side).max(1);
        // Particles are in node order: those whose windows reach a band lie in its rows and the
        // `side` rows above and below.
        let ranges: Vec<_> = self
            .band_rows(bands)
            .into_iter()
            .map(|rows| {
                let first = self.row_start(rows.start.saturating_sub(side));
                let last = self.row_start((rows.end + side).min(g.height));
                (rows, first..last)
            })
            .collect();
        self.scratch.resize_with(bands, Vec::new);
        for s in &mut self.scratch {
            s.resize(scatter::scratch_len(side), 0.0);
        }
        let frame = scatter::Frame {
            geometry: g,
            kernel: self.kernel,
            mode: self.config.mode,
            side,
            positions: &self.sorted_positions,
            values: &self.sorted_values,
        };
        // Split the accumulator and every output channel at the band boundaries.
        let mut work: Vec<(scatter::Band, Vec<&mut [f32]>)> = Vec::with_capacity(bands);
        let mut acc_rest: &mut [f32] = &mut self.acc;
        let mut out_rest: Vec<&mut [f32]> = out.chunks_exact_mut(g.nodes()).take(out_channels).collect();
        for (band_rows, band_particles) in ranges {
            let band_nodes = band_rows.len() * g.width;
            let (acc, tail) = std::mem::take(&mut acc_rest).split_at_mut(band_nodes * N);
            acc_rest = tail;
            let mut outs = Vec::with_capacity(out_channels);
            for channel in &mut out_rest {
                let (head, tail) = std::mem::take(channel).split_at_mut(band_nodes);
                outs.push(head);
                *channel = tail;
            }
            work.push((scatter::Band { rows: band_rows, particles: band_particles, acc }, outs));
        }
        let (stride, mode, avx) = (N, self.config.mode, self.avx);
        let run = |(band, outs): &mut (scatter::Band, Vec<&mut [f32]>), scratch: &mut Vec<f32>| {
            band.acc.fill(0.0);
            scatter::scatter_band::<N>(&frame, band, scratch, avx);
            scatter::finish_band(band.acc, stride, c_count, mode, empty, outs);
        };
        let run = &run;
        let mut jobs = work.iter_mut().zip(self.scratch.iter_mut());
        let (first_band, first_scratch) = jobs.next().expect("at least one band");
        std::thread::scope(|s| {
            for (band, scratch) in jobs {
                s.spawn(move || run(band, scratch));
            }
            // The calling thread takes the first band.
            run(first_band, first_scratch);
        });
    }

    /// Index in node order of the first particle whose nearest-node row is `row` or later
    /// (`row <= height`); after [`Transfer::order_by_row`], whose counting sort leaves each
    /// bucket's end in `rows`.
    fn row_start(&self, row: usize) -> usize {
        match row * self.geometry.width {
            0 => 0,
            node => self.rows[node - 1] as usize,
        }
    }

    /// Splits the grid rows into `bands` consecutive ranges of about equal particle counts.
    fn band_rows(&self, bands: usize) -> Vec<std::ops::Range<usize>> {
        let height = self.geometry.height;
        let total = self.row_start(height);
        let mut ranges = Vec::with_capacity(bands);
        let mut start = 0;
        for b in 1..bands {
            let target = total * b / bands;
            let mut end = start + 1;
            while end < height - (bands - b) && self.row_start(end) < target {
                end += 1;
            }
            ranges.push(start..end);
            start = end;
        }
        ranges.push(start..height);
        ranges
    }

    /// Fills `self.order` with the indices of the particles inside the grid, sorted by their
    /// nearest node in row-major order (a counting sort over the nodes). Consecutive particles
    /// then write to overlapping windows of nodes, which stay in L1 cache; in random order the
    /// scatter of 10,000 particles is bound by cache misses on the accumulator. Counts the
    /// particles outside.
    fn order_by_row(&mut self, positions: &[[f32; 2]]) -> SplatReport {
        let g = self.geometry;
        // Contacts on the walls lie a penetration depth outside the box: they must still reach
        // the grid (the floor carries the largest impulses). Half the support keeps their kernel
        // weights well away from zero.
        let margin = 0.5 * self.kernel.support();
        let mut report = SplatReport::default();
        self.rows.clear();
        self.rows.resize(g.nodes() + 1, 0);
        self.particle_rows.clear();
        for &[x, y] in positions {
            if g.contains_within(x, y, margin) {
                // Negative coordinates saturate to 0 in the cast: the nearest edge cell.
                let [c, r] = g.grid_coords(x, y);
                let cell = g.node_index((r as usize).min(g.height - 1), (c as usize).min(g.width - 1));
                self.rows[cell + 1] += 1;
                self.particle_rows.push(cell as u32);
                report.splatted += 1;
            } else {
                self.particle_rows.push(u32::MAX);
                report.outside += 1;
            }
        }
        for k in 1..self.rows.len() {
            self.rows[k] += self.rows[k - 1];
        }
        self.order.clear();
        self.order.resize(report.splatted, 0);
        for (i, &row) in self.particle_rows.iter().enumerate() {
            if row != u32::MAX {
                let slot = &mut self.rows[row as usize];
                self.order[*slot as usize] = i as u32;
                *slot += 1;
            }
        }
        report
    }

    /// One particle through a range query on the k-d tree of the nodes (the thesis's algorithm).
    #[inline(always)]
    fn scatter_kdtree<const N: usize>(&mut self, x: f32, y: f32, v: &[f32; N]) {
        let h = self.kernel.support();
        let tree = self.tree.as_ref().expect("k-d tree search has a tree");
        self.neighbours.clear();
        let mut total = 0.0;
        for n in tree.within_unsorted::<SquaredEuclidean>(&[x, y], h * h) {
            let w = self.kernel.eval_r2(n.distance);
            total += w;
            self.neighbours.push((n.item, w));
        }
        let scale = match self.config.mode {
            Mode::Sph if total > 0.0 => 1.0 / total,
            Mode::Sph => 0.0,
            Mode::Preserving => 1.0,
        };
        for &(node, w) in &self.neighbours {
            let start = node as usize * N;
            scatter::add_row::<N, false>(&mut self.acc[start..start + N], &[w], scale, v);
        }
    }

    /// Particle -> grid -> particle: splats `particles`, then samples every channel back at their
    /// positions (particle-major, like [`ParticleSet::values`]). The transfer-error study's core.
    pub fn round_trip(&mut self, particles: &ParticleSet) -> Result<(Vec<f32>, SplatReport), SphError> {
        let c_count = particles.channel_count();
        let mut grid = vec![0.0; self.output_len(c_count)];
        let report = self.splat(particles, &mut grid)?;
        let nodes = self.geometry.nodes();
        let mut back = Vec::with_capacity(particles.len() * c_count);
        for &[x, y] in particles.positions() {
            for c in 0..c_count {
                back.push(self.geometry.sample(&grid[c * nodes..(c + 1) * nodes], x, y));
            }
        }
        Ok((back, report))
    }
}

impl GridGeometry {
    /// Bilinear interpolation of one channel (row-major, `width * height` values) at `(x, y)`;
    /// see [`sample_bilinear`].
    pub fn sample(&self, channel: &[f32], x: f32, y: f32) -> f32 {
        if channel.len() < self.width * self.height {
            return 0.0;
        }
        let Some(cell) = self.bilinear_cell(x, y) else { return 0.0 };
        let w = self.width;
        let at = |r: usize, c: usize| channel[r * w + c];
        let low = at(cell.r0, cell.c0) * (1.0 - cell.tx) + at(cell.r0, cell.c1) * cell.tx;
        let high = at(cell.r1, cell.c0) * (1.0 - cell.tx) + at(cell.r1, cell.c1) * cell.tx;
        low * (1.0 - cell.ty) + high * cell.ty
    }

    /// The four nodes (indices within a channel) a bilinear sample at `(x, y)` reads, with their
    /// weights (they sum to 1): what a loss taken at contact points gathers from a predicted grid.
    /// `None` for an empty grid or a non-finite point (where [`GridGeometry::sample`] gives 0).
    pub fn bilinear_stencil(&self, x: f32, y: f32) -> Option<[(usize, f32); 4]> {
        let BilinearCell { r0, c0, r1, c1, tx, ty } = self.bilinear_cell(x, y)?;
        let w = self.width;
        Some([
            (r0 * w + c0, (1.0 - tx) * (1.0 - ty)),
            (r0 * w + c1, tx * (1.0 - ty)),
            (r1 * w + c0, (1.0 - tx) * ty),
            (r1 * w + c1, tx * ty),
        ])
    }

    fn bilinear_cell(&self, x: f32, y: f32) -> Option<BilinearCell> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 || !x.is_finite() || !y.is_finite() {
            return None;
        }
        let [gc, gr] = self.grid_coords(x, y);
        // Clamp to the edge: a contact on a wall, just outside the node rectangle, takes the
        // value of the nearest edge rather than nothing.
        let gc = gc.clamp(0.0, (w - 1) as f32);
        let gr = gr.clamp(0.0, (h - 1) as f32);
        let c0 = (gc as usize).min(w.saturating_sub(2));
        let r0 = (gr as usize).min(h.saturating_sub(2));
        Some(BilinearCell {
            r0,
            c0,
            r1: (r0 + 1).min(h - 1),
            c1: (c0 + 1).min(w - 1),
            tx: gc - c0 as f32,
            ty: gr - r0 as f32,
        })
    }
}

/// The grid cell around a point and the point's place in it.
struct BilinearCell {
    r0: usize,
    c0: usize,
    r1: usize,
    c1: usize,
    tx: f32,
    ty: f32,
}

/// Grid -> particle: bilinear interpolation of one channel of a grid at world point `(x, y)`.
///
/// `channel_data` is the channel's `width * height` values, row-major (`Grid::channel_data(c)`).
/// Points outside the node rectangle are clamped to its edge (they take the nearest edge value:
/// contacts with the walls lie on the boundary and must still get a warm start); non-finite points
/// and a malformed grid give 0, the "no warm start" value.
pub fn sample_bilinear(grid_header: &GridHeader, channel_data: &[f32], x: f32, y: f32) -> f32 {
    GridGeometry::from_header(grid_header).sample(channel_data, x, y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Bounds;
    use crate::particles::Source;

    fn geometry(min: [f32; 2], max: [f32; 2], res: f32) -> GridGeometry {
        GridGeometry::from_bounds(Bounds::new(min, max).unwrap(), res, 1).unwrap()
    }

    fn one_channel(points: &[([f32; 2], f32)]) -> ParticleSet {
        let mut set = ParticleSet::new(&["v"]);
        for (i, &(p, v)) in points.iter().enumerate() {
            set.push(Source::Index(i as u32), p, &[v]).unwrap();
        }
        set
    }

    fn config(mode: Mode, search: Search, h: f32) -> TransferConfig {
        TransferConfig { mode, search, h, ..Default::default() }
    }

    #[test]
    fn thesis_figure_7_2_lights_the_lower_left_for_the_lower_left_particle() {
        // Grid (0,0)-(2,2), res 0.2, p1 = (0.5, 0.5) value 1, p2 = (1.5, 1.5) value 5.
        let g = geometry([0.0, 0.0], [2.0, 2.0], 0.2);
        assert_eq!((g.width, g.height), (11, 11));
        let set = one_channel(&[([0.5, 0.5], 1.0), ([1.5, 1.5], 5.0)]);
        for mode in Mode::ALL {
            let mut t = Transfer::new(config(mode, Search::IndexWindow, 0.5), g).unwrap();
            let (grid, _) = t.splat_grid(StepHeader::default(), &set).unwrap();
            let v = grid.channel_data(0);
            // Low rows, low cols: p1 only; high rows, high cols: p2 only.
            let low = v[g.node_index(2, 2)]; // node at (0.4, 0.4)
            let high = v[g.node_index(8, 8)]; // node at (1.6, 1.6)
            assert!(low > 0.0 && high > low, "{mode}: low {low} high {high}");
            // The off-diagonal corners (high x low y, low x high y) stay empty.
            assert_eq!(v[g.node_index(2, 8)], 0.0, "{mode}");
            assert_eq!(v[g.node_index(8, 2)], 0.0, "{mode}");
            if mode == Mode::Preserving {
                assert!((low - 1.0).abs() < 1e-6 && (high - 5.0).abs() < 1e-5, "{low} {high}");
            }
            // The grid read back through the sampler puts each value where its particle was.
            let s = |x, y| sample_bilinear(&grid.header, grid.channel_data(0), x, y);
            assert!(s(0.5, 0.5) < s(1.5, 1.5));
            assert_eq!(s(0.5, 1.5), 0.0);
        }
    }

    #[test]
    fn bilinear_sampling_is_exact_on_a_linear_field_and_oriented() {
        // value = 10 x + y at each node.
        let g = geometry([1.0, 2.0], [2.5, 3.0], 0.5);
        let header = g.header(StepHeader::default(), &["f"]).unwrap();
        let field: Vec<f32> = g.node_positions().iter().map(|p| 10.0 * p[0] + p[1]).collect();
        for &(x, y) in &[(1.0, 2.0), (1.3, 2.2), (2.5, 3.0), (2.49, 2.99), (1.75, 2.6)] {
            let v = sample_bilinear(&header, &field, x, y);
            assert!((v - (10.0 * x + y)).abs() < 1e-4, "({x}, {y}) -> {v}");
        }
    }

    #[test]
    fn sampling_outside_the_grid_clamps_to_the_edge() {
        let g = geometry([1.0, 2.0], [2.5, 3.0], 0.5);
        let field: Vec<f32> = g.node_positions().iter().map(|p| 10.0 * p[0] + p[1]).collect();
        assert!((g.sample(&field, -5.0, 100.0) - (10.0 + 3.0)).abs() < 1e-5);
        assert!((g.sample(&field, 9.0, 2.25) - (25.0 + 2.25)).abs() < 1e-4);
        assert_eq!(g.sample(&field, f32::NAN, 2.25), 0.0);
    }

    #[test]
    fn the_bilinear_stencil_is_the_sample() {
        let g = geometry([0.0, 0.0], [4.0, 3.0], 0.25);
        let field: Vec<f32> = (0..g.nodes()).map(|i| ((i * 37) % 101) as f32 * 0.1 - 3.0).collect();
        for &(x, y) in &[(0.0, 0.0), (1.3, 2.7), (3.99, 0.01), (-1.0, 5.0), (4.0, 3.0), (2.125, 1.5)] {
            let stencil = g.bilinear_stencil(x, y).unwrap();
            let total: f32 = stencil.iter().map(|&(_, w)| w).sum();
            let value: f32 = stencil.iter().map(|&(n, w)| field[n] * w).sum();
            assert!((total - 1.0).abs() < 1e-6, "weights at ({x}, {y}) sum to {total}");
            assert!((value - g.sample(&field, x, y)).abs() < 1e-5, "({x}, {y}): {value} vs {}", g.sample(&field, x, y));
        }
        assert!(g.bilinear_stencil(f32::NAN, 1.0).is_none());
    }

    #[test]
    fn isolated_particle_value_is_preserved() {
        let g = geometry([0.0, 0.0], [15.0, 15.0], 0.125);
        for kernel in KernelKind::ALL {
            for search in [Search::IndexWindow, Search::KdTree] {
                let cfg = TransferConfig { kernel, ..config(Mode::Preserving, search, 0.5) };
                let mut t = Transfer::new(cfg, g).unwrap();
                assert!(t.covers_cells());
                let set = one_channel(&[([7.31, 4.07], 2.75), ([1.02, 13.9], -0.4)]);
                let (back, report) = t.round_trip(&set).unwrap();
                assert_eq!(report, SplatReport { splatted: 2, outside: 0 });
                for (b, want) in back.iter().zip([2.75, -0.4]) {
                    assert!((b - want).abs() <= 0.01 * want.abs(), "{kernel} {search}: {b} vs {want}");
                }
            }
        }
    }

    #[test]
    fn thesis_sph_mode_shrinks_an_isolated_value_to_a_few_percent() {
        // The thesis's failure, reproduced: W(0) * res^2 of the value stays at the particle.
        let g = geometry([0.0, 0.0], [15.0, 15.0], 0.125);
        let mut t = Transfer::new(config(Mode::Sph, Search::IndexWindow, 0.5), g).unwrap();
        let (back, _) = t.round_trip(&one_channel(&[([7.5, 7.5], 1.0)])).unwrap();
        assert!(back[0] > 0.02 && back[0] < 0.2, "{}", back[0]);
    }

    #[test]
    fn sph_mode_conserves_the_total() {
        let g = geometry([0.0, 0.0], [4.0, 4.0], 0.125);
        let mut t = Transfer::new(config(Mode::Sph, Search::IndexWindow, 0.5), g).unwrap();
        let set = one_channel(&[([1.3, 2.2], 3.0), ([1.5, 2.4], -1.0), ([0.1, 0.1], 2.0)]);
        let mut out = vec![0.0; t.output_len(1)];
        t.splat(&set, &mut out).unwrap();
        let total: f32 = out.iter().sum();
        assert!((total - 4.0).abs() < 1e-4, "{total}");
    }

    #[test]
    fn kdtree_and_index_window_give_the_same_grid() {
        let g = geometry([0.0, 0.0], [5.0, 3.0], 0.1);
        let mut set = ParticleSet::new(&["a", "b", "c"]);
        for i in 0..200u32 {
            let f = i as f32;
            let p = [(f * 0.7371).fract() * 5.0, (f * 0.3819).fract() * 3.0];
            set.push(Source::Index(i), p, &[f, -f, (f * 0.1).sin()]).unwrap();
        }
        for mode in Mode::ALL {
            for kernel in KernelKind::ALL {
                let grid = |search| {
                    let cfg = TransferConfig { kernel, weight_channel: true, ..config(mode, search, 0.35) };
                    Transfer::new(cfg, g).unwrap().splat_grid(StepHeader::default(), &set).unwrap().0
                };
                let (a, b) = (grid(Search::IndexWindow), grid(Search::KdTree));
                assert_eq!(a.header, b.header);
                for (x, y) in a.items.iter().zip(&b.items) {
                    assert!((x - y).abs() <= 1e-4 * (1.0 + x.abs()), "{mode} {kernel}: {x} vs {y}");
                }
            }
        }
    }

    #[test]
    fn particles_outside_the_grid_are_skipped_and_counted() {
        let g = geometry([0.0, 0.0], [2.0, 2.0], 0.25);
        let mut t = Transfer::new(config(Mode::Preserving, Search::IndexWindow, 0.5), g).unwrap();
        // Half the support (0.25) outside still counts: a contact on a wall. Farther is skipped.
        let set = one_channel(&[([1.0, 1.0], 1.0), ([-0.3, 1.0], 9.0), ([1.0, 2.5], 9.0), ([2.0, 2.0], 3.0)]);
        let (grid, report) = t.splat_grid(StepHeader::default(), &set).unwrap();
        assert_eq!(report, SplatReport { splatted: 2, outside: 2 });
        assert!(grid.items.iter().all(|&v| v <= 3.0 + 1e-6), "an outside value leaked in");
    }

    #[test]
    fn a_contact_just_outside_the_box_still_reaches_the_grid() {
        let g = geometry([0.0, 0.0], [2.0, 2.0], 0.25);
        let mut t = Transfer::new(config(Mode::Preserving, Search::IndexWindow, 0.5), g).unwrap();
        let set = one_channel(&[([1.0, -0.01], 4.0)]);
        let (back, report) = t.round_trip(&set).unwrap();
        assert_eq!(report, SplatReport { splatted: 1, outside: 0 });
        assert!((back[0] - 4.0).abs() < 0.04, "{}", back[0]);
    }

    #[test]
    fn weight_channel_marks_empty_regions() {
        let g = geometry([0.0, 0.0], [4.0, 4.0], 0.25);
        let cfg = TransferConfig { weight_channel: true, ..config(Mode::Preserving, Search::IndexWindow, 0.5) };
        let mut t = Transfer::new(cfg, g).unwrap();
        let set = one_channel(&[([1.0, 1.0], 0.0)]);
        let (grid, _) = t.splat_grid(StepHeader::default(), &set).unwrap();
        let weight = grid.header.channel(WEIGHT_CHANNEL).unwrap();
        // A true zero near the particle has weight; the far corner has none.
        assert!(grid.channel_data(weight)[g.node_index(4, 4)] > 0.0);
        assert_eq!(grid.channel_data(weight)[g.node_index(16, 16)], 0.0);
        assert_eq!(grid.channel_data(0)[g.node_index(4, 4)], 0.0);
    }

    #[test]
    fn wrong_output_length_is_an_error() {
        let g = geometry([0.0, 0.0], [1.0, 1.0], 0.5);
        let mut t = Transfer::new(TransferConfig::default(), g).unwrap();
        let err = t.splat(&one_channel(&[]), &mut [0.0; 3]).unwrap_err();
        assert!(matches!(err, SphError::OutputLength { expected: 9, got: 3 }), "{err}");
    }
}
