//! Synthetic frames with known values, for the transfer-error study, the benchmark and the tests:
//! a settled ball pile like the thesis's scene, uniformly scattered particles, and isolated ones.
//! Deterministic from a seed (a small [`SplitMix64`] generator, so the library needs no `rand`).
//!
//! [`SplitMix64`] is the workspace's one seeded generator for data (the U-Net's split and batch
//! shuffles use it too); it is part of the light library (no feature needed).

use crate::geometry::Bounds;
use crate::particles::{ParticleSet, Source};
use msgs::{Body, Contact, Shape};

/// SplitMix64's increment, the golden gamma `2^64 / phi`.
const GOLDEN_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// SplitMix64 (Steele, Lea and Flood 2014, as in Vigna's reference `splitmix64.c`): tiny, fast,
/// deterministic across platforms and builds; good enough for test data and shuffles, not for
/// cryptography. The state is public: `SplitMix64(s)` continues the reference generator from state
/// `s` (its first output mixes `s + gamma`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The generator with state `state` (the reference seeding: no scrambling of the seed).
    pub fn new(state: u64) -> SplitMix64 {
        SplitMix64(state)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN_GAMMA);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f32 {
        let u = self.unit().max(1e-7);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    }
}

/// The generator of the synthetic frames for `seed`: state `seed ^ gamma` (what these frames have
/// always used; changing it would change every synthetic frame and the study's numbers).
fn frame_rng(seed: u64) -> SplitMix64 {
    SplitMix64(seed ^ GOLDEN_GAMMA)
}

/// A synthetic simulation frame: bodies (walls included) and contacts with impulses.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthFrame {
    /// Balls, then the four walls.
    pub bodies: Vec<Body>,
    /// Contacts at the touching points.
    pub contacts: Vec<Contact>,
}

/// Ball radius of the thesis's scene.
pub const BALL_RADIUS: f32 = 0.5;
const GRAVITY_DT: f32 = 9.81 / 100.0;

/// A settled pile of `n` balls of radius 0.5 in the 15 x 15 box (the thesis's scene after the balls
/// have fallen): hexagonally packed rows of 14 and 13 balls from the floor up, a partial top row,
/// the whole pile shifted sideways and each ball jittered a little by the seed. Contacts sit at the
/// touching points between balls and against floor and walls; their normal impulse grows with the
/// number of layers above (the weight the contact carries, `m g dt` per layer) times a random factor
/// in [0.7, 1.3], the tangent impulse is within +-0.25 of it (inside a friction cone of 0.5).
pub fn ball_pile(seed: u64, n: usize) -> SynthFrame {
    let mut rng = frame_rng(seed);
    let r = BALL_RADIUS;
    let side = Bounds::THESIS_BOX.max[0];
    let mass = std::f32::consts::PI * r * r;
    let row_height = 3f32.sqrt() * r;
    let shift = rng.uniform(-0.45, 0.45);
    // Slots row by row; the last row keeps a random subset.
    let mut centres: Vec<[f32; 2]> = Vec::with_capacity(n);
    let mut row = 0;
    while centres.len() < n {
        let count = if row % 2 == 0 { 14 } else { 13 };
        let x0 = side / 2.0 - (count as f32 - 1.0) * r + shift;
        let y = r + row as f32 * row_height;
        let mut slots: Vec<usize> = (0..count).collect();
        let take = (n - centres.len()).min(count);
        for i in 0..take {
            let j = i + (rng.next_u64() % (count - i) as u64) as usize;
            slots.swap(i, j);
        }
        let mut chosen = slots[..take].to_vec();
        chosen.sort_unstable();
        for i in chosen {
            let jitter = [rng.uniform(-0.01, 0.01), rng.uniform(0.0, 0.01)];
            centres.push([x0 + 2.0 * r * i as f32 + jitter[0], y + jitter[1]]);
        }
        row += 1;
    }
    let top = centres.iter().map(|c| c[1]).fold(0.0, f32::max);

    let mut bodies: Vec<Body> = centres
        .iter()
        .enumerate()
        .map(|(i, c)| Body {
            id: i as u32,
            shape: Shape::Ball as u32,
            size: [r, r],
            mass,
            inertia: 0.5 * mass * r * r,
            x: c[0],
            y: c[1],
            angle: rng.uniform(-3.1, 3.1),
            vx: 0.05 * rng.normal(),
            vy: 0.05 * rng.normal(),
            omega: 0.2 * rng.normal(),
        })
        .collect();
    let first_wall = bodies.len() as u32;
    for (k, (x, y, hx, hy)) in [
        (side / 2.0, -0.5, side / 2.0 + 1.0, 0.5),
        (side / 2.0, side + 0.5, side / 2.0 + 1.0, 0.5),
        (-0.5, side / 2.0, 0.5, side / 2.0 + 1.0),
        (side + 0.5, side / 2.0, 0.5, side / 2.0 + 1.0),
    ]
    .into_iter()
    .enumerate()
    {
        bodies.push(Body {
            id: first_wall + k as u32,
            shape: Shape::Wall as u32,
            size: [hx, hy],
            x,
            y,
            ..Default::default()
        });
    }

    let mut contacts = Vec::new();
    let mut contact = |a: u32, b: u32, p: [f32; 2], normal: [f32; 2], rng: &mut SplitMix64| {
        let layers_above = ((top - p[1]) / row_height).max(0.0) + 1.0;
        let lambda = mass * GRAVITY_DT * layers_above * rng.uniform(0.7, 1.3);
        contacts.push(Contact {
            body_a: a,
            body_b: b,
            feature: 0,
            x: p[0],
            y: p[1],
            nx: normal[0],
            ny: normal[1],
            penetration: 0.0,
            friction: 0.5,
            normal_impulse: lambda,
            tangent_impulse: lambda * rng.uniform(-0.25, 0.25),
        });
    };
    let touch = 0.04;
    for (i, a) in centres.iter().enumerate() {
        for (j, b) in centres.iter().enumerate().skip(i + 1) {
            let d = [b[0] - a[0], b[1] - a[1]];
            let dist = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if dist < 2.0 * r + touch {
                let nrm = [d[0] / dist, d[1] / dist];
                contact(i as u32, j as u32, [a[0] + nrm[0] * r, a[1] + nrm[1] * r], nrm, &mut rng);
            }
        }
        if a[1] - r < touch {
            contact(first_wall, i as u32, [a[0], 0.0], [0.0, 1.0], &mut rng);
        }
        if a[0] - r < touch {
            contact(first_wall + 2, i as u32, [0.0, a[1]], [1.0, 0.0], &mut rng);
        }
        if a[0] + r > side - touch {
            contact(first_wall + 3, i as u32, [side, a[1]], [-1.0, 0.0], &mut rng);
        }
    }
    SynthFrame { bodies, contacts }
}

/// `n` particles uniformly in `bounds` with `channels` values each, smooth in space (a sum of two
/// sinusoids per channel) plus 10% noise: a stand-in for any field on any layout, e.g. for timing.
pub fn scattered(seed: u64, n: usize, bounds: Bounds, channels: &[&str]) -> ParticleSet {
    let mut rng = frame_rng(seed);
    let mut set = ParticleSet::new(channels);
    set.reserve(n);
    let mut values = vec![0.0; channels.len()];
    for i in 0..n {
        let p = [rng.uniform(bounds.min[0], bounds.max[0]), rng.uniform(bounds.min[1], bounds.max[1])];
        for (c, v) in values.iter_mut().enumerate() {
            let k = 0.3 + 0.1 * c as f32;
            *v = 1.0 + 0.5 * (k * p[0]).sin() * (0.7 * k * p[1]).cos() + 0.1 * rng.normal();
        }
        set.push(Source::Index(i as u32), p, &values).expect("synthetic values are finite");
    }
    set
}

/// Up to `n` particles in `bounds`, at least `separation` apart (rejection sampling), one channel
/// `value` uniform in [0.1, 5]: each particle alone within its kernel support when `separation > 2h`.
pub fn isolated(seed: u64, n: usize, bounds: Bounds, separation: f32) -> ParticleSet {
    let mut rng = frame_rng(seed);
    let mut set = ParticleSet::new(&["value"]);
    let mut tries = 0;
    while set.len() < n && tries < 100 * n {
        tries += 1;
        let p = [rng.uniform(bounds.min[0], bounds.max[0]), rng.uniform(bounds.min[1], bounds.max[1])];
        let far = set.positions().iter().all(|q| (q[0] - p[0]).hypot(q[1] - p[1]) >= separation);
        if far {
            let v = rng.uniform(0.1, 5.0);
            set.push(Source::Index(set.len() as u32), p, &[v]).expect("finite");
        }
    }
    set
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_sequence() {
        // Vigna's splitmix64.c from state 0 and from state 42.
        let mut g = SplitMix64::new(0);
        assert_eq!(
            [g.next_u64(), g.next_u64(), g.next_u64()],
            [0xe220a8397b1dcdaf, 0x6e789e6aa1b965f4, 0x06c45d188009454f]
        );
        let mut g = SplitMix64(42);
        assert_eq!([g.next_u64(), g.next_u64()], [0xbdd732262feb6e95, 0x28efe333b266f103]);
        assert_eq!(g, SplitMix64(42u64.wrapping_add(GOLDEN_GAMMA.wrapping_mul(2))), "the state advances by gamma");
    }

    #[test]
    fn ball_pile_has_100_balls_inside_the_box_touching_each_other() {
        let f = ball_pile(3, 100);
        let balls: Vec<&Body> = f.bodies.iter().filter(|b| b.shape == Shape::Ball as u32).collect();
        assert_eq!(balls.len(), 100);
        assert!(balls.iter().all(|b| b.x >= 0.5 && b.x <= 14.5 && b.y >= 0.5 && b.y < 15.0));
        // A hexagonal pile: about three contacts per ball, no overlaps.
        assert!(f.contacts.len() > 200 && f.contacts.len() < 400, "{}", f.contacts.len());
        for (i, a) in balls.iter().enumerate() {
            for b in &balls[i + 1..] {
                assert!((a.x - b.x).hypot(a.y - b.y) > 0.98, "overlap");
            }
        }
        assert!(f
            .contacts
            .iter()
            .all(|c| c.normal_impulse > 0.0 && c.tangent_impulse.abs() <= 0.25 * c.normal_impulse));
        assert_eq!(ball_pile(3, 100), f, "deterministic from the seed");
    }

    #[test]
    fn isolated_particles_keep_their_distance() {
        let s = isolated(1, 30, Bounds::THESIS_BOX, 1.2);
        assert_eq!(s.len(), 30);
        let p = s.positions();
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                assert!((p[i][0] - p[j][0]).hypot(p[i][1] - p[j][1]) >= 1.2);
            }
        }
    }
}
