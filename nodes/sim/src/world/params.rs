//! The world's stepping parameters and their checks.

use crate::error::SimError;
use crate::solver::{PositionParams, SolveParams};

/// Parameters of the time stepping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldParams {
    /// Time step, seconds.
    pub dt: f32,
    /// Gravity.
    pub gravity: [f32; 2],
    /// Velocity solve stopping rule.
    pub solve: SolveParams,
    /// The oracle's stopping rule (`copy` and the ablations): solved from builtin's warm start to
    /// a tolerance far below the run's, so that `copy` needs ~0 sweeps. 2e-6, not lower: the
    /// impulses are f32, and a sweep's change stalls near their resolution on deep piles.
    pub oracle: SolveParams,
    /// Position pass parameters.
    pub position: PositionParams,
    /// rapier's prediction distance: manifolds are kept this far apart, so features are tracked
    /// while contacts open and close.
    pub prediction: f32,
    /// A manifold point becomes a contact row when its signed distance is at most this (0: touching
    /// or overlapping, as Box2D's discs; a positive margin would stop bodies short of touching).
    pub contact_margin: f32,
    /// Largest translation of a body in one step (`b2_maxTranslation`).
    pub max_translation: f32,
    /// Largest rotation of a body in one step (`b2_maxRotation`).
    pub max_rotation: f32,
}

impl Default for WorldParams {
    fn default() -> Self {
        WorldParams {
            dt: 1.0 / 100.0,
            gravity: [0.0, -9.81],
            solve: SolveParams::default(),
            oracle: SolveParams { tolerance: 2e-6, max_sweeps: 10_000, ..SolveParams::default() },
            position: PositionParams::default(),
            prediction: 0.02,
            contact_margin: 0.0,
            max_translation: 2.0,
            max_rotation: 0.5 * std::f32::consts::PI,
        }
    }
}

impl WorldParams {
    /// The default parameters with the recommended solver and rule ([`SolveParams::recommended`])
    /// for the run; the oracle keeps the change rule (see `dc-sim --oracle-tolerance`).
    pub fn recommended() -> WorldParams {
        let solve = SolveParams::recommended();
        let oracle = WorldParams::default().oracle.with_setting(solve.setting());
        WorldParams { solve, oracle, ..WorldParams::default() }
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad =
            |name, value: String, why: &str| Err(SimError::InvalidParameter { name, value, why: why.to_string() });
        if !(self.solve.tolerance.is_finite() && self.solve.tolerance > 0.0) {
            return bad("tolerance", self.solve.tolerance.to_string(), "must be > 0");
        }
        if self.solve.max_sweeps == 0 {
            return bad("max-sweeps", "0".into(), "must be >= 1");
        }
        for c in [self.solve.compliance, self.oracle.compliance] {
            if !SolveParams::valid_compliance(c) {
                return bad("compliance", c.to_string(), &format!("must be {}", SolveParams::compliance_range()));
            }
        }
        for w in [self.solve.relaxation, self.oracle.relaxation] {
            if !SolveParams::valid_relaxation(w) {
                return bad("relaxation", w.to_string(), &format!("must be {}", SolveParams::relaxation_range()));
            }
        }
        for p in [self.solve, self.oracle] {
            if !p.setting().is_valid() {
                return bad("solver", p.setting().to_string(), crate::solver::SolverSetting::SPELLING);
            }
        }
        if !(self.oracle.tolerance.is_finite() && self.oracle.tolerance > 0.0) || self.oracle.max_sweeps == 0 {
            return bad("oracle", format!("{:?}", self.oracle), "tolerance > 0 and max sweeps >= 1");
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return bad("dt", self.dt.to_string(), "must be > 0");
        }
        let slop = self.position.slop;
        if !(slop.is_finite() && slop >= 0.0 && self.position.baumgarte >= 0.0 && self.position.baumgarte <= 1.0) {
            return bad("baumgarte/slop", format!("{:?}", self.position), "baumgarte in [0, 1], slop finite and >= 0");
        }
        Ok(())
    }
}
