//! The common start of the probes that correct builtin by the step's own linear problem
//! (`subspace`, `coarse`, `cg`): builtin's guess projected onto the friction cone, its active set,
//! and what the step still asks of it there (with the solver's compliance).

use crate::solver::rows::{apply, relative, row_masses, ContactRow, Impulse, SolverBody};
use crate::warm::model::{StepRows, WarmStartInput};

/// builtin's guess for a Galerkin correction to start from: its active set and the solver's
/// per-row compliance (`None`: rigid).
pub(crate) struct BuiltinStep<'a> {
    /// The step's rows and bodies the correction is solved on.
    pub rows: &'a [ContactRow],
    pub bodies: &'a [SolverBody],
    /// Per row `[normal closed, tangent sticking]` at builtin's projected guess.
    pub active: Vec<[bool; 2]>,
    pub compliance: Option<Vec<[f64; 2]>>,
}

/// Writes builtin's guess into `out`, projected onto the friction cone, and into `residual` what
/// the step's own problem (with its compliance) still asks on the guess's active rows; `None`,
/// with builtin's guess as it is, when the input carries no solver rows.
pub(crate) fn builtin_step<'a>(
    input: &WarmStartInput<'a>,
    out: &mut [Impulse],
    velocities: &mut Vec<[f64; 3]>,
    residual: &mut Vec<[f64; 2]>,
) -> Option<BuiltinStep<'a>> {
    input.history.fill_previous(input.contacts, out);
    let step = input.rows?;
    let StepRows { rows, bodies, compliance: gamma } = step;
    if rows.len() != out.len() || rows.is_empty() {
        return None;
    }
    let active = project_to_cone(rows, out);
    step_residual(bodies, rows, out, &active, velocities, residual);
    let compliance = row_compliance(rows, bodies, gamma);
    if let Some(c) = &compliance {
        add_compliance_residual(c, out, &active, residual);
    }
    Some(BuiltinStep { rows, bodies, active, compliance })
}

/// Projects a guess onto the friction cone as the solver will, and says which rows are active
/// there: `[normal closed, tangent sticking]`. A Galerkin correction moves only active rows.
pub(crate) fn project_to_cone(rows: &[ContactRow], out: &mut [Impulse]) -> Vec<[bool; 2]> {
    rows.iter()
        .zip(out.iter_mut())
        .map(|(row, o)| {
            o.normal = o.normal.max(0.0);
            let t_max = row.friction * o.normal;
            o.tangent = o.tangent.clamp(-t_max, t_max);
            let closed = o.normal > 0.0;
            [closed, closed && o.tangent.abs() < 0.999 * row.friction * o.normal]
        })
        .collect()
}

/// What the step's problem still asks after the guess `out`: minus the relative velocity of the
/// active rows (0 on the others). `velocities` is scratch.
pub(crate) fn step_residual(
    bodies: &[SolverBody],
    rows: &[ContactRow],
    out: &[Impulse],
    active: &[[bool; 2]],
    velocities: &mut Vec<[f64; 3]>,
    residual: &mut Vec<[f64; 2]>,
) {
    velocities.clear();
    velocities.extend(bodies.iter().map(|b| [b.v.x as f64, b.v.y as f64, b.w as f64]));
    for (row, o) in rows.iter().zip(out.iter()) {
        apply(velocities, bodies, row, [o.normal as f64, o.tangent as f64]);
    }
    residual.clear();
    residual.extend(rows.iter().zip(active).map(|(row, act)| {
        let [vn, vt] = relative(velocities, row);
        [if act[0] { -vn } else { 0.0 }, if act[1] { -vt } else { 0.0 }]
    }));
}

/// Per row the compliance term `[C_nn, C_tt]` of the solver (`gamma W_ii`: the row asks
/// `u + C lambda = 0`), or `None` for rigid contacts.
fn row_compliance(rows: &[ContactRow], bodies: &[SolverBody], gamma: f32) -> Option<Vec<[f64; 2]>> {
    (gamma > 0.0).then(|| {
        rows.iter()
            .map(|row| {
                let (mn, mt) = row_masses(row, bodies);
                let c = |m: f32| if m > 0.0 { gamma as f64 / m as f64 } else { 0.0 };
                [c(mn), c(mt)]
            })
            .collect()
    })
}

/// With compliance, the step still asks `-C lambda` of the guess's active rows.
fn add_compliance_residual(compliance: &[[f64; 2]], out: &[Impulse], active: &[[bool; 2]], residual: &mut [[f64; 2]]) {
    for (((c, o), act), r) in compliance.iter().zip(out).zip(active).zip(residual.iter_mut()) {
        if act[0] {
            r[0] -= c[0] * o.normal as f64;
        }
        if act[1] {
            r[1] -= c[1] * o.tangent as f64;
        }
    }
}
