//! Smoothing kernels `W(r, h)` in two dimensions, each normalised so that it integrates to 1 over
//! the plane and vanishes beyond its support radius `h`.
//!
//! The 2D constants differ from the 3D ones found in most SPH papers (and in the thesis's text):
//! - Poly6 `4 / (pi h^8) (h^2 - r^2)^3`: `int_0^h 2 pi r (h^2 - r^2)^3 dr = pi h^8 / 4`;
//! - Spiky `10 / (pi h^5) (h - r)^3`: `int_0^h 2 pi r (h - r)^3 dr = pi h^5 / 10` (the thesis's
//!   `15 / (pi h^6)` is the 3D constant and would not integrate to 1 in the plane);
//! - Gaussian with standard deviation `sigma`, truncated at `h`:
//!   `exp(-r^2 / 2 sigma^2) / (2 pi sigma^2 (1 - exp(-h^2 / 2 sigma^2)))`, the denominator being
//!   the mass inside the truncation radius.

use crate::error::SphError;
use std::f32::consts::PI;
use std::fmt;
use std::str::FromStr;

/// Which kernel, before a support radius is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KernelKind {
    /// `4 / (pi h^8) (h^2 - r^2)^3`: smooth, flat top, the thesis's choice.
    Poly6,
    /// `10 / (pi h^5) (h - r)^3`: peaked at the particle.
    Spiky,
    /// A Gaussian with `sigma = sigma_over_h * h`, truncated at `h` and renormalised.
    Gaussian {
        /// Standard deviation as a fraction of the support radius (1/3 by default: the truncated
        /// tail then holds ~1% of the untruncated mass).
        sigma_over_h: f32,
    },
}

impl KernelKind {
    /// The Gaussian with the default `sigma = h / 3`.
    pub const GAUSSIAN: KernelKind = KernelKind::Gaussian { sigma_over_h: 1.0 / 3.0 };
    /// The kernels of the transfer-error study, in the order of its tables.
    pub const ALL: [KernelKind; 3] = [KernelKind::Poly6, KernelKind::Spiky, KernelKind::GAUSSIAN];

    /// The kernel with support radius `h` (> 0).
    pub fn with_support(self, h: f32) -> Result<Kernel, SphError> {
        Kernel::new(self, h)
    }
}

impl fmt::Display for KernelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KernelKind::Poly6 => write!(f, "poly6"),
            KernelKind::Spiky => write!(f, "spiky"),
            KernelKind::Gaussian { sigma_over_h } if *sigma_over_h == 1.0 / 3.0 => write!(f, "gaussian"),
            KernelKind::Gaussian { sigma_over_h } => write!(f, "gaussian:{sigma_over_h}"),
        }
    }
}

impl FromStr for KernelKind {
    type Err = SphError;
    /// `poly6`, `spiky`, `gaussian` (sigma = h / 3) or `gaussian:RATIO` (sigma = RATIO * h).
    fn from_str(s: &str) -> Result<KernelKind, SphError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "poly6" => Ok(KernelKind::Poly6),
            "spiky" => Ok(KernelKind::Spiky),
            "gaussian" => Ok(KernelKind::GAUSSIAN),
            other => match other.strip_prefix("gaussian:").map(str::parse::<f32>) {
                Some(Ok(r)) if r > 0.0 && r.is_finite() => Ok(KernelKind::Gaussian { sigma_over_h: r }),
                _ => Err(SphError::BadParameter(format!(
                    "unknown kernel `{s}` (poly6, spiky, gaussian, gaussian:SIGMA_OVER_H)"
                ))),
            },
        }
    }
}

/// A kernel with its support radius and normalisation worked out, ready to evaluate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    kind: KernelKind,
    h: f32,
    h2: f32,
    /// Normalisation constant (the factor in front of the shape function).
    norm: f32,
    /// `1 / (2 sigma^2)` for the Gaussian.
    inv_two_sigma2: f32,
}

impl Kernel {
    /// `kind` with support radius `h` (> 0, finite).
    pub fn new(kind: KernelKind, h: f32) -> Result<Kernel, SphError> {
        if !(h > 0.0 && h.is_finite()) {
            return Err(SphError::BadParameter(format!("support radius h must be > 0, got {h}")));
        }
        let (norm, inv_two_sigma2) = match kind {
            KernelKind::Poly6 => (4.0 / (PI * h.powi(8)), 0.0),
            KernelKind::Spiky => (10.0 / (PI * h.powi(5)), 0.0),
            KernelKind::Gaussian { sigma_over_h } => {
                if !(sigma_over_h > 0.0 && sigma_over_h.is_finite()) {
                    return Err(SphError::BadParameter(format!("gaussian sigma / h must be > 0, got {sigma_over_h}")));
                }
                let sigma = sigma_over_h * h;
                let a = 1.0 / (2.0 * sigma * sigma);
                let inside = 1.0 - (-h * h * a).exp();
                (1.0 / (2.0 * PI * sigma * sigma * inside), a)
            }
        };
        Ok(Kernel { kind, h, h2: h * h, norm, inv_two_sigma2 })
    }

    /// Which kernel.
    pub fn kind(&self) -> KernelKind {
        self.kind
    }

    /// Support radius: the kernel is 0 at and beyond it.
    pub fn support(&self) -> f32 {
        self.h
    }

    /// `W(r)` for a distance `r`.
    pub fn eval(&self, r: f32) -> f32 {
        self.eval_r2(r * r)
    }

    /// `W` from the squared distance, which is what the neighbour searches return (Poly6 and the
    /// Gaussian then need no square root).
    #[inline]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(r2 < h2)` on purpose: NaN is outside the support
    pub fn eval_r2(&self, r2: f32) -> f32 {
        if !(r2 < self.h2) {
            return 0.0;
        }
        match self.kind {
            KernelKind::Poly6 => {
                let d = self.h2 - r2;
                self.norm * d * d * d
            }
            KernelKind::Spiky => {
                let d = self.h - r2.sqrt();
                self.norm * d * d * d
            }
            KernelKind::Gaussian { .. } => self.norm * (-r2 * self.inv_two_sigma2).exp(),
        }
    }
}

impl Kernel {
    /// Writes `W` for the squared distances `dx2[k] + dy2` into `out[k]`: one row of a particle's
    /// index window. The kernel is chosen once per row rather than per node, and the Poly6 and
    /// Spiky loops are branch-free (`max(0)` instead of the support test), so they vectorise.
    #[inline(always)]
    pub fn row_weights(&self, dx2: &[f32], dy2: f32, out: &mut [f32]) {
        let (h, h2, norm) = (self.h, self.h2, self.norm);
        match self.kind {
            KernelKind::Poly6 => {
                for (o, &d) in out.iter_mut().zip(dx2) {
                    let d = (h2 - (d + dy2)).max(0.0);
                    *o = norm * d * d * d;
                }
            }
            KernelKind::Spiky => {
                for (o, &d) in out.iter_mut().zip(dx2) {
                    let d = (h - (d + dy2).sqrt()).max(0.0);
                    *o = norm * d * d * d;
                }
            }
            KernelKind::Gaussian { .. } => {
                for (o, &d) in out.iter_mut().zip(dx2) {
                    *o = self.eval_r2(d + dy2);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Midpoint rule over the square [-h, h]^2 with `n x n` cells, in f64.
    fn integral(k: &Kernel, n: usize) -> f64 {
        let h = k.support() as f64;
        let d = 2.0 * h / n as f64;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let x = -h + (i as f64 + 0.5) * d;
                let y = -h + (j as f64 + 0.5) * d;
                sum += k.eval(((x * x + y * y) as f32).sqrt()) as f64;
            }
        }
        sum * d * d
    }

    #[test]
    fn every_kernel_integrates_to_one_over_the_plane() {
        for kind in KernelKind::ALL.into_iter().chain([KernelKind::Gaussian { sigma_over_h: 0.5 }]) {
            for h in [0.25, 0.5, 2.0] {
                let k = kind.with_support(h).unwrap();
                let i = integral(&k, 800);
                assert!((i - 1.0).abs() < 2e-3, "{kind} h={h}: integral {i}");
            }
        }
    }

    #[test]
    fn the_thesis_3d_spiky_constant_would_not_integrate_to_one_in_2d() {
        // 15 / (pi h^6) instead of 10 / (pi h^5): off by 1.5 / h, so right only at h = 1.5.
        let k = KernelKind::Spiky.with_support(0.5).unwrap();
        let i = integral(&k, 800) * (15.0 / 0.5f64.powi(6)) / (10.0 / 0.5f64.powi(5));
        assert!((i - 3.0).abs() < 1e-2, "{i}");
    }

    #[test]
    fn kernels_vanish_at_and_beyond_the_support_radius() {
        for kind in KernelKind::ALL {
            let k = kind.with_support(0.5).unwrap();
            assert_eq!(k.eval(0.5), 0.0, "{kind}");
            assert_eq!(k.eval(0.7), 0.0, "{kind}");
            assert!(k.eval(0.0) > k.eval(0.25) && k.eval(0.25) > 0.0, "{kind}");
        }
    }

    #[test]
    fn row_weights_match_pointwise_evaluation() {
        let dx2: Vec<f32> = (0..9).map(|i| (0.125 * i as f32 - 0.5).powi(2)).collect();
        for kind in KernelKind::ALL {
            let k = kind.with_support(0.5).unwrap();
            for dy2 in [0.0, 0.01, 0.2, 0.3] {
                let mut out = vec![-1.0; dx2.len() + 1];
                k.row_weights(&dx2, dy2, &mut out[..dx2.len()]);
                assert_eq!(out[dx2.len()], -1.0);
                for (a, &d) in out.iter().zip(&dx2) {
                    let b = k.eval_r2(d + dy2);
                    assert!((a - b).abs() <= 1e-6 * b.abs().max(1e-3), "{kind}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn kernel_names_round_trip_and_bad_ones_are_rejected() {
        for kind in KernelKind::ALL.into_iter().chain([KernelKind::Gaussian { sigma_over_h: 0.5 }]) {
            assert_eq!(kind.to_string().parse::<KernelKind>().unwrap(), kind);
        }
        assert!("cubic".parse::<KernelKind>().is_err());
        assert!("gaussian:-1".parse::<KernelKind>().is_err());
        assert!(Kernel::new(KernelKind::Poly6, 0.0).is_err());
    }
}
