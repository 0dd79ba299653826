//! Random number generators for scene sampling and the `random` warm-start model.
//!
//! Two generators sit behind one small trait, [`Sampler`]:
//! - [`NumpyRandomState`] reproduces numpy's legacy `RandomState(seed)` bit for bit (MT19937 seeded
//!   by `init_genrand`, 53-bit doubles, the polar Box-Muller `legacy_gauss` with its cached second
//!   value), so the initial worlds of the original Python code can be rebuilt exactly;
//! - [`Xoshiro`] (xoshiro256++ seeded through SplitMix64) is the fast native default with the same
//!   distributions.

/// A source of uniform doubles in [0, 1) and standard normal deviates.
pub trait Sampler {
    /// A uniform double in [0, 1) with 53 random bits.
    fn uniform(&mut self) -> f64;

    /// A standard normal deviate (polar Box-Muller, numpy's `legacy_gauss` algorithm).
    fn gauss(&mut self) -> f64;

    /// A uniform double in [lo, hi).
    fn uniform_range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// `mu + sigma * gauss()`, numpy's `legacy_normal`.
    fn normal(&mut self, mu: f64, sigma: f64) -> f64 {
        mu + sigma * self.gauss()
    }
}

/// Polar Box-Muller with a cached second value, exactly numpy's `legacy_gauss`.
///
/// Numpy returns `f * x2` first and keeps `f * x1` for the next call; the order matters for
/// bit-identical reproduction.
fn polar_gauss(uniform: &mut impl FnMut() -> f64, cache: &mut Option<f64>) -> f64 {
    if let Some(g) = cache.take() {
        return g;
    }
    loop {
        let x1 = 2.0 * uniform() - 1.0;
        let x2 = 2.0 * uniform() - 1.0;
        let r2 = x1 * x1 + x2 * x2;
        if r2 >= 1.0 || r2 == 0.0 {
            continue;
        }
        let f = (-2.0 * r2.ln() / r2).sqrt();
        *cache = Some(f * x1);
        return f * x2;
    }
}

/// Mersenne Twister MT19937 (32-bit), the bit generator behind numpy's legacy `RandomState`.
#[derive(Clone)]
pub struct Mt19937 {
    state: [u32; 624],
    index: usize,
}

impl Mt19937 {
    const N: usize = 624;
    const M: usize = 397;

    /// Seeds with `init_genrand(seed)`, which is what numpy's `RandomState(int)` does.
    pub fn new(seed: u32) -> Mt19937 {
        let mut state = [0u32; 624];
        state[0] = seed;
        for i in 1..Self::N {
            let prev = state[i - 1];
            state[i] = 1_812_433_253u32.wrapping_mul(prev ^ (prev >> 30)).wrapping_add(i as u32);
        }
        Mt19937 { state, index: Self::N }
    }

    fn generate(&mut self) {
        const UPPER: u32 = 0x8000_0000;
        const LOWER: u32 = 0x7fff_ffff;
        const MATRIX_A: u32 = 0x9908_b0df;
        for i in 0..Self::N {
            let y = (self.state[i] & UPPER) | (self.state[(i + 1) % Self::N] & LOWER);
            let mut v = self.state[(i + Self::M) % Self::N] ^ (y >> 1);
            if y & 1 != 0 {
                v ^= MATRIX_A;
            }
            self.state[i] = v;
        }
        self.index = 0;
    }

    /// The next tempered 32-bit output.
    pub fn next_u32(&mut self) -> u32 {
        if self.index >= Self::N {
            self.generate();
        }
        let mut y = self.state[self.index];
        self.index += 1;
        y ^= y >> 11;
        y ^= (y << 7) & 0x9d2c_5680;
        y ^= (y << 15) & 0xefc6_0000;
        y ^= y >> 18;
        y
    }
}

/// numpy's legacy `RandomState(seed)`: `random_sample` and `normal` reproduced exactly.
#[derive(Clone)]
pub struct NumpyRandomState {
    mt: Mt19937,
    gauss: Option<f64>,
}

impl NumpyRandomState {
    /// `np.random.RandomState(seed)` for an integer seed.
    pub fn new(seed: u32) -> NumpyRandomState {
        NumpyRandomState { mt: Mt19937::new(seed), gauss: None }
    }

    /// `rand(n)`: `n` uniform doubles.
    pub fn rand(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.uniform()).collect()
    }
}

impl Sampler for NumpyRandomState {
    fn uniform(&mut self) -> f64 {
        // numpy's legacy_double / mt19937_next_double: 27 + 26 bits.
        let a = (self.mt.next_u32() >> 5) as f64;
        let b = (self.mt.next_u32() >> 6) as f64;
        (a * 67_108_864.0 + b) / 9_007_199_254_740_992.0
    }

    fn gauss(&mut self) -> f64 {
        let mt = &mut self.mt;
        let mut uniform = || {
            let a = (mt.next_u32() >> 5) as f64;
            let b = (mt.next_u32() >> 6) as f64;
            (a * 67_108_864.0 + b) / 9_007_199_254_740_992.0
        };
        polar_gauss(&mut uniform, &mut self.gauss)
    }
}

/// xoshiro256++ seeded through SplitMix64: small, fast and good enough for sampling scenes.
#[derive(Clone)]
pub struct Xoshiro {
    s: [u64; 4],
    gauss: Option<f64>,
}

impl Xoshiro {
    /// A generator whose whole state derives from `seed` (SplitMix64 expansion, never all zero).
    pub fn new(seed: u64) -> Xoshiro {
        let mut sm = seed;
        let mut next = || {
            sm = sm.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = sm;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^ (z >> 31)
        };
        Xoshiro { s: [next(), next(), next(), next()], gauss: None }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }
}

impl Sampler for Xoshiro {
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    fn gauss(&mut self) -> f64 {
        let mut cache = self.gauss.take();
        let g = {
            let mut uniform = || (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0);
            polar_gauss(&mut uniform, &mut cache)
        };
        self.gauss = cache;
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mt19937_matches_reference_output() {
        // Reference: the first outputs of init_genrand(5489) (the MT19937 default seed).
        let mut mt = Mt19937::new(5489);
        assert_eq!(mt.next_u32(), 3_499_211_612);
        assert_eq!(mt.next_u32(), 581_869_302);
        assert_eq!(mt.next_u32(), 3_890_346_734);
    }

    #[test]
    fn numpy_random_sample_matches_numpy() {
        // np.random.RandomState(0).rand(2) == [0.5488135039273248, 0.7151893663724195]
        let mut rs = NumpyRandomState::new(0);
        assert_eq!(rs.uniform(), 0.5488135039273248);
        assert_eq!(rs.uniform(), 0.7151893663724195);
    }

    #[test]
    fn numpy_normal_matches_numpy() {
        // np.random.RandomState(0).normal(0, 1, 3) == [1.764052345967664, 0.4001572083672233,
        // 0.9787379841057392]
        let mut rs = NumpyRandomState::new(0);
        assert_eq!(rs.gauss(), 1.764052345967664);
        assert_eq!(rs.gauss(), 0.4001572083672233);
        assert_eq!(rs.gauss(), 0.9787379841057392);
    }

    #[test]
    fn xoshiro_moments_are_standard() {
        let mut x = Xoshiro::new(3);
        let n = 200_000;
        let (mut s, mut s2, mut u) = (0.0, 0.0, 0.0);
        for _ in 0..n {
            let g = x.gauss();
            s += g;
            s2 += g * g;
            u += x.uniform();
        }
        let n = n as f64;
        assert!((s / n).abs() < 0.01, "mean {}", s / n);
        assert!((s2 / n - 1.0).abs() < 0.02, "variance {}", s2 / n);
        assert!((u / n - 0.5).abs() < 0.005, "uniform mean {}", u / n);
    }
}
