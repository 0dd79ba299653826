//! The contact-graph network, in plain f32 (the inference path: no framework, one core, small
//! enough for every step). Per step:
//!
//! 1. encode: `h_c = relu(E_c x_c)` per contact, `h_b = relu(E_b x_b)` per body;
//! 2. `rounds` rounds of message passing with weights shared across rounds:
//!    `m_b = mean of h_c over the body's contacts`, `h_b = relu(B [h_b, m_b])`,
//!    `g = mean of h_c over all contacts` (the pile-wide context),
//!    `h_c = h_c + relu(C [h_c, h_a, h_b, g])` (a and b the contact's bodies);
//! 3. decode: `y_c = D [h_c, x_c]` (the last state and the contact's own features), two numbers
//!    in velocity units; the warm start is builtin's impulse
//!    plus `y_c` times the contact's effective masses (a correction on persisting contacts, the
//!    value itself on new ones, where builtin is 0).
//!
//! `D` starts at zero, so an untrained network is builtin exactly.

use crate::features::{BODY_FEATURES, CONTACT_FEATURES};
use serde::{Deserialize, Serialize};
use sph::SplitMix64;

/// A dense layer `y = W x + b`, `W` row-major `[out][in]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Linear {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

impl Linear {
    /// Zero weights and bias.
    pub fn zeros(inputs: usize, outputs: usize) -> Linear {
        Linear { inputs, outputs, weight: vec![0.0; inputs * outputs], bias: vec![0.0; outputs] }
    }

    /// Weights uniform in `±sqrt(6 / (inputs + outputs))` (Glorot) from a seeded generator.
    pub fn glorot(inputs: usize, outputs: usize, rng: &mut SplitMix64) -> Linear {
        let bound = (6.0 / (inputs + outputs) as f64).sqrt();
        let weight = (0..inputs * outputs).map(|_| ((unit_f64(rng) * 2.0 - 1.0) * bound) as f32).collect();
        Linear { inputs, outputs, weight, bias: vec![0.0; outputs] }
    }

    /// `out = W x + b` (out cleared first), then `relu` if asked.
    #[inline]
    fn apply(&self, x: &[f32], relu: bool, out: &mut [f32]) {
        debug_assert_eq!(x.len(), self.inputs);
        for (o, (row, b)) in out.iter_mut().zip(self.weight.chunks_exact(self.inputs).zip(&self.bias)) {
            let s = dot(row, x) + b;
            *o = if relu { s.max(0.0) } else { s };
        }
    }

    /// `out = W[:, first..first + x.len()] x`: the part of the layer that reads one block of its
    /// input, without the bias.
    #[inline]
    fn apply_block(&self, first: usize, x: &[f32], out: &mut [f32]) {
        debug_assert!(first + x.len() <= self.inputs);
        for (o, row) in out.iter_mut().zip(self.weight.chunks_exact(self.inputs)) {
            *o = dot(&row[first..first + x.len()], x);
        }
    }

    fn check(&self, name: &str, inputs: usize, outputs: usize) -> Result<(), String> {
        if (self.inputs, self.outputs) != (inputs, outputs)
            || self.weight.len() != inputs * outputs
            || self.bias.len() != outputs
        {
            return Err(format!(
                "layer {name}: {}x{} with {} weights and {} biases, expected {inputs}x{outputs}",
                self.inputs,
                self.outputs,
                self.weight.len(),
                self.bias.len()
            ));
        }
        if self.weight.iter().chain(&self.bias).any(|w| !w.is_finite()) {
            return Err(format!("layer {name}: weights that are not finite"));
        }
        Ok(())
    }
}

/// A dot product in four independent lanes (so it vectorises).
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// A uniform double in [0, 1) with 53 random bits.
fn unit_f64(rng: &mut SplitMix64) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// The network's shape (also the command-line flags of the tools that make networks).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::Args)]
pub struct NetConfig {
    /// Width of the contact and body states.
    #[arg(long, default_value_t = 16)]
    pub hidden: usize,
    /// Message-passing rounds (weights shared across rounds).
    #[arg(long, default_value_t = 4)]
    pub rounds: usize,
}

impl Default for NetConfig {
    fn default() -> Self {
        NetConfig { hidden: 16, rounds: 4 }
    }
}

/// The network's weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Net {
    pub config: NetConfig,
    pub encode_contact: Linear,
    pub encode_body: Linear,
    pub body: Linear,
    pub contact: Linear,
    pub decode: Linear,
}

/// Reusable buffers of one prediction.
#[derive(Debug, Default)]
pub struct Scratch {
    hc: Vec<f32>,
    hb: Vec<f32>,
    mb: Vec<f32>,
    counts: Vec<f32>,
    input: Vec<f32>,
    update: Vec<f32>,
    global: Vec<f32>,
    /// Per body, the contact layer's terms for a contact's body a and body b.
    from_a: Vec<f32>,
    from_b: Vec<f32>,
    /// The contact layer's term for the pile-wide mean, with its bias.
    from_global: Vec<f32>,
}

impl Net {
    /// A fresh network: Glorot weights from `seed`, the decoder at zero (output = builtin).
    pub fn new(config: NetConfig, seed: u64) -> Net {
        let h = config.hidden;
        let mut rng = SplitMix64::new(seed);
        Net {
            config,
            encode_contact: Linear::glorot(CONTACT_FEATURES, h, &mut rng),
            encode_body: Linear::glorot(BODY_FEATURES, h, &mut rng),
            body: Linear::glorot(2 * h, h, &mut rng),
            contact: Linear::glorot(4 * h, h, &mut rng),
            decode: Linear::zeros(h + CONTACT_FEATURES, 2),
        }
    }

    /// Inputs of the decoder per contact: the final state and the contact's features.
    pub fn readout_width(&self) -> usize {
        self.config.hidden + CONTACT_FEATURES
    }

    /// Checks every layer's shape against the configuration, and that weights are finite.
    pub fn validate(&self) -> Result<(), String> {
        let h = self.config.hidden;
        if h == 0 || self.config.rounds > 64 {
            return Err(format!("configuration {:?} is out of range", self.config));
        }
        self.encode_contact.check("encode_contact", CONTACT_FEATURES, h)?;
        self.encode_body.check("encode_body", BODY_FEATURES, h)?;
        self.body.check("body", 2 * h, h)?;
        self.contact.check("contact", 4 * h, h)?;
        self.decode.check("decode", h + CONTACT_FEATURES, 2)
    }

    /// The output per contact (velocity units): `contact_features` holds [`CONTACT_FEATURES`]
    /// per contact, `body_features` [`BODY_FEATURES`] per body, `pairs` each contact's bodies.
    pub fn predict(
        &self,
        contact_features: &[f32],
        body_features: &[f32],
        pairs: &[(u32, u32)],
        s: &mut Scratch,
        out: &mut Vec<[f32; 2]>,
    ) {
        out.clear();
        out.resize(pairs.len(), [0.0; 2]);
        if pairs.is_empty() {
            return;
        }
        self.embed(contact_features, body_features, pairs, s);
        let h = self.config.hidden;
        for ((o, hc), x) in
            out.iter_mut().zip(s.hc.chunks_exact(h)).zip(contact_features.chunks_exact(CONTACT_FEATURES))
        {
            s.input[..h].copy_from_slice(hc);
            s.input[h..h + CONTACT_FEATURES].copy_from_slice(x);
            self.decode.apply(&s.input[..h + CONTACT_FEATURES], false, o);
        }
    }

    /// The decoder's input per contact (`readout_width` each): what a readout is fitted on.
    pub fn readout_inputs(
        &self,
        contact_features: &[f32],
        body_features: &[f32],
        pairs: &[(u32, u32)],
        s: &mut Scratch,
        out: &mut Vec<f32>,
    ) {
        out.clear();
        if pairs.is_empty() {
            return;
        }
        self.embed(contact_features, body_features, pairs, s);
        let h = self.config.hidden;
        for (hc, x) in s.hc.chunks_exact(h).zip(contact_features.chunks_exact(CONTACT_FEATURES)) {
            out.extend_from_slice(hc);
            out.extend_from_slice(x);
        }
    }

    /// Encodes and runs the message-passing rounds: the final contact states are in `s.hc`.
    fn embed(&self, contact_features: &[f32], body_features: &[f32], pairs: &[(u32, u32)], s: &mut Scratch) {
        let h = self.config.hidden;
        let (nc, nb) = (pairs.len(), body_features.len() / BODY_FEATURES);
        // The body layer's input [h_b, m_b] and the decoder's [h_c, x_c]; the contact layer reads
        // its blocks in place.
        s.input.resize((2 * h).max(h + CONTACT_FEATURES), 0.0);
        s.hc.resize(nc * h, 0.0);
        s.hb.resize(nb * h, 0.0);
        s.mb.resize(nb * h, 0.0);
        s.update.resize(h, 0.0);
        s.global.resize(h, 0.0);
        s.from_a.resize(nb * h, 0.0);
        s.from_b.resize(nb * h, 0.0);
        s.from_global.resize(h, 0.0);
        for (x, hc) in contact_features.chunks_exact(CONTACT_FEATURES).zip(s.hc.chunks_exact_mut(h)) {
            self.encode_contact.apply(x, true, hc);
        }
        for (x, hb) in body_features.chunks_exact(BODY_FEATURES).zip(s.hb.chunks_exact_mut(h)) {
            self.encode_body.apply(x, true, hb);
        }
        s.counts.clear();
        s.counts.resize(nb, 0.0);
        for &(a, b) in pairs {
            s.counts[a as usize] += 1.0;
            s.counts[b as usize] += 1.0;
        }
        for _ in 0..self.config.rounds {
            // Bodies gather the mean of their contacts.
            s.mb.fill(0.0);
            for (&(a, b), hc) in pairs.iter().zip(s.hc.chunks_exact(h)) {
                for body in [a as usize, b as usize] {
                    for (m, v) in s.mb[body * h..(body + 1) * h].iter_mut().zip(hc) {
                        *m += v;
                    }
                }
            }
            for (i, (hb, mb)) in s.hb.chunks_exact_mut(h).zip(s.mb.chunks_exact_mut(h)).enumerate() {
                let inv = if s.counts[i] > 0.0 { 1.0 / s.counts[i] } else { 0.0 };
                s.input[..h].copy_from_slice(hb);
                for (dst, m) in s.input[h..2 * h].iter_mut().zip(mb.iter()) {
                    *dst = m * inv;
                }
                self.body.apply(&s.input[..2 * h], true, hb);
            }
            // The pile-wide mean, then each contact from itself, its bodies and the mean. The
            // contact layer is linear in its four input blocks: the body and mean blocks are
            // computed once per body and once per round, not once per contact.
            s.global.fill(0.0);
            for hc in s.hc.chunks_exact(h) {
                for (g, v) in s.global.iter_mut().zip(hc) {
                    *g += v;
                }
            }
            let inv = 1.0 / nc as f32;
            s.global.iter_mut().for_each(|g| *g *= inv);
            self.contact.apply_block(3 * h, &s.global, &mut s.from_global);
            for (g, b) in s.from_global.iter_mut().zip(&self.contact.bias) {
                *g += b;
            }
            for ((hb, fa), fb) in
                s.hb.chunks_exact(h).zip(s.from_a.chunks_exact_mut(h)).zip(s.from_b.chunks_exact_mut(h))
            {
                self.contact.apply_block(h, hb, fa);
                self.contact.apply_block(2 * h, hb, fb);
            }
            for (&(a, b), hc) in pairs.iter().zip(s.hc.chunks_exact_mut(h)) {
                self.contact.apply_block(0, hc, &mut s.update);
                let (fa, fb) =
                    (&s.from_a[a as usize * h..(a as usize + 1) * h], &s.from_b[b as usize * h..(b as usize + 1) * h]);
                for ((((v, u), x), y), g) in hc.iter_mut().zip(&s.update).zip(fa).zip(fb).zip(&s.from_global) {
                    *v += (u + x + y + g).max(0.0);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs(nc: usize, nb: usize) -> (Vec<f32>, Vec<f32>, Vec<(u32, u32)>) {
        let mut rng = SplitMix64::new(7);
        let xc = (0..nc * CONTACT_FEATURES).map(|_| unit_f64(&mut rng) as f32).collect();
        let xb = (0..nb * BODY_FEATURES).map(|_| unit_f64(&mut rng) as f32).collect();
        let pairs = (0..nc).map(|i| ((i % nb) as u32, ((i * 7 + 1) % nb) as u32)).collect();
        (xc, xb, pairs)
    }

    #[test]
    fn an_untrained_network_predicts_exactly_zero() {
        let net = Net::new(NetConfig::default(), 3);
        net.validate().unwrap();
        let (xc, xb, pairs) = inputs(200, 101);
        let mut out = Vec::new();
        net.predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut out);
        assert_eq!(out.len(), 200);
        assert!(out.iter().all(|o| *o == [0.0, 0.0]));
    }

    #[test]
    fn messages_carry_information_between_contacts() {
        let mut net = Net::new(NetConfig { hidden: 8, rounds: 2 }, 5);
        net.decode = Linear::glorot(8 + CONTACT_FEATURES, 2, &mut SplitMix64::new(11));
        // Two contacts share body 1; a third is apart. Changing contact 0's features changes
        // contact 1's output (one body away) but not contact 2's.
        let (mut xc, xb, _) = inputs(3, 5);
        let pairs = [(0, 1), (1, 2), (3, 4)];
        let (mut before, mut after) = (Vec::new(), Vec::new());
        let mut s = Scratch::default();
        net.predict(&xc, &xb, &pairs, &mut s, &mut before);
        // Every contact hears the others through the pile-wide mean; a neighbour hears more.
        xc[0] += 5.0;
        net.predict(&xc, &xb, &pairs, &mut s, &mut after);
        let d = |i: usize| (before[i][0] - after[i][0]).abs() + (before[i][1] - after[i][1]).abs();
        assert!(d(1) > 0.0, "the neighbour sees the change");
        assert!(d(1) > d(2), "the neighbour sees it more than a contact apart: {} vs {}", d(1), d(2));
    }

    #[test]
    fn bad_shapes_and_weights_are_refused() {
        let mut net = Net::new(NetConfig::default(), 1);
        net.contact.weight.pop();
        assert!(net.validate().unwrap_err().contains("layer contact"));
        let mut net = Net::new(NetConfig::default(), 1);
        net.body.bias[0] = f32::NAN;
        assert!(net.validate().unwrap_err().contains("not finite"));
    }
}
