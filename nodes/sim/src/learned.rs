//! Learned warm starts that run inside the simulator: the contact-graph network (`gnn`), fed the
//! step's velocity problem as the world captured it.

use crate::solver::Impulse;
use crate::warm::{Unavailable, WarmStartInput, WarmStartModel};

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

    fn wants_problem(&self) -> bool {
        true
    }

    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let Some(problem) = input.problem else {
            return Err(Unavailable("the world did not capture the step's problem".into()));
        };
        self.out.clear();
        self.out.resize(problem.contacts.len(), [0.0; 2]);
        self.predictor.warm_start(&problem.bodies, &problem.contacts, &mut self.out);
        for (o, p) in out.iter_mut().zip(&self.out) {
            *o = Impulse { normal: p[0], tangent: p[1] };
        }
        Ok(())
    }
}

/// Sends a step's problem to the node that serves warm starts.
pub type ProblemSender = Box<dyn FnMut(&crate::problem::Problem) -> Result<(), String>>;

/// `gnn-node`: the same network served by a `dc-gnn` node: the step's problem goes out on
/// `problem/*`, the per-contact warm start comes back on `warm/gnn` (matched by contact key); late,
/// missing or from a node that is down, the step falls back (counted) like the grid models.
pub struct GnnNodeModel {
    send: ProblemSender,
    source: Box<dyn crate::warm::ContactWarmSource>,
}

impl GnnNodeModel {
    pub fn new(send: ProblemSender, source: Box<dyn crate::warm::ContactWarmSource>) -> GnnNodeModel {
        GnnNodeModel { send, source }
    }
}

impl WarmStartModel for GnnNodeModel {
    fn name(&self) -> &str {
        "gnn-node"
    }

    fn wants_problem(&self) -> bool {
        true
    }

    fn warm_start(&mut self, input: &mut WarmStartInput<'_>, out: &mut [Impulse]) -> Result<(), Unavailable> {
        let Some(problem) = input.problem else {
            return Err(Unavailable("the world did not capture the step's problem".into()));
        };
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
