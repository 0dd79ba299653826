//! SPH grid transfer for Deep Contact: smoothing kernels, particle -> grid scatter, grid -> particle
//! bilinear sampling. Their parameters were chosen by the transfer-error study (an experiment:
//! `experiments::sph_study`, binary `dc-sph-study`).
//!
//! The thesis (chapters 4 and 7.2) lost its warm starts here: its transfer normalised each
//! particle's kernel weights to sum 1, spreading every impulse over ~50 nodes so that less than 20%
//! came back, and its grid -> contact lookup read the grid transposed and flipped. This crate
//! keeps the thesis's transfer as [`Mode::Sph`] for comparison and defaults to
//! [`Mode::Preserving`] (Shepard / normalised gather), which gives an isolated particle's value back
//! exactly; orientation lives in one type, [`GridGeometry`].
//!
//! What the simulator calls:
//! - grid -> contact: [`sample_bilinear`]`(&grid.header, grid.channel_data(c), x, y)`;
//! - contacts -> grid (e.g. a `copy-grid` model sending the exact solution through the grid and
//!   back): build a [`Transfer`] once per scene with [`GridGeometry::from_bounds`], then per step
//!   [`Transfer::contacts_grid`]; or the one-shot [`contacts_to_grid`].
//!
//! The library depends on `msgs`, `kiddo` and `thiserror` only; the `dc-sph` binary (node, bench)
//! sits behind the default `node` feature.

mod error;
pub mod geometry;
pub mod kernel;
pub mod mode;
pub mod pairing;
pub mod particles;
mod scatter;
pub mod synth;
pub mod transfer;

pub use error::{Source, SphError};
pub use geometry::{Bounds, GridGeometry};
pub use kernel::{Kernel, KernelKind};
pub use mode::Mode;
pub use pairing::StepPairer;
pub use particles::{ParticleSet, BODY_CHANNELS, CONTACT_CHANNELS, TEMPORAL_CHANNELS, WEIGHT_CHANNEL};
pub use synth::SplitMix64;
pub use transfer::{sample_bilinear, Search, SplatReport, Transfer, TransferConfig};

use msgs::{Body, Contact, Grid, StepHeader};

impl Transfer {
    /// The contact impulse grid of one step: channels `normal`, `tangent` (and `weight` when
    /// configured), the grid the simulator's `grid` model samples.
    pub fn contacts_grid(&mut self, step: StepHeader, contacts: &[Contact]) -> Result<(Grid, SplatReport), SphError> {
        self.splat_grid(step, &ParticleSet::from_contacts(contacts)?)
    }

    /// The bodies grid of one step: `vx, vy, omega, mass, inertia`, then with `temporal` the
    /// step's contact impulses as `prev_normal, prev_tangent` (the 7-channel input: the U-Net sees
    /// bodies(k) and impulses(k) and predicts the impulses of step k+1, so "previous" is relative to
    /// the prediction, and a simulation's first step never borrows another simulation's impulses),
    /// then `weight` when configured (the bodies' weight).
    pub fn bodies_grid(
        &mut self,
        step: StepHeader,
        bodies: &[Body],
        temporal: Option<&[Contact]>,
    ) -> Result<(Grid, SplatReport), SphError> {
        let body_set = ParticleSet::from_bodies(bodies)?;
        let Some(contacts) = temporal else {
            return self.splat_grid(step, &body_set);
        };
        let contact_set = ParticleSet::from_contacts(contacts)?;
        let mut names = body_set.channels();
        names.extend(TEMPORAL_CHANNELS);
        if self.config().weight_channel {
            names.push(WEIGHT_CHANNEL);
        }
        let header = self.geometry().header(step, &names)?;
        let nodes = self.geometry().nodes();
        let mut grid = Grid::new(header, vec![0.0; header.len()]);
        let body_len = self.output_len(BODY_CHANNELS.len());
        let mut contact_part = vec![0.0; self.output_len(CONTACT_CHANNELS.len())];
        let report = self.splat(&body_set, &mut grid.items[..body_len])?;
        if self.config().weight_channel {
            // The bodies' weight channel sits where prev_normal goes; move it to the end.
            let (head, tail) = grid.items.split_at_mut(body_len);
            tail[nodes..].copy_from_slice(&head[body_len - nodes..]);
        }
        self.splat(&contact_set, &mut contact_part)?;
        let start = BODY_CHANNELS.len() * nodes;
        grid.items[start..start + 2 * nodes].copy_from_slice(&contact_part[..2 * nodes]);
        Ok((grid, report))
    }
}

/// One-shot contacts -> impulse grid over `bounds` (builds a [`Transfer`]; a caller doing this
/// every step should keep one [`Transfer`] and call [`Transfer::contacts_grid`]).
pub fn contacts_to_grid(
    step: StepHeader,
    contacts: &[Contact],
    config: TransferConfig,
    bounds: Bounds,
    spacing: f32,
) -> Result<(Grid, SplatReport), SphError> {
    let geometry = GridGeometry::from_bounds(bounds, spacing, 1)?;
    Transfer::new(config, geometry)?.contacts_grid(step, contacts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::Shape;

    #[test]
    fn contact_impulses_survive_the_grid_round_trip_in_preserving_mode() {
        // The copy-grid model: exact solution -> grid -> sampled at the contacts.
        let contacts = [
            Contact {
                body_a: 1,
                body_b: 2,
                x: 3.0,
                y: 0.0,
                normal_impulse: 0.8,
                tangent_impulse: -0.1,
                ..Default::default()
            },
            Contact {
                body_a: 2,
                body_b: 3,
                x: 9.2,
                y: 4.4,
                normal_impulse: 0.3,
                tangent_impulse: 0.05,
                ..Default::default()
            },
        ];
        let (grid, report) =
            contacts_to_grid(StepHeader::default(), &contacts, TransferConfig::default(), Bounds::THESIS_BOX, 0.125)
                .unwrap();
        assert_eq!(report.outside, 0);
        let (n, t) = (grid.header.channel("normal").unwrap(), grid.header.channel("tangent").unwrap());
        for c in &contacts {
            let sn = sample_bilinear(&grid.header, grid.channel_data(n), c.x, c.y);
            let st = sample_bilinear(&grid.header, grid.channel_data(t), c.x, c.y);
            assert!((sn - c.normal_impulse).abs() < 1e-5 && (st - c.tangent_impulse).abs() < 1e-5, "{sn} {st}");
        }
    }

    #[test]
    fn temporal_bodies_grid_has_seven_channels_then_weight() {
        let geometry = GridGeometry::from_bounds(Bounds::new([0.0, 0.0], [4.0, 4.0]).unwrap(), 0.25, 1).unwrap();
        let cfg = TransferConfig { weight_channel: true, ..Default::default() };
        let mut t = Transfer::new(cfg, geometry).unwrap();
        let bodies =
            [Body { id: 0, shape: Shape::Ball as u32, x: 1.0, y: 1.0, vx: 2.0, mass: 3.0, ..Default::default() }];
        let contacts = [Contact { x: 3.0, y: 3.0, normal_impulse: 5.0, ..Default::default() }];
        let (grid, _) = t.bodies_grid(StepHeader::default(), &bodies, Some(&contacts)).unwrap();
        let names: Vec<&str> = (0..grid.header.channels as usize).map(|c| grid.header.channel_name(c)).collect();
        assert_eq!(names, ["vx", "vy", "omega", "mass", "inertia", "prev_normal", "prev_tangent", "weight"]);
        let at_body = geometry.node_index(4, 4);
        let at_contact = geometry.node_index(12, 12);
        assert!((grid.channel_data(0)[at_body] - 2.0).abs() < 1e-6);
        assert!((grid.channel_data(5)[at_contact] - 5.0).abs() < 1e-6);
        assert_eq!(grid.channel_data(5)[at_body], 0.0);
        // The weight channel is the bodies' (non-zero at the body, zero at the lone contact).
        assert!(grid.channel_data(7)[at_body] > 0.0);
        assert_eq!(grid.channel_data(7)[at_contact], 0.0);
    }
}
