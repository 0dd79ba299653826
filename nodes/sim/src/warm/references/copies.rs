//! Fixed references of the evaluation: the step's exact solution as it is (`copy`), rounded
//! (`copy0`, `copy2`) or sent through the SPH grid and back (`copy-grid`, `copy-grid-sph`), and
//! random starts (`random`; `bad` is a constant start, built by the registry). The oracle behind the first ones *is* the
//! solve: they bound what a model could gain, they are not models a simulator can run.

use crate::contact::ContactPoint;
use crate::rng::{Sampler, Xoshiro};
use crate::solver::rows::Impulse;
use crate::warm::model::{exact_solution, Needs, Unavailable, WarmStartInput, WarmStartModel};

/// `copy`, `copy0`, `copy2`, `copy-grid`, `copy-grid-sph`: the step's own solution (the oracle),
/// as it is or degraded the way a prediction would be: rounded, or sent through a grid and back.
#[derive(Debug)]
pub struct Copy {
    name: &'static str,
    degrade: Degrade,
}

/// What [`Copy`] does to the exact solution.
#[derive(Debug)]
enum Degrade {
    Nothing,
    Round { decimals: i32 },
    Grid(GridTrip),
}

impl Copy {
    /// The exact solution (`copy`).
    pub fn exact() -> Copy {
        Copy { name: "copy", degrade: Degrade::Nothing }
    }
    /// The solution rounded to whole units (`copy0`).
    pub fn rounded_to_units() -> Copy {
        Copy { name: "copy0", degrade: Degrade::Round { decimals: 0 } }
    }
    /// The solution rounded to 2 decimals (`copy2`).
    pub fn rounded_to_hundredths() -> Copy {
        Copy { name: "copy2", degrade: Degrade::Round { decimals: 2 } }
    }
    /// The solution through the SPH grid and back (particle -> grid -> bilinear at the contacts),
    /// by the value-preserving transfer (`copy-grid`) or the thesis's (`copy-grid-sph`). The gate
    /// for every grid-based model: no prediction on that grid can do better than the solution
    /// itself after the transfer.
    pub fn through_grid(mode: sph::Mode) -> Copy {
        let name = match mode {
            sph::Mode::Preserving => "copy-grid",
            sph::Mode::Sph => "copy-grid-sph",
        };
        Copy { name, degrade: Degrade::Grid(GridTrip::new(mode)) }
    }
}

impl WarmStartModel for Copy {
    fn name(&self) -> &str {
        self.name
    }
    fn needs(&self) -> Needs {
        Needs::EXACT
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        out.copy_from_slice(exact_solution(input)?);
        match &self.degrade {
            Degrade::Nothing => {}
            Degrade::Round { decimals } => {
                let s = 10f32.powi(*decimals);
                for o in out.iter_mut() {
                    o.normal = (o.normal * s).round() / s;
                    o.tangent = (o.tangent * s).round() / s;
                }
            }
            Degrade::Grid(trip) => {
                trip.round_trip(input.contacts, out).map_err(|e| Unavailable(format!("grid transfer: {e}")))?
            }
        }
        Ok(())
    }
}

/// The SPH transfer of contact values to a grid and back.
#[derive(Debug)]
struct GridTrip {
    config: sph::TransferConfig,
    /// Grid spacing (the thesis's 0.125).
    spacing: f32,
}

impl GridTrip {
    fn new(mode: sph::Mode) -> GridTrip {
        GridTrip { config: sph::TransferConfig { mode, ..Default::default() }, spacing: 0.125 }
    }

    /// A grid over the contacts, on the lattice of a scene grid with origin (0, 0) (so the result
    /// is the same as on the scene-sized grid: only nodes within the kernel radius matter).
    fn geometry(&self, contacts: &[ContactPoint]) -> Result<sph::GridGeometry, sph::SphError> {
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for c in contacts {
            for (i, v) in [c.point.x, c.point.y].into_iter().enumerate() {
                lo[i] = lo[i].min(v);
                hi[i] = hi[i].max(v);
            }
        }
        let margin = self.config.h + self.spacing;
        let snap_lo = |v: f32| ((v - margin) / self.spacing).floor() * self.spacing;
        let snap_hi = |v: f32| ((v + margin) / self.spacing).ceil() * self.spacing;
        let bounds = sph::Bounds::new([snap_lo(lo[0]), snap_lo(lo[1])], [snap_hi(hi[0]), snap_hi(hi[1])])?;
        sph::GridGeometry::from_bounds(bounds, self.spacing, 1)
    }

    /// Replaces each contact's value in `values` by its value after the round trip.
    fn round_trip(&self, contacts: &[ContactPoint], values: &mut [Impulse]) -> Result<(), sph::SphError> {
        if contacts.is_empty() {
            return Ok(());
        }
        let mut particles = sph::ParticleSet::new(&["normal", "tangent"]);
        for (c, o) in contacts.iter().zip(values.iter()) {
            let source = sph::Source::Contact { body_a: c.key.body_a, body_b: c.key.body_b };
            particles.push(source, [c.point.x, c.point.y], &[o.normal, o.tangent])?;
        }
        let mut transfer = sph::Transfer::new(self.config, self.geometry(contacts)?)?;
        let (back, _) = transfer.round_trip(&particles)?;
        for (o, v) in values.iter_mut().zip(back.chunks_exact(2)) {
            *o = Impulse { normal: v[0], tangent: v[1] };
        }
        Ok(())
    }
}

/// `random`: normal uniform in [0, 5], tangent uniform in [-2, 2]; reseeded from the simulation's
/// seed, so runs repeat.
#[derive(Clone)]
pub struct Random {
    seed: u64,
    rng: Xoshiro,
}

impl Random {
    /// A random model whose stream derives from `seed` and each simulation's seed.
    pub fn new(seed: u64) -> Random {
        Random { seed, rng: Xoshiro::new(seed) }
    }
}

impl WarmStartModel for Random {
    fn name(&self) -> &str {
        "random"
    }
    fn begin_simulation(&mut self, _simulation: u32, seed: u64) {
        // Distinct from the scene sampler's stream of the same seed.
        self.rng = Xoshiro::new(self.seed ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x5eed);
    }
    fn warm_start(&mut self, _: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        for o in out.iter_mut() {
            o.normal = self.rng.uniform_range(0.0, 5.0) as f32;
            o.tangent = self.rng.uniform_range(-2.0, 2.0) as f32;
        }
        Ok(())
    }
}
