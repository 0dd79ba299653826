//! The contact-graph network in burn: the same layers, weights and forward pass as the f32
//! inference network (`gnn::net::Net`), so that a network trained here (end to end, with
//! autodiff) runs in the simulator as it was trained. [`GnnNet::from_net`] and
//! [`GnnNet::to_net`] move weights between the two; the parity test holds them to 1e-5.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::relu;
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};
use gnn::features::{BODY_FEATURES, CONTACT_FEATURES};
use gnn::net::{Net, NetConfig};

/// The burn twin of [`gnn::net::Net`].
#[derive(Module, Debug)]
pub struct GnnNet {
    pub encode_contact: Linear,
    pub encode_body: Linear,
    pub body: Linear,
    pub contact: Linear,
    pub decode: Linear,
    pub hidden: usize,
    pub rounds: usize,
}

/// One step's graph as tensors.
pub struct GraphInput {
    /// `[contacts, CONTACT_FEATURES]`.
    pub contact_features: Tensor<2>,
    /// `[bodies, BODY_FEATURES]`.
    pub body_features: Tensor<2>,
    /// Each contact's bodies.
    pub body_a: Tensor<1, Int>,
    pub body_b: Tensor<1, Int>,
    /// `[bodies, 1]`: 1 / (contacts of the body), 0 for a body without contacts.
    pub inverse_degree: Tensor<2>,
}

impl GraphInput {
    pub fn new(contact_features: &[f32], body_features: &[f32], pairs: &[(u32, u32)], device: &Device) -> GraphInput {
        let (nc, nb) = (pairs.len(), body_features.len() / BODY_FEATURES);
        let mut degree = vec![0f32; nb];
        for &(a, b) in pairs {
            degree[a as usize] += 1.0;
            degree[b as usize] += 1.0;
        }
        let inverse: Vec<f32> = degree.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect();
        let index = |f: fn(&(u32, u32)) -> u32| {
            let v: Vec<i64> = pairs.iter().map(|p| f(p) as i64).collect();
            Tensor::<1, Int>::from_data(TensorData::new(v, [nc]), device)
        };
        GraphInput {
            contact_features: Tensor::from_data(
                TensorData::new(contact_features.to_vec(), [nc, CONTACT_FEATURES]),
                device,
            ),
            body_features: Tensor::from_data(TensorData::new(body_features.to_vec(), [nb, BODY_FEATURES]), device),
            body_a: index(|p| p.0),
            body_b: index(|p| p.1),
            inverse_degree: Tensor::from_data(TensorData::new(inverse, [nb, 1]), device),
        }
    }
}

/// A burn layer holding `l`'s weights (burn stores `[in, out]`, ours `[out][in]`).
fn linear_from(l: &gnn::net::Linear, device: &Device) -> Linear {
    let mut w = vec![0f32; l.inputs * l.outputs];
    for o in 0..l.outputs {
        for i in 0..l.inputs {
            w[i * l.outputs + o] = l.weight[o * l.inputs + i];
        }
    }
    Linear {
        weight: Param::from_tensor(Tensor::from_data(TensorData::new(w, [l.inputs, l.outputs]), device)),
        bias: Some(Param::from_tensor(Tensor::from_data(TensorData::new(l.bias.clone(), [l.outputs]), device))),
    }
}

/// Our layer of a burn layer's weights.
fn linear_to(l: &Linear) -> gnn::net::Linear {
    let [inputs, outputs] = l.weight.val().dims();
    let w: Vec<f32> = l.weight.val().into_data().try_into_vec::<f32>().expect("f32 weights");
    let bias: Vec<f32> = match &l.bias {
        Some(b) => b.val().into_data().try_into_vec::<f32>().expect("f32 bias"),
        None => vec![0.0; outputs],
    };
    let mut weight = vec![0f32; inputs * outputs];
    for o in 0..outputs {
        for i in 0..inputs {
            weight[o * inputs + i] = w[i * outputs + o];
        }
    }
    gnn::net::Linear { inputs, outputs, weight, bias }
}

impl GnnNet {
    /// The twin of `net`, on `device`.
    pub fn from_net(net: &Net, device: &Device) -> GnnNet {
        GnnNet {
            encode_contact: linear_from(&net.encode_contact, device),
            encode_body: linear_from(&net.encode_body, device),
            body: linear_from(&net.body, device),
            contact: linear_from(&net.contact, device),
            decode: linear_from(&net.decode, device),
            hidden: net.config.hidden,
            rounds: net.config.rounds,
        }
    }

    /// The f32 network of these weights.
    pub fn to_net(&self) -> Net {
        Net {
            config: NetConfig { hidden: self.hidden, rounds: self.rounds },
            encode_contact: linear_to(&self.encode_contact),
            encode_body: linear_to(&self.encode_body),
            body: linear_to(&self.body),
            contact: linear_to(&self.contact),
            decode: linear_to(&self.decode),
        }
    }

    /// The network's output per contact, `[contacts, 2]` (velocity units), as `Net::predict`.
    pub fn forward(&self, g: &GraphInput) -> Tensor<2> {
        let [nc, _] = g.contact_features.dims();
        let [nb, _] = g.body_features.dims();
        let device = g.contact_features.device();
        let h = self.hidden;
        let mut hc = relu(self.encode_contact.forward(g.contact_features.clone()));
        let mut hb = relu(self.encode_body.forward(g.body_features.clone()));
        for _ in 0..self.rounds {
            let gathered = Tensor::<2>::zeros([nb, h], &device)
                .select_assign(0, g.body_a.clone(), hc.clone(), IndexingUpdateOp::Add)
                .select_assign(0, g.body_b.clone(), hc.clone(), IndexingUpdateOp::Add);
            let mean = gathered * g.inverse_degree.clone();
            hb = relu(self.body.forward(Tensor::cat(vec![hb, mean], 1)));
            let global = hc.clone().mean_dim(0).expand([nc, h]);
            let ha = hb.clone().select(0, g.body_a.clone());
            let hbb = hb.clone().select(0, g.body_b.clone());
            hc = hc.clone() + relu(self.contact.forward(Tensor::cat(vec![hc, ha, hbb, global], 1)));
        }
        self.decode.forward(Tensor::cat(vec![hc, g.contact_features.clone()], 1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gnn::net::{Plan, Scratch};

    #[test]
    fn burn_and_the_f32_network_agree() {
        let device = Device::flex();
        let mut net = Net::new(NetConfig::default(), 12);
        net.decode = gnn::net::Linear::glorot(net.readout_width(), 2, &mut sph::SplitMix64::new(13));
        // A pile-like graph: 150 contacts among 60 bodies, body 0 fixed.
        let mut state = 5u64;
        let mut unit = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let xc: Vec<f32> = (0..150 * CONTACT_FEATURES).map(|_| unit() * 2.0 - 1.0).collect();
        let xb: Vec<f32> = (0..60 * BODY_FEATURES).map(|_| unit()).collect();
        let pairs: Vec<(u32, u32)> = (0..150u32).map(|i| (i % 7, 7 + (i * 13) % 53)).collect();
        let mut want = Vec::new();
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut want);
        let twin = GnnNet::from_net(&net, &device);
        let got: Vec<f32> =
            twin.forward(&GraphInput::new(&xc, &xb, &pairs, &device)).into_data().try_into_vec::<f32>().unwrap();
        let scale = want.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        let worst = want.iter().flatten().zip(&got).map(|(w, g)| (w - g).abs()).fold(0f32, f32::max);
        assert!(scale > 0.1, "a non-trivial output: {scale}");
        assert!(worst <= 1e-5 * scale, "max difference {worst} vs output scale {scale}");
        // Weights survive the round trip exactly.
        assert_eq!(twin.to_net(), net);
    }
}
