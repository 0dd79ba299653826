//! The product's warm starts: what a simulator user runs. `none` (a [`Constant`]) and `builtin` (the
//! simulator's own temporal warm start), the grid-based models fed by another node (`grid`,
//! `unet`, `unet-delta`), and the contact-graph network in process (`gnn`), served by a node
//! (`gnn-node`) or served one step ahead (`gnn-pipelined`).

use crate::problem::Problem;
use crate::solver::rows::Impulse;
use crate::warm::model::{
    step_problem, ContactWarmSource, GridSource, Needs, SolvedStep, Unavailable, WarmStartInput, WarmStartModel,
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

/// `gnn-every:N`: the network amortised over N steps. On the step it runs, its warm start is
/// `gnn`'s, and it keeps its correction to builtin (prediction minus builtin's start) per contact;
/// on the N-1 steps after, builtin's start plus that correction on the contacts that persist (new
/// ones get builtin's). Between inferences the step's problem is not even captured: the warm start
/// costs builtin's plus one merge, so the network's time is paid once every N steps.
pub struct GnnEveryModel {
    name: String,
    network: GnnModel,
    every: u32,
    /// Steps until the network runs again (0: this step).
    due_in: u32,
    /// The last inference's correction per contact, sorted by key (the step's contacts are).
    correction: Vec<(crate::contact::ContactKey, Impulse)>,
}

impl GnnEveryModel {
    /// The network `net` every `every`-th step (at least 1: every step, `gnn` itself).
    pub fn new(name: String, net: gnn::net::Net, every: u32) -> GnnEveryModel {
        GnnEveryModel { name, network: GnnModel::new(net), every: every.max(1), due_in: 0, correction: Vec::new() }
    }
}

impl WarmStartModel for GnnEveryModel {
    fn name(&self) -> &str {
        &self.name
    }

    fn begin_simulation(&mut self, _simulation: u32, _seed: u64) {
        self.due_in = 0;
        self.correction.clear();
    }

    fn needs(&self) -> Needs {
        if self.due_in == 0 {
            Needs::PROBLEM
        } else {
            Needs::default()
        }
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        if self.due_in == 0 {
            self.network.warm_start(input, out)?;
            self.due_in = self.every - 1;
            self.correction.clear();
            // The captured problem carries builtin's start (`previous`, 0 on new contacts).
            let problem = step_problem(input)?;
            for ((c, o), p) in input.contacts.iter().zip(out.iter()).zip(&problem.contacts) {
                let d = Impulse { normal: o.normal - p.previous[0], tangent: o.tangent - p.previous[1] };
                self.correction.push((c.key, d));
            }
            return Ok(());
        }
        self.due_in -= 1;
        // Both lists sorted by key: one merge.
        let mut kept = self.correction.iter().peekable();
        let previous = input.history.previous_each(input.contacts.iter().map(|c| &c.key));
        for ((c, o), previous) in input.contacts.iter().zip(out.iter_mut()).zip(previous) {
            while kept.next_if(|(k, _)| *k < c.key).is_some() {}
            let correction = kept.next_if(|(k, _)| *k == c.key).map(|(_, d)| *d);
            *o = match (previous, correction) {
                (Some(p), Some(d)) => Impulse { normal: p.normal + d.normal, tangent: p.tangent + d.tangent },
                (previous, _) => previous.unwrap_or_default(),
            };
        }
        Ok(())
    }
}

/// Sends a step's problem to the node that serves warm starts.
pub type ProblemSender = Box<dyn FnMut(&Problem) -> Result<(), String>>;

/// `gnn-node`: the same network served by a `dc-gnn` node: the step's problem goes out on
/// `problem/*`, the per-contact warm start comes back on `warm/gnn` (matched by contact key); late,
/// missing or from a node that is down, the step falls back (counted) like the grid models.
///
/// An external model (`external:NAME`) is the same exchange with any process on
/// `warm/external`, under the user's name.
pub struct GnnNodeModel {
    name: String,
    send: ProblemSender,
    source: Box<dyn ContactWarmSource>,
}

impl GnnNodeModel {
    pub fn new(send: ProblemSender, source: Box<dyn ContactWarmSource>) -> GnnNodeModel {
        GnnNodeModel::named("gnn-node".into(), send, source)
    }

    /// The exchange under another name (an external model's).
    pub fn named(name: String, send: ProblemSender, source: Box<dyn ContactWarmSource>) -> GnnNodeModel {
        GnnNodeModel { name, send, source }
    }
}

impl WarmStartModel for GnnNodeModel {
    fn name(&self) -> &str {
        &self.name
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

/// `gnn-pipelined`: the network served by a `dc-gnn` node one step ahead, off the simulator's
/// critical path. Once step t is done, its problem carried one step on goes out
/// ([`carry_one_step`]); the node predicts step t+1's warm start from it while the simulator
/// records step t and detects step t+1's contacts. At step t+1 the prediction is matched to the new contacts by key; a contact
/// it lacks (new at t+1) gets builtin's start. Late, missing or from a node that is down, the
/// step falls back (counted). A simulation's first step, for which nothing was asked, is
/// builtin's.
pub struct GnnPipelinedModel {
    send: ProblemSender,
    source: Box<dyn ContactWarmSource>,
    /// The problem carried one step on (buffers reused).
    ahead: Problem,
    /// The step a prediction was asked for, or why asking failed.
    asked: Option<Result<(u64, u32, u32), String>>,
}

impl GnnPipelinedModel {
    pub fn new(send: ProblemSender, source: Box<dyn ContactWarmSource>) -> GnnPipelinedModel {
        let ahead = Problem { header: Default::default(), bodies: Vec::new(), contacts: Vec::new() };
        GnnPipelinedModel { send, source, ahead, asked: None }
    }
}

/// Step t's problem as step t+1's is expected to look, into `ahead`: the solved impulses as
/// the previous ones (each contact one step older), the bodies' velocities after the step plus
/// gravity's, and each contact's normal, arms, depth and height re-measured at the poses the
/// position pass left. Contacts that t+1 will add or lose are not known yet.
pub fn carry_one_step(done: &SolvedStep<'_>, problem: &Problem, ahead: &mut Problem) {
    ahead.header = problem.header;
    ahead.header.step.step = problem.header.step.step + 1;
    ahead.bodies.clear();
    ahead.bodies.extend(problem.bodies.iter().zip(done.bodies).map(|(p, b)| {
        // External forces act on dynamic bodies only (the ones with mass to move).
        let g = if p.inv_mass > 0.0 { done.gravity_dt } else { [0.0, 0.0] };
        msgs::ProblemBody { v: [b.v.x + g[0], b.v.y + g[1]], w: b.w, ..*p }
    }));
    ahead.contacts.clear();
    let measured = done.geometry.len() == problem.contacts.len();
    for (k, (c, i)) in problem.contacts.iter().zip(done.impulses).enumerate() {
        let mut next = msgs::ProblemContact {
            age: c.age + 1,
            previous: [i.normal, i.tangent],
            before_previous: c.previous,
            reference: [f32::NAN; 2],
            ..*c
        };
        if measured {
            let (n, point, separation) = crate::solver::measure(&done.geometry[k], done.poses);
            let (a, b) = (done.poses[c.body_a as usize].x, done.poses[c.body_b as usize].x);
            next.normal = n.into();
            next.ra = (point - a).into();
            next.rb = (point - b).into();
            next.penetration = -separation;
            next.height = point.y;
        }
        ahead.contacts.push(next);
    }
}

impl WarmStartModel for GnnPipelinedModel {
    fn name(&self) -> &str {
        "gnn-pipelined"
    }

    fn needs(&self) -> Needs {
        Needs::PROBLEM
    }

    fn begin_simulation(&mut self, _simulation: u32, _seed: u64) {
        self.asked = None;
    }

    fn warm_start(&mut self, input: &WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        // Builtin's start under whatever the prediction covers.
        input.history.fill_previous(input.contacts, out);
        match self.asked.take() {
            Some(Ok(asked)) if asked == (input.run_id, input.simulation, input.step) => {}
            Some(Err(why)) => return Err(Unavailable(format!("sending step {} ahead: {why}", input.step - 1))),
            // Nothing asked for this step (a simulation's first): builtin's, not a fallback.
            _ => return Ok(()),
        }
        let reply = self
            .source
            .warm(input.run_id, input.simulation, input.step)
            .ok_or_else(|| Unavailable(format!("no prediction for step {} in time", input.step)))?;
        let key =
            |r: &msgs::Contact| crate::contact::ContactKey { body_a: r.body_a, body_b: r.body_b, feature: r.feature };
        // Both lists are sorted by key (the world sorts its contacts; the node answers in the
        // problem's order): one merge.
        if !reply.items.is_sorted_by_key(key) {
            return Err(Unavailable(format!("the prediction for step {} is not in contact order", input.step)));
        }
        let mut predicted = reply.items.iter().peekable();
        for (c, o) in input.contacts.iter().zip(out.iter_mut()) {
            while predicted.next_if(|r| key(r) < c.key).is_some() {}
            if let Some(r) = predicted.next_if(|r| key(r) == c.key) {
                *o = Impulse { normal: r.normal_impulse, tangent: r.tangent_impulse };
            }
        }
        Ok(())
    }

    fn after_step(&mut self, done: &SolvedStep<'_>) {
        let Some(problem) = done.problem else { return };
        carry_one_step(done, problem, &mut self.ahead);
        self.asked = Some((self.send)(&self.ahead).map(|()| (done.run_id, done.simulation, done.step + 1)));
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
