//! The per-frame inner loops of the index-window scatter, and the accumulator -> grid step.
//!
//! Layout and order, chosen by `dc-sph bench` (10,000 particles, 7 channels, 121 x 121 nodes):
//! - particles are visited in node order, from packed copies of their positions and values (the
//!   transfer sorts them before calling in), so consecutive particles hit overlapping, cached
//!   nodes and the loads are sequential;
//! - each particle's window is a fixed `side x side` square of nodes (`side = ceil(2 h /
//!   spacing)`, 8 for the thesis's h = 4 spacings): constant trip counts, which the branch
//!   predictor learns, where a per-row chord (~50 instead of 64 nodes) lost more to mispredicted
//!   loop exits than it saved; nodes beyond h get weight 0;
//! - the kernel weights of a window are computed once and reused for every channel;
//! - a node's channels plus its weight are one block of `N` (a power of two) floats, updated with
//!   one AVX2 FMA for `N = 8` where the CPU has it (checked once per frame; LLVM leaves the scalar
//!   8-lane loop unvectorised), SSE otherwise;
//! - the grid's rows are split into bands of about equal particle counts, one thread each; a band
//!   writes only its own rows of the accumulator, so no per-thread grids need summing, and each
//!   node still receives its particles in the same order whatever the thread count: the result
//!   does not depend on it.

use crate::geometry::GridGeometry;
use crate::kernel::Kernel;
use crate::mode::Mode;
use std::ops::Range;

/// What every band of one frame shares.
#[derive(Clone, Copy)]
pub(crate) struct Frame<'a> {
    pub geometry: GridGeometry,
    pub kernel: Kernel,
    pub mode: Mode,
    /// Window side in nodes.
    pub side: usize,
    /// Particle positions in node order.
    pub positions: &'a [[f32; 2]],
    /// Particle values in node order, `N` per particle: the channels, a 1 (the weight), zeros.
    pub values: &'a [f32],
}

/// Grid rows `rows` of the accumulator (`acc` starts at the band's first row) and the particles
/// (in node order) whose windows may reach them.
pub(crate) struct Band<'a> {
    pub rows: Range<usize>,
    pub particles: Range<usize>,
    pub acc: &'a mut [f32],
}

/// Window side in nodes for a support radius of `reach` node spacings: the nodes strictly within
/// `reach` of any point along one axis (an open interval of length `2 reach`).
pub(crate) fn window_side(reach: f32) -> usize {
    (2.0 * reach).ceil().max(1.0) as usize
}

/// Scratch floats one band needs for a window side.
pub(crate) fn scratch_len(side: usize) -> usize {
    side + side * side
}

/// Adds the band's particles into its accumulator rows; `scratch` holds [`scratch_len`] floats.
pub(crate) fn scatter_band<const N: usize>(frame: &Frame, band: &mut Band, scratch: &mut [f32], avx: bool) {
    #[cfg(target_arch = "x86_64")]
    if avx {
        // SAFETY: `avx` is true only where the caller detected AVX2 and FMA on this CPU.
        unsafe { scatter_band_avx::<N>(frame, band, scratch) };
        return;
    }
    let _ = avx;
    scatter_band_body::<N, false>(frame, band, scratch);
}

/// Whether this CPU runs the AVX2 + FMA variant.
pub(crate) fn has_avx() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The band loop compiled with AVX2 and FMA (the kernel weights vectorise 8 wide as well).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn scatter_band_avx<const N: usize>(frame: &Frame, band: &mut Band, scratch: &mut [f32]) {
    scatter_band_body::<N, true>(frame, band, scratch);
}

/// `floor(x)` as an integer, without the libm call `f32::floor` is on baseline x86-64.
#[inline(always)]
fn floor_i(x: f32) -> isize {
    let i = x as isize;
    i - ((i as f32) > x) as isize
}

/// The nodes `[lo, hi)` along one axis of a window of `side` nodes around grid coordinate `g`,
/// cut to `0..len`.
#[inline(always)]
fn window(g: f32, reach: f32, side: usize, len: usize) -> (usize, usize) {
    let first = floor_i(g - reach) + 1;
    let hi = (first + side as isize).clamp(0, len as isize) as usize;
    let lo = (first.max(0) as usize).min(hi);
    (lo, hi)
}

#[inline(always)]
fn scatter_band_body<const N: usize, const AVX: bool>(frame: &Frame, band: &mut Band, scratch: &mut [f32]) {
    let g = &frame.geometry;
    let inv_spacing = 1.0 / g.spacing;
    let reach = frame.kernel.support() * inv_spacing;
    let side = frame.side;
    let (dx2, weights) = scratch.split_at_mut(side);
    let (band_lo, band_hi) = (band.rows.start, band.rows.end);
    for i in band.particles.clone() {
        let [x, y] = frame.positions[i];
        let v: &[f32; N] = frame.values[i * N..(i + 1) * N].try_into().expect("N values per particle");
        let (c0, c1) = window((x - g.origin[0]) * inv_spacing, reach, side, g.width);
        let (r0, r1) = window((y - g.origin[1]) * inv_spacing, reach, side, g.height);
        let (b0, b1) = (r0.max(band_lo), r1.min(band_hi));
        if c0 >= c1 || b0 >= b1 {
            continue;
        }
        let columns = c1 - c0;
        for (col, d) in (c0..c1).zip(dx2.iter_mut()) {
            let dx = g.origin[0] + col as f32 * g.spacing - x;
            *d = dx * dx;
        }
        // Thesis SPH normalises over the particle's whole window, so a band computes every row's
        // weights; preserving mode needs only the band's own rows.
        let (w0, w1) = match frame.mode {
            Mode::Sph => (r0, r1),
            Mode::Preserving => (b0, b1),
        };
        let used = &mut weights[..(w1 - w0) * columns];
        for (row, row_weights) in (w0..w1).zip(used.chunks_exact_mut(columns)) {
            let dy = g.origin[1] + row as f32 * g.spacing - y;
            frame.kernel.row_weights(&dx2[..columns], dy * dy, row_weights);
        }
        let scale = match frame.mode {
            Mode::Sph => {
                let total = sum(used);
                if total > 0.0 {
                    1.0 / total
                } else {
                    0.0
                }
            }
            Mode::Preserving => 1.0,
        };
        for row in b0..b1 {
            let k = (row - w0) * columns;
            let start = ((row - band_lo) * g.width + c0) * N;
            add_row::<N, AVX>(&mut band.acc[start..start + columns * N], &used[k..k + columns], scale, v);
        }
    }
}

/// Sum in eight independent lanes: a single running sum is a chain of dependent adds, four
/// cycles each.
#[inline(always)]
fn sum(xs: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let chunks = xs.chunks_exact(8);
    let tail: f32 = chunks.remainder().iter().sum();
    for chunk in chunks {
        for (l, x) in lanes.iter_mut().zip(chunk) {
            *l += x;
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// `node += w * scale * v` for consecutive nodes of one window row (`acc` holds `N` floats per
/// weight).
#[inline(always)]
pub(crate) fn add_row<const N: usize, const AVX: bool>(acc: &mut [f32], weights: &[f32], scale: f32, v: &[f32; N]) {
    assert_eq!(acc.len(), weights.len() * N, "one block per weight");
    #[cfg(target_arch = "x86_64")]
    {
        if AVX && N.is_multiple_of(8) {
            // SAFETY: AVX is true only in the variant compiled for, and detected on, AVX2 + FMA
            // CPUs; the lengths were checked above.
            unsafe { add_row_avx::<N>(acc, weights, scale, v) };
            return;
        }
        if N.is_multiple_of(4) {
            // SAFETY: SSE is baseline on x86-64; the lengths were checked above.
            unsafe { add_row_sse::<N>(acc, weights, scale, v) };
            return;
        }
    }
    for (node, &w) in acc.chunks_exact_mut(N).zip(weights) {
        let w = w * scale;
        for (a, b) in node.iter_mut().zip(v) {
            *a += w * b;
        }
    }
}

/// # Safety
/// The CPU has AVX2 and FMA; `acc.len() == weights.len() * N`; `N % 8 == 0`.
///
/// Loads and stores are `maskload` / `maskstore` with every lane on, which LLVM turns into plain
/// unaligned moves: `_mm256_loadu_ps` / `_mm256_storeu_ps` go through `copy_nonoverlapping`,
/// whose overlap check (on in this workspace's optimised `dev` profile, which keeps debug
/// assertions) forced every block through the stack and made the scatter 2-3x slower.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn add_row_avx<const N: usize>(acc: &mut [f32], weights: &[f32], scale: f32, v: &[f32; N]) {
    use std::arch::x86_64::{
        _mm256_fmadd_ps, _mm256_maskload_ps, _mm256_maskstore_ps, _mm256_set1_epi32, _mm256_set1_ps,
    };
    let all = _mm256_set1_epi32(-1);
    let node_ptr = acc.as_mut_ptr();
    for (j, &w) in weights.iter().enumerate() {
        let wv = _mm256_set1_ps(w * scale);
        for k in (0..N).step_by(8) {
            let p = node_ptr.add(j * N + k);
            let sum = _mm256_fmadd_ps(wv, _mm256_maskload_ps(v.as_ptr().add(k), all), _mm256_maskload_ps(p, all));
            _mm256_maskstore_ps(p, all, sum);
        }
    }
}

/// # Safety
/// `acc.len() == weights.len() * N`; `N % 4 == 0`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn add_row_sse<const N: usize>(acc: &mut [f32], weights: &[f32], scale: f32, v: &[f32; N]) {
    use std::arch::x86_64::{_mm_add_ps, _mm_loadu_ps, _mm_mul_ps, _mm_set1_ps, _mm_storeu_ps};
    let node_ptr = acc.as_mut_ptr();
    for (j, &w) in weights.iter().enumerate() {
        let wv = _mm_set1_ps(w * scale);
        for k in (0..N).step_by(4) {
            let p = node_ptr.add(j * N + k);
            _mm_storeu_ps(p, _mm_add_ps(_mm_loadu_ps(p), _mm_mul_ps(wv, _mm_loadu_ps(v.as_ptr().add(k)))));
        }
    }
}

/// Node-major accumulator blocks of one band -> the band's part of each output channel: the
/// channel sums (divided by the summed weight in preserving mode; below `empty` a node counts as
/// unreached and is 0), then, when `outs` has one more slice, the summed weight.
pub(crate) fn finish_band(
    acc: &mut [f32],
    stride: usize,
    c_count: usize,
    mode: Mode,
    empty: f32,
    outs: &mut [&mut [f32]],
) {
    if mode == Mode::Preserving {
        for block in acc.chunks_exact_mut(stride) {
            let w = block[c_count];
            let factor = if w > empty { 1.0 / w } else { 0.0 };
            for a in &mut block[..c_count] {
                *a *= factor;
            }
        }
    }
    // One output channel at a time, so that the writes are sequential.
    for (c, out) in outs.iter_mut().enumerate() {
        for (o, block) in out.iter_mut().zip(acc.chunks_exact(stride)) {
            *o = block[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_holds_every_node_strictly_within_reach() {
        for &(g, reach) in &[(5.3f32, 4.0f32), (5.0, 4.0), (0.2, 4.0), (-1.5, 4.0), (7.9, 1.5), (3.0, 2.0)] {
            let side = window_side(reach);
            let (lo, hi) = window(g, reach, side, 1000);
            assert!(hi - lo <= side);
            for n in 0..20usize {
                let distance = ((n as f32) - g).abs();
                if distance < reach {
                    assert!((lo..hi).contains(&n), "g {g} reach {reach} node {n}: window {lo}..{hi}");
                }
                if (lo..hi).contains(&n) {
                    assert!(distance <= reach, "g {g} reach {reach} node {n}: window {lo}..{hi}");
                }
            }
        }
        assert_eq!(window(-9.0, 4.0, 8, 10), (0, 0));
        assert_eq!(window(12.5, 4.0, 8, 10), (9, 10));
    }

    #[test]
    fn lane_sum_matches_a_running_sum() {
        let xs: Vec<f32> = (0..37).map(|i| i as f32 * 0.5).collect();
        assert_eq!(sum(&xs), xs.iter().sum::<f32>());
    }

    #[test]
    fn row_add_variants_agree() {
        let v: [f32; 8] = [1.0, -2.0, 3.5, 0.25, 8.0, -1.0, 0.0, 1.0];
        let weights = [0.5f32, 0.0, 2.0];
        let mut scalar = vec![1.0f32; 24];
        for (node, &w) in scalar.chunks_exact_mut(8).zip(&weights) {
            for (a, b) in node.iter_mut().zip(&v) {
                *a += w * 3.0 * b;
            }
        }
        let mut baseline = vec![1.0f32; 24];
        add_row::<8, false>(&mut baseline, &weights, 3.0, &v);
        assert_eq!(baseline, scalar);
        if has_avx() {
            let mut avx = vec![1.0f32; 24];
            // SAFETY: AVX2 and FMA were detected.
            unsafe { add_row_avx::<8>(&mut avx, &weights, 3.0, &v) };
            assert_eq!(avx, scalar);
        }
    }
}
