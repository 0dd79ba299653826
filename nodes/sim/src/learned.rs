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
