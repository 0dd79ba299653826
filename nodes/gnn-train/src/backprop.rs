//! End-to-end training of the contact-graph network (burn, autodiff) on the step's own
//! velocity-level complementarity residual at the prediction, the null-space-invariant loss of
//! issue #13 (after Servin et al.'s GNN solver): with `lambda = builtin + correction` and `v` the
//! velocities after applying it,
//!
//! - every contact's normal pair must be complementary: `x = lambda_n / m_n >= 0`, `v_n >= 0`,
//!   `x v_n = 0`, measured by the Fischer-Burmeister function `x + v_n - sqrt(x^2 + v_n^2)`;
//! - a contact the reference solution holds sticking must not slide: `v_t = 0`.
//!
//! No particular solution is asked for: any warm start in the problem's null space scores the
//! same. Each step weighs by builtin's sweeps on it.

use crate::twin::{GnnNet, GraphInput};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, IndexingUpdateOp, Tensor, TensorData};
use gnn::features;
use gnn::net::Net;

/// What the loss needs of one step besides the graph.
pub struct StepData {
    contact_features: Vec<f32>,
    body_features: Vec<f32>,
    pairs: Vec<(u32, u32)>,
    /// Per contact: normal (2), ra (2), rb (2), masses (2), previous in velocity units (2),
    /// velocity after builtin (2), sticking (1), the reference in velocity units (2).
    per_contact: Vec<f32>,
    /// Per body: inverse mass, inverse mass, inverse inertia.
    per_body: Vec<f32>,
    weight: f32,
    /// The problem's relative compliance (0: rigid): a row then asks `v + gamma lambda / m = 0`.
    compliance: f32,
    /// The step's problem for the solver in the loop (an index into the training problems).
    pub problem: usize,
}

const PER_CONTACT: usize = 15;

impl StepData {
    pub fn new(problem: &sim::problem::Problem, index: usize, weight: f32) -> Option<StepData> {
        let (mut xc, mut xb, mut masses) = (Vec::new(), Vec::new(), Vec::new());
        features::features(&problem.bodies, &problem.contacts, &mut xc, &mut xb, &mut masses);
        if problem.contacts.is_empty() {
            return None;
        }
        let mut per_contact = Vec::with_capacity(problem.contacts.len() * PER_CONTACT);
        for ((c, k), x) in problem.contacts.iter().zip(&masses).zip(xc.chunks_exact(features::CONTACT_FEATURES)) {
            let [rn, rt] = c.reference;
            let sticking = rn > 1e-6 && rt.abs() < 0.999 * c.friction * rn;
            per_contact.extend_from_slice(&[
                c.normal[0],
                c.normal[1],
                c.ra[0],
                c.ra[1],
                c.rb[0],
                c.rb[1],
                k[0],
                k[1],
                x[0],
                x[1],
                x[9],
                x[10],
                sticking as u32 as f32,
                if k[0] > 0.0 { rn / k[0] } else { 0.0 },
                if k[1] > 0.0 { rt / k[1] } else { 0.0 },
            ]);
        }
        let per_body = problem.bodies.iter().flat_map(|b| [b.inv_mass, b.inv_mass, b.inv_inertia]).collect();
        let pairs = problem.contacts.iter().map(|c| (c.body_a, c.body_b)).collect();
        let compliance = problem.header.compliance;
        Some(StepData {
            contact_features: xc,
            body_features: xb,
            pairs,
            per_contact,
            per_body,
            weight,
            compliance,
            problem: index,
        })
    }
}

fn column(t: &Tensor<2>, i: usize) -> Tensor<2> {
    let [n, _] = t.dims();
    t.clone().slice([0..n, i..i + 1])
}

/// The weighted residual loss of one step.
pub fn loss(model: &GnnNet, step: &StepData, device: &Device) -> Tensor<1> {
    let graph = GraphInput::new(&step.contact_features, &step.body_features, &step.pairs, device);
    let out = model.forward(&graph);
    let nc = step.pairs.len();
    let nb = step.per_body.len() / 3;
    let c = Tensor::<2>::from_data(TensorData::new(step.per_contact.clone(), [nc, PER_CONTACT]), device);
    let inv = Tensor::<2>::from_data(TensorData::new(step.per_body.clone(), [nb, 3]), device);
    let (nx, ny, rax, ray, rbx, rby) =
        (column(&c, 0), column(&c, 1), column(&c, 2), column(&c, 3), column(&c, 4), column(&c, 5));
    let (kn, kt) = (column(&c, 6), column(&c, 7));
    let (pn, pt, v0n, v0t, stick) = (column(&c, 8), column(&c, 9), column(&c, 10), column(&c, 11), column(&c, 12));
    let (on, ot) = (column(&out, 0), column(&out, 1));
    // The correction's impulse in world coordinates (tangent = (ny, -nx)).
    let (dn, dt) = (on.clone() * kn, ot.clone() * kt);
    let px = dn.clone() * nx.clone() + dt.clone() * ny.clone();
    let py = dn * ny.clone() - dt * nx.clone();
    let on_b = Tensor::cat(vec![px.clone(), py.clone(), rbx.clone() * py.clone() - rby.clone() * px.clone()], 1);
    let on_a = Tensor::cat(vec![px.clone(), py.clone(), rax.clone() * py - ray.clone() * px], 1);
    let delta = Tensor::<2>::zeros([nb, 3], device)
        .select_assign(0, graph.body_b.clone(), on_b, IndexingUpdateOp::Add)
        .select_assign(0, graph.body_a.clone(), on_a.neg(), IndexingUpdateOp::Add)
        * inv;
    let (da, db) = (delta.clone().select(0, graph.body_a.clone()), delta.select(0, graph.body_b.clone()));
    let rel_x = column(&db, 0) - column(&db, 2) * rby - column(&da, 0) + column(&da, 2) * ray;
    let rel_y = column(&db, 1) + column(&db, 2) * rbx - column(&da, 1) - column(&da, 2) * rax;
    let mut vn = v0n + rel_x.clone() * nx.clone() + rel_y.clone() * ny.clone();
    let mut vt = v0t + rel_x * ny - rel_y * nx;
    let x = pn + on.clone();
    if step.compliance > 0.0 {
        // A compliant row's "velocity" carries its own impulse: v + gamma lambda / m (in velocity
        // units lambda / m is builtin's plus the output).
        vn = vn + x.clone().mul_scalar(step.compliance);
        vt = vt + (pt + ot).mul_scalar(step.compliance);
    }
    // Fischer-Burmeister on (lambda_n / m_n, v_n); the square root kept away from 0.
    let fb = x.clone() + vn.clone() - (x.clone() * x + vn.clone() * vn + 1e-10).sqrt();
    let per_contact = fb.clone() * fb + stick * vt.clone() * vt;
    per_contact.mean().mul_scalar(step.weight)
}

/// The weighted squared distance of one step's warm start (builtin + output) to its reference
/// solution, in each row's velocity units.
pub fn mse_loss(model: &GnnNet, step: &StepData, device: &Device) -> Tensor<1> {
    let graph = GraphInput::new(&step.contact_features, &step.body_features, &step.pairs, device);
    let out = model.forward(&graph);
    let nc = step.pairs.len();
    let c = Tensor::<2>::from_data(TensorData::new(step.per_contact.clone(), [nc, PER_CONTACT]), device);
    let dn = column(&c, 8) + column(&out, 0) - column(&c, 13);
    let dt = column(&c, 9) + column(&out, 1) - column(&c, 14);
    (dn.clone() * dn + dt.clone() * dt).mean().mul_scalar(step.weight)
}

/// The solver-in-the-loop loss of one step (see [`gnn::unroll`]): the network's output is read,
/// the residual after `sweeps` PGS sweeps from its warm start and that residual's gradient are
/// computed by hand, and the returned surrogate `sum(output * gradient)` carries that gradient
/// into the network on `backward`. Returns the surrogate and the true residual.
pub fn unrolled_loss(
    model: &GnnNet,
    step: &StepData,
    problem: &sim::problem::Problem,
    sweeps: usize,
    weights: LossWeights,
    device: &Device,
) -> (Tensor<1>, f64) {
    let graph = GraphInput::new(&step.contact_features, &step.body_features, &step.pairs, device);
    let out = model.forward(&graph);
    let values: Vec<f32> = out.clone().into_data().try_into_vec::<f32>().expect("f32 output");
    let masses: Vec<[f64; 2]> =
        step.per_contact.chunks_exact(PER_CONTACT).map(|c| [c[6] as f64, c[7] as f64]).collect();
    let warm: Vec<[f64; 2]> = problem
        .contacts
        .iter()
        .zip(values.chunks_exact(2))
        .zip(&masses)
        .map(|((c, y), k)| [c.previous[0] as f64 + y[0] as f64 * k[0], c.previous[1] as f64 + y[1] as f64 * k[1]])
        .collect();
    let mut unrolled = gnn::unroll::Unrolled::new(&problem.bodies, &problem.contacts);
    unrolled.power = weights.power;
    unrolled.approach_weight = weights.approach;
    let (residual, grad) = unrolled.loss_and_gradient(&warm, sweeps);
    let w = step.weight as f64;
    let g: Vec<f32> =
        grad.iter().zip(&masses).flat_map(|(g, k)| [(w * g[0] * k[0]) as f32, (w * g[1] * k[1]) as f32]).collect();
    let g = Tensor::<2>::from_data(TensorData::new(g, [step.pairs.len(), 2]), device);
    ((out * g).sum(), w * residual)
}

/// The sweeps unrolled on a step: `sweeps`, or with 0 as many as builtin took on it less one (at
/// most 400): the residual there is what decides whether the model stops earlier.
fn unrolled_sweeps(sweeps: usize, builtin: u32) -> usize {
    if sweeps == 0 {
        (builtin.saturating_sub(1) as usize).min(400)
    } else {
        sweeps
    }
}

/// How the unrolled loss weighs the last sweep's changes ([`gnn::unroll::Unrolled`]'s
/// `power` and `approach_weight`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossWeights {
    pub power: f64,
    pub approach: f64,
}

/// What a training step minimises.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Objective {
    /// The complementarity residual at the warm start.
    Residual,
    /// The residual left after this many PGS sweeps from the warm start.
    Unrolled { sweeps: usize, weights: LossWeights },
    /// The squared distance to the recorded reference solution (velocity units): the supervised
    /// loss, well posed only where the solution is unique (compliant contacts).
    Mse,
}

/// The mean loss of `net` as it is over `steps`, whose problems are `problems` (indexed by each
/// step's `problem`): where the epochs' mean losses start from, and the validation loss.
pub fn mean_loss(
    net: &Net,
    steps: &[StepData],
    problems: &[(sim::problem::Problem, u32)],
    objective: Objective,
) -> Option<f64> {
    let device = Device::flex();
    let model = GnnNet::from_net(net, &device);
    let one = |s: &StepData| -> Option<f64> {
        let l = match objective {
            Objective::Residual => loss(&model, s, &device),
            Objective::Mse => mse_loss(&model, s, &device),
            Objective::Unrolled { sweeps, weights } => {
                let (problem, builtin) = problems.get(s.problem)?;
                return Some(unrolled_loss(&model, s, problem, unrolled_sweeps(sweeps, *builtin), weights, &device).1);
            }
        };
        Some(l.into_scalar::<f32>() as f64)
    };
    let values: Vec<f64> = steps.iter().map(one).collect::<Option<_>>()?;
    let finite: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if finite.len() < values.len() {
        tracing::warn!(skipped = values.len() - finite.len(), "non-finite losses left out of the mean");
    }
    Some(finite.iter().sum::<f64>() / finite.len().max(1) as f64)
}

/// Trains `net` for `epochs` passes over `train` (shuffled by `seed`), calling `validate` after
/// each epoch with the f32 network and the mean loss.
#[allow(clippy::too_many_arguments)] // one training run's knobs, read once
pub fn train(
    net: &Net,
    train: &[StepData],
    problems: &[(sim::problem::Problem, u32)],
    objective: Objective,
    epochs: usize,
    lr: f64,
    seed: u64,
    mut validate: impl FnMut(usize, &Net, f64),
) {
    let device = Device::flex().autodiff();
    let mut model = GnnNet::from_net(net, &device);
    let mut optim = AdamConfig::new().init();
    let mut order: Vec<usize> = (0..train.len()).collect();
    let mut rng = sph::SplitMix64::new(seed);
    for epoch in 0..epochs {
        // Fisher-Yates.
        for i in (1..order.len()).rev() {
            order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
        }
        let mut sum = 0.0f64;
        for &i in &order {
            let (l, value) = match objective {
                Objective::Residual => {
                    let l = loss(&model, &train[i], &device);
                    let value = l.clone().into_scalar::<f32>() as f64;
                    (l, value)
                }
                Objective::Mse => {
                    let l = mse_loss(&model, &train[i], &device);
                    let value = l.clone().into_scalar::<f32>() as f64;
                    (l, value)
                }
                Objective::Unrolled { sweeps, weights } => {
                    let (problem, builtin) = &problems[train[i].problem];
                    unrolled_loss(&model, &train[i], problem, unrolled_sweeps(sweeps, *builtin), weights, &device)
                }
            };
            if !value.is_finite() {
                tracing::warn!(epoch, step = i, "non-finite loss: step skipped");
                continue;
            }
            sum += value;
            let grads = GradientsParams::from_grads(l.backward(), &model);
            model = optim.step(lr, model, grads);
        }
        validate(epoch, &model.valid().to_net(), sum / order.len().max(1) as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gnn::net::NetConfig;
    use msgs::{ProblemBody, ProblemContact, ProblemHeader};

    /// A ball (mass 2, inertia 0.5) on the floor, moving down at 0.1 m/s, resting on one contact.
    fn ball_on_floor(previous: f32) -> sim::problem::Problem {
        sim::problem::Problem {
            header: ProblemHeader::default(),
            bodies: vec![
                ProblemBody::default(),
                ProblemBody { v: [0.0, -0.1], w: 0.0, inv_mass: 0.5, inv_inertia: 2.0 },
            ],
            contacts: vec![ProblemContact {
                body_a: 0,
                body_b: 1,
                normal: [0.0, 1.0],
                ra: [0.0, 0.0],
                rb: [0.0, -0.5],
                friction: 0.5,
                previous: [previous, 0.0],
                reference: [0.2, 0.0],
                age: 3,
                ..Default::default()
            }],
        }
    }

    #[test]
    fn the_loss_is_the_complementarity_residual_of_the_warm_start() {
        let device = Device::flex();
        let model = GnnNet::from_net(&Net::new(NetConfig::default(), 1), &device);
        // Untrained: the warm start is builtin's. Effective normal mass 2 (the torque arm is along
        // the normal), so x = previous / 2; v_n = -0.1 + previous / 2.
        for previous in [0.0f32, 0.2, 0.5] {
            let step = StepData::new(&ball_on_floor(previous), 0, 1.0).unwrap();
            let got: f32 = loss(&model, &step, &device).into_scalar();
            let (x, v) = (previous as f64 / 2.0, -0.1 + previous as f64 / 2.0);
            let fb = x + v - (x * x + v * v + 1e-10).sqrt();
            // The reference holds it sticking; tangential velocity is 0 here.
            assert!((got as f64 - fb * fb).abs() < 1e-6, "previous {previous}: {got} vs {}", fb * fb);
        }
        // At the solution (previous = 0.2: v_n = 0, x = 0.1) the residual vanishes.
        let step = StepData::new(&ball_on_floor(0.2), 0, 1.0).unwrap();
        assert!(loss(&model, &step, &device).into_scalar::<f32>() < 1e-8);
    }

    #[test]
    fn compliant_rows_carry_their_impulse_in_the_residual_and_mse_measures_the_reference() {
        let device = Device::flex();
        let model = GnnNet::from_net(&Net::new(NetConfig::default(), 1), &device);
        let compliant = |previous: f32, gamma: f32| {
            let mut p = ball_on_floor(previous);
            p.header.compliance = gamma;
            p
        };
        // v_n + gamma x = 0 with v_n = -0.1 + x: x = 0.1 / (1 + gamma), the impulse twice that.
        let solution = 2.0 * 0.1 / 1.1;
        let at = |previous, gamma| loss(&model, &StepData::new(&compliant(previous, gamma), 0, 1.0).unwrap(), &device);
        assert!(at(solution, 0.1).into_scalar::<f32>() < 1e-8, "the compliant solution");
        assert!(at(0.2, 0.1).into_scalar::<f32>() > 1e-5, "the rigid solution is not the compliant one");
        assert!(at(0.2, 0.0).into_scalar::<f32>() < 1e-8);
        // Sliding along the floor at 0.05 m/s, held sticking: the tangent row's effective mass is
        // 1, so a compliant stick needs lambda_t = -0.05 / (1 + gamma).
        let sliding = |tangent: f32, gamma: f32| {
            let mut p = compliant(solution, gamma);
            p.bodies[1].v[0] = 0.05;
            p.contacts[0].previous[1] = tangent;
            p.contacts[0].reference = [solution, -0.05 / 1.1];
            StepData::new(&p, 0, 1.0).unwrap()
        };
        let residual = |tangent, gamma| loss(&model, &sliding(tangent, gamma), &device).into_scalar::<f32>();
        assert!(residual(-0.05 / 1.1, 0.1) < 1e-8, "the compliant stick");
        assert!(residual(-0.05, 0.1) > 1e-6, "the rigid stick is not it");
        let at_reference: f32 = mse_loss(&model, &sliding(-0.05 / 1.1, 0.1), &device).into_scalar();
        assert!(at_reference < 1e-12, "{at_reference}");
        let off: f32 = mse_loss(&model, &sliding(0.0, 0.1), &device).into_scalar();
        assert!((off - (0.05f32 / 1.1).powi(2)).abs() < 1e-7, "tangent off by 0.05 / 1.1: {off}");
        // The reference is 0.2 (x = 0.1): the untrained warm start is `previous`.
        let mse = |previous| mse_loss(&model, &StepData::new(&ball_on_floor(previous), 0, 1.0).unwrap(), &device);
        assert!(mse(0.2).into_scalar::<f32>() < 1e-12);
        let got: f32 = mse(0.6).into_scalar();
        assert!((got - 0.2f32.powi(2)).abs() < 1e-6, "((0.6 - 0.2) / 2)^2 on the normal, 0 on the tangent: {got}");
    }

    #[test]
    fn training_lowers_the_residual() {
        let problems: Vec<(sim::problem::Problem, u32)> =
            [0.0f32, 0.05, 0.1, 0.3].iter().map(|&p| (ball_on_floor(p), 1)).collect();
        let steps: Vec<StepData> =
            problems.iter().enumerate().map(|(i, (p, _))| StepData::new(p, i, 1.0).unwrap()).collect();
        let device = Device::flex();
        let net = Net::new(NetConfig { hidden: 8, rounds: 1 }, 2);
        let before: f32 =
            steps.iter().map(|s| loss(&GnnNet::from_net(&net, &device), s, &device).into_scalar::<f32>()).sum();
        let mut after = f32::INFINITY;
        train(&net, &steps, &problems, Objective::Residual, 30, 1e-2, 3, |_, trained, _| {
            let m = GnnNet::from_net(trained, &device);
            after = steps.iter().map(|s| loss(&m, s, &device).into_scalar::<f32>()).sum();
        });
        assert!(after < 0.5 * before, "residual {before} -> {after}");
    }
}
