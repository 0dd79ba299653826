//! The bus plumbing node's science: deterministic frame contents that a receiver can verify bit
//! for bit, a monotonic clock shared by processes of one host, and latency / throughput summaries.

use msgs::{Body, GridHeader, StepHeader};
use serde::{Deserialize, Serialize};

/// Grid size of the bench: the U-Net's temporal input, 7 x 128 x 128.
pub const GRID_CHANNELS: [&str; 7] = ["vx", "vy", "omega", "mass", "inertia", "normal", "tangent"];
pub const GRID_SIDE: u32 = 128;

/// CLOCK_MONOTONIC in nanoseconds: one clock for every process of a host, so a receiver can
/// measure one-way latency from a timestamp the sender put in the header.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A cheap, well-mixed 32-bit hash (for verifiable contents).
fn mix(a: u32, b: u32) -> u32 {
    let mut x = a.wrapping_mul(0x9E37_79B9) ^ b.wrapping_mul(0x85EB_CA6B);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x
}

/// Fills `bodies` with the contents of frame `seq` (every bit depends on seq and index).
pub fn fill_bodies(seq: u32, bodies: &mut [Body]) {
    for (i, b) in bodies.iter_mut().enumerate() {
        let i = i as u32;
        let h = mix(seq, i);
        *b = Body {
            id: i,
            shape: h % 3,
            size: [f32::from_bits(mix(h, 1) & 0x7F7F_FFFF), 0.5],
            mass: f32::from_bits(mix(h, 2) & 0x7F7F_FFFF),
            inertia: seq as f32,
            x: i as f32 * 0.5,
            y: f32::from_bits(mix(h, 3) & 0x7F7F_FFFF),
            angle: -(i as f32),
            vx: f32::from_bits(mix(h, 4) & 0xFF7F_FFFF),
            vy: f32::from_bits(mix(h, 5) & 0xFF7F_FFFF),
            omega: h as f32,
        };
    }
}

/// Fills grid values of frame `seq`.
pub fn fill_grid(seq: u32, values: &mut [f32]) {
    for (i, v) in values.iter_mut().enumerate() {
        *v = f32::from_bits(mix(seq, i as u32) & 0xFF7F_FFFF);
    }
}

/// Values of the bench grid.
pub const GRID_LEN: usize = GRID_CHANNELS.len() * (GRID_SIDE * GRID_SIDE) as usize;

/// The bench grid's header for a frame.
pub fn grid_header(step: StepHeader) -> GridHeader {
    msgs::Grid::zeros(step, [0.0, 0.0], 0.125, 0, 0, &GRID_CHANNELS).header.with_size(GRID_SIDE, GRID_SIDE)
}

/// Index of the first element that differs bitwise, if any.
pub fn first_difference<T: msgs::FrameItem>(got: &[T], expected: &[T]) -> Option<usize> {
    if got.len() != expected.len() {
        return Some(got.len().min(expected.len()));
    }
    got.iter().zip(expected).position(|(a, b)| bytemuck::bytes_of(a) != bytemuck::bytes_of(b))
}

/// Latency and throughput of one bench case, as the receiver measured them. The latency
/// percentiles are by nearest rank ([`charts::quantile_nearest_rank`]): each is a measured
/// latency.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BenchResult {
    pub transport: String,
    pub payload: String,
    pub bytes: usize,
    pub latency_samples: usize,
    pub p50_us: f64,
    pub p99_us: f64,
    pub frames_per_s: f64,
    pub mb_per_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contents_differ_between_frames_and_are_reproducible() {
        let mut a = vec![Body::default(); 100];
        let mut b = vec![Body::default(); 100];
        fill_bodies(1, &mut a);
        fill_bodies(1, &mut b);
        assert_eq!(first_difference(&a, &b), None);
        fill_bodies(2, &mut b);
        assert_eq!(first_difference(&a, &b), Some(0));
    }
}
