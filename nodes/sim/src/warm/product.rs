//! The product's warm starts: what a simulator user runs. `none` (a [`Constant`]) and `builtin` (the
//! simulator's own temporal warm start), the grid-based models fed by another node (`grid`,
//! `unet`, `unet-delta`), and the contact-graph network in process (`gnn`) or served by a node
//! (`gnn-node`).

use crate::problem::Problem;
use crate::solver::rows::Impulse;
use crate::warm::model::{
    step_problem, ContactWarmSource, GridSource, Needs, Unavailable, WarmStartInput, WarmStartModel,
};
use sph::sample_bilinear;

/// A constant start: `none` (zero, the cold start), and the evaluation's `bad` (50 everywhere).
#[derive(Debug, Clone, Copy)]
pub struct Constant {
    name: &'static str,
    value: Impulse,
}

impl Constant {
    /// `none`: start from zero.
    pub fn zero() -> Constant {
        Constant { name: "none", value: Impulse::default() }
    }
    /// `name`: every contact starts at `value`.
    pub fn new(name: &'static str, value: Impulse) -> Constant {
        Constant { name, value }
    }
}

impl WarmStartModel for Constant {
    fn name(&self) -> &str {
        self.name
    }
    fn warm_start(&mut self, _: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        out.fill(self.value);
        Ok(())
    }
}

/// `builtin`: the previous step's impulse of the same contact (temporal coherence), 0 for new ones.
#[derive(Debug, Default)]
pub struct Builtin;

impl WarmStartModel for Builtin {
    fn name(&self) -> &str {
        "builtin"
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        input.history.fill_previous(input.contacts, out);
        Ok(())
    }
}

/// `grid` / `unet`: the previous step's impulse grid (channels "normal" and "tangent"), sampled
/// bilinearly at the new contact points. `unet-delta` (the U-Net's fair second chance): builtin's
/// own impulse on persisting contacts plus the grid's predicted change there (channels
/// "d_normal", "d_tangent"), the grid's value on new contacts.
pub struct GridModel {
    name: &'static str,
    source: Box<dyn GridSource>,
    delta: bool,
}

impl GridModel {
    /// A grid-based model called `name` fed by `source`.
    pub fn new(name: &'static str, source: Box<dyn GridSource>) -> GridModel {
        GridModel { name, source, delta: false }
    }

    /// Builtin plus the grid's predicted change on persisting contacts.
    pub fn delta(name: &'static str, source: Box<dyn GridSource>) -> GridModel {
        GridModel { name, source, delta: true }
    }
}

impl WarmStartModel for GridModel {
    fn name(&self) -> &str {
        self.name
    }
    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        if input.step == 0 {
            // No previous step exists, hence no grid: zero is the model's own answer here.
            out.fill(Impulse::default());
            return Ok(());
        }
        // Always fetch, even without contacts: in lockstep the producer waits for us to consume.
        let grid = self
            .source
            .grid(input.run_id, input.simulation, input.step - 1)
            .ok_or_else(|| Unavailable(format!("no grid for step {} in time", input.step - 1)))?;
        let (Some(cn), Some(ct)) = (grid.header.channel("normal"), grid.header.channel("tangent")) else {
            return Err(Unavailable("grid lacks a `normal` or `tangent` channel".into()));
        };
        if grid.items.len() < grid.header.len() {
            return Err(Unavailable("grid holds fewer values than its header announces".into()));
        }
        let (normal, tangent) = (grid.channel_data(cn), grid.channel_data(ct));
        let change = match (self.delta, grid.header.channel("d_normal"), grid.header.channel("d_tangent")) {
            (false, _, _) => None,
            (true, Some(dn), Some(dt)) => Some((grid.channel_data(dn), grid.channel_data(dt))),
            (true, _, _) => {
                return Err(Unavailable("grid lacks `d_normal` / `d_tangent` (a temporal U-Net makes them)".into()))
            }
        };
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            let sample = |field: &[f32]| sample_bilinear(&grid.header, field, c.point.x, c.point.y);
            *o = match (change, input.history.previous(&c.key)) {
                (Some((dn, dt)), Some(before)) => {
                    Impulse { normal: before.normal + sample(dn), tangent: before.tangent + sample(dt) }
                }
                _ => Impulse { normal: sample(normal), tangent: sample(tangent) },
            };
        }
        Ok(())
    }
}

/// `gnn`: builtin plus the network's per-contact correction (see the `gnn` crate).
pub struct GnnModel {
    predictor: gnn::Predictor,
    out: Vec<[f32; 2]>,
}

impl GnnModel {
    pub fn new(net: gnn::net::Net) -> GnnModel {
        GnnModel { predictor: gnn::Predictor::new(net), out: Vec::new() }
    }
}

impl WarmStartModel for GnnModel {
    fn name(&self) -> &str {
        "gnn"
    }

    fn needs(&self) -> Needs {
        Needs::PROBLEM
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let problem = step_problem(input)?;
        self.out.clear();
        self.out.resize(problem.contacts.len(), [0.0; 2]);
        self.predictor
            .warm_start(&problem.bodies, &problem.contacts, &mut self.out)
            .map_err(|e| Unavailable(e.to_string()))?;
        for (o, p) in out.iter_mut().zip(&self.out) {
            *o = Impulse { normal: p[0], tangent: p[1] };
        }
        Ok(())
    }
}

/// Sends a step's problem to the node that serves warm starts.
pub type ProblemSender = Box<dyn FnMut(&Problem) -> Result<(), String>>;

/// `gnn-node`: the same network served by a `dc-gnn` node: the step's problem goes out on
/// `problem/*`, the per-contact warm start comes back on `warm/gnn` (matched by contact key); late,
/// missing or from a node that is down, the step falls back (counted) like the grid models.
pub struct GnnNodeModel {
    send: ProblemSender,
    source: Box<dyn ContactWarmSource>,
}

impl GnnNodeModel {
    pub fn new(send: ProblemSender, source: Box<dyn ContactWarmSource>) -> GnnNodeModel {
        GnnNodeModel { send, source }
    }
}

impl WarmStartModel for GnnNodeModel {
    fn name(&self) -> &str {
        "gnn-node"
    }

    fn needs(&self) -> Needs {
        Needs::PROBLEM
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let problem = step_problem(input)?;
        (self.send)(problem).map_err(|e| Unavailable(format!("sending the problem: {e}")))?;
        let reply = self
            .source
            .warm(input.run_id, input.simulation, input.step)
            .ok_or_else(|| Unavailable(format!("no warm start for step {} in time", input.step)))?;
        if reply.items.len() != input.contacts.len() {
            return Err(Unavailable(format!(
                "warm start of {} contacts for a step with {}",
                reply.items.len(),
                input.contacts.len()
            )));
        }
        for ((c, r), o) in input.contacts.iter().zip(&reply.items).zip(out.iter_mut()) {
            if (r.body_a, r.body_b, r.feature) != (c.key.body_a, c.key.body_b, c.key.feature) {
                return Err(Unavailable(format!(
                    "warm start for contact {:?} came as ({}, {}, {})",
                    c.key, r.body_a, r.body_b, r.feature
                )));
            }
            *o = Impulse { normal: r.normal_impulse, tangent: r.tangent_impulse };
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::ImpulseHistory;
    use crate::warm::model::harness::{floor_contact, guess};

    fn point(body_b: u32) -> crate::contact::ContactPoint {
        floor_contact(body_b, 0, 0.0)
    }

    #[test]
    fn unet_delta_adds_the_predicted_change_to_builtin_on_persisting_contacts_only() {
        let imp = |n: f32, t: f32| Impulse { normal: n, tangent: t };
        let mut history = ImpulseHistory::default();
        history.push([point(1).key].into_iter(), &[imp(1.0, 0.1)], ImpulseHistory::no_trail());
        // A uniform grid: value (2, 0.2), change (0.5, -0.05), over the contacts at the origin.
        let source = |_: u64, _: u32, step: u32| {
            let mut g = msgs::Grid::zeros(
                msgs::StepHeader { run_id: 0, simulation: 0, step },
                [-1.0, -1.0],
                1.0,
                3,
                3,
                &["normal", "tangent", "d_normal", "d_tangent"],
            );
            for (c, v) in [2.0, 0.2, 0.5, -0.05].into_iter().enumerate() {
                g.items[c * 9..(c + 1) * 9].fill(v);
            }
            Some(g)
        };
        let contacts = [point(1), point(2)];
        let mut delta = GridModel::delta("unet-delta", Box::new(source));
        let g = guess(&mut delta, &contacts, &history);
        assert!((g[0].normal - 1.5).abs() < 1e-6 && (g[0].tangent - 0.05).abs() < 1e-6, "builtin + change: {g:?}");
        assert!((g[1].normal - 2.0).abs() < 1e-6 && (g[1].tangent - 0.2).abs() < 1e-6, "a new contact: the value");
        // The plain model overwrites every contact with the grid's value.
        let g = guess(&mut GridModel::new("unet", Box::new(source)), &contacts, &history);
        assert!((g[0].normal - 2.0).abs() < 1e-6, "{g:?}");
    }
}
