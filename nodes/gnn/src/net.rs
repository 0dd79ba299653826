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

/// A uniform double in [0, 1) with 53 random bits.
fn unit_f64(rng: &mut SplitMix64) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// Widest state a network may have: about 6.3 million weights, some 30 MB as a model file, well
/// under [`runtime::files::MAX_MODEL_BYTES`] (the shipped networks have 16).
pub const MAX_HIDDEN: usize = 1024;
/// Most message-passing rounds.
pub const MAX_ROUNDS: usize = 64;

/// The network's shape (also the command-line flags of the tools that make networks).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::Args)]
pub struct NetConfig {
    /// Width of the contact and body states (1 to 1024).
    #[arg(long, default_value_t = 16,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_HIDDEN as u64))]
    pub hidden: usize,
    /// Message-passing rounds (weights shared across rounds; at most 64).
    #[arg(long, default_value_t = 4,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(0..=MAX_ROUNDS as u64))]
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
    /// Contact states, then body states (of the bodies with contacts), and the bodies' means.
    hc: Vec<f32>,
    hb: Vec<f32>,
    mb: Vec<f32>,
    /// Per body of the problem, its number among the bodies with contacts (`u32::MAX`: none).
    slot: Vec<u32>,
    /// The bodies with contacts, their contact counts and features; each contact's two bodies
    /// by their numbers.
    touched: Vec<u32>,
    counts: Vec<f32>,
    xb: Vec<f32>,
    local: Vec<(usize, usize)>,
    acc: Vec<f32>,
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
        if h == 0 || h > MAX_HIDDEN || self.config.rounds > MAX_ROUNDS {
            return Err(format!("configuration {:?} is out of range", self.config));
        }
        self.encode_contact.check("encode_contact", CONTACT_FEATURES, h)?;
        self.encode_body.check("encode_body", BODY_FEATURES, h)?;
        self.body.check("body", 2 * h, h)?;
        self.contact.check("contact", 4 * h, h)?;
        self.decode.check("decode", h + CONTACT_FEATURES, 2)
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
        let h = self.config.hidden;
        Plan::new(self).forward(Graph { contact_features, body_features, pairs }, s, false);
        for (hc, x) in s.hc.chunks_exact(h).zip(contact_features.chunks_exact(CONTACT_FEATURES)) {
            out.extend_from_slice(hc);
            out.extend_from_slice(x);
        }
    }
}

/// A layer laid out for inference: the weights transposed (`[in][out]`), so that `W x` is a sum
/// of weight columns scaled by the inputs, which vectorises across the outputs without the
/// horizontal sums of row-by-row dot products.
#[derive(Debug, Clone)]
struct Columns {
    columns: Vec<f32>,
    bias: Vec<f32>,
}

impl Columns {
    fn new(l: &Linear) -> Columns {
        let mut columns = vec![0.0; l.inputs * l.outputs];
        for (o, row) in l.weight.chunks_exact(l.inputs).enumerate() {
            for (i, w) in row.iter().enumerate() {
                columns[i * l.outputs + o] = *w;
            }
        }
        Columns { columns, bias: l.bias.clone() }
    }

    /// `acc[r] = start + W[:, first..first + width] x[r]` for every row `r` of `acc` (`w` values
    /// each), row `r`'s input being `inputs`' row `r`, stored through a ReLU when `relu`: the
    /// part of the layer that reads one block of its input, for many inputs at once.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn product<K: Kernel>(
        &self,
        w: impl Width,
        first: usize,
        inputs: Rows<'_>,
        start: Start<'_>,
        relu: bool,
        acc: &mut [f32],
    ) {
        let n = w.get();
        debug_assert_eq!(n, self.bias.len());
        K::product(&self.columns[first * n..(first + inputs.width) * n], n, inputs, start, relu, acc);
    }
}

/// A step's problem as the network reads it: [`CONTACT_FEATURES`] per contact,
/// [`BODY_FEATURES`] per body, each contact's two bodies.
#[derive(Clone, Copy)]
struct Graph<'a> {
    contact_features: &'a [f32],
    body_features: &'a [f32],
    pairs: &'a [(u32, u32)],
}

/// Input rows of a layer block: row `r` is `x[r * stride..][..width]`.
#[derive(Clone, Copy)]
struct Rows<'a> {
    x: &'a [f32],
    stride: usize,
    width: usize,
}

impl<'a> Rows<'a> {
    /// Rows of `width` values one after the other.
    fn packed(x: &'a [f32], width: usize) -> Rows<'a> {
        Rows { x, stride: width, width }
    }
}

/// What each output row starts from before the products are added.
#[derive(Clone, Copy)]
enum Start<'a> {
    /// What the row holds (a second block of the same layer).
    Held,
    /// The same values for every row (a bias, a term shared by all rows).
    Row(&'a [f32]),
    Zero,
}

/// The width of the network's states: known when the code is compiled for the usual widths
/// (every loop over a state then has a fixed length, unrolled and vectorised), else at run time.
trait Width: Copy {
    fn get(self) -> usize;
}

#[derive(Clone, Copy)]
struct Fixed<const N: usize>;

impl<const N: usize> Width for Fixed<N> {
    #[inline(always)]
    fn get(self) -> usize {
        N
    }
}

#[derive(Clone, Copy)]
struct Dynamic(usize);

impl Width for Dynamic {
    #[inline(always)]
    fn get(self) -> usize {
        self.0
    }
}

/// How `acc[r] = start + W x[r]` (then a ReLU if asked) is computed for many rows: `columns`
/// holds `inputs.width` columns of `n` values, row `r`'s accumulators are
/// `acc[r * n..(r + 1) * n]`. Every kernel makes the same roundings in the same order (per value:
/// the start, then a product and a sum column after column), so all give the same bits.
trait Kernel {
    fn product(columns: &[f32], n: usize, inputs: Rows<'_>, start: Start<'_>, relu: bool, acc: &mut [f32]);
}

/// Plain loops (any processor).
struct Portable;

impl Kernel for Portable {
    #[inline(always)]
    fn product(columns: &[f32], n: usize, inputs: Rows<'_>, start: Start<'_>, relu: bool, acc: &mut [f32]) {
        let Rows { x, stride, width } = inputs;
        for (r, acc) in acc.chunks_exact_mut(n).enumerate() {
            match start {
                Start::Held => {}
                Start::Row(row) => acc.copy_from_slice(&row[..n]),
                Start::Zero => acc.fill(0.0),
            }
            for (column, &xi) in columns.chunks_exact(n).zip(&x[r * stride..r * stride + width]) {
                for (a, w) in acc.iter_mut().zip(column) {
                    *a += w * xi;
                }
            }
            if relu {
                // As AVX's `max(a, 0)`: 0 for NaN and for -0.
                acc.iter_mut().for_each(|a| *a = if *a > 0.0 { *a } else { 0.0 });
            }
        }
    }
}

/// AVX2 for 8, 16 and 32 values a row: a few rows at a time with their accumulators in registers
/// and each weight column loaded once for them (the compiler keeps a loop's accumulators in
/// memory, and does not vectorise a fixed-size array of them either). Used only where the
/// processor has AVX2.
#[cfg(target_arch = "x86_64")]
struct Avx2;

#[cfg(target_arch = "x86_64")]
impl Kernel for Avx2 {
    #[inline(always)]
    fn product(columns: &[f32], n: usize, inputs: Rows<'_>, start: Start<'_>, relu: bool, acc: &mut [f32]) {
        let Rows { x, stride, width } = inputs;
        let rows = acc.len() / n;
        assert!(acc.len() == rows * n && columns.len() >= width * n);
        assert!(rows == 0 || x.len() >= (rows - 1) * stride + width);
        if let Start::Row(row) = start {
            assert!(row.len() >= n);
        }
        let block = Block { columns: columns.as_ptr(), width, x: x.as_ptr(), stride, start, relu };
        // SAFETY: `Avx2` is only used by `Plan::forward_avx2`, called once
        // AVX2 was detected; the asserts above keep every read and write inside the slices.
        unsafe {
            match n {
                8 => rows_avx2::<1, 4>(&block, acc.as_mut_ptr(), rows),
                16 => rows_avx2::<2, 4>(&block, acc.as_mut_ptr(), rows),
                32 => rows_avx2::<4, 2>(&block, acc.as_mut_ptr(), rows),
                _ => Portable::product(columns, n, inputs, start, relu, acc),
            }
        }
    }
}

/// A product as [`Avx2`]'s blocks read it.
#[cfg(target_arch = "x86_64")]
struct Block<'a> {
    columns: *const f32,
    width: usize,
    x: *const f32,
    stride: usize,
    start: Start<'a>,
    relu: bool,
}

/// `rows` rows of `8 V` values, `R` rows at a time (then one at a time).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn rows_avx2<const V: usize, const R: usize>(block: &Block<'_>, acc: *mut f32, rows: usize) {
    let n = 8 * V;
    let mut r = 0;
    while r + R <= rows {
        block_avx2::<V, R>(block, r, acc.add(r * n));
        r += R;
    }
    while r < rows {
        block_avx2::<V, 1>(block, r, acc.add(r * n));
        r += 1;
    }
}

/// `R` rows of `8 V` values from row `first`: `R V` accumulators in registers, each column loaded
/// once.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn block_avx2<const V: usize, const R: usize>(block: &Block<'_>, first: usize, acc: *mut f32) {
    use std::arch::x86_64::{
        __m256, _mm256_add_ps, _mm256_loadu_ps, _mm256_max_ps, _mm256_mul_ps, _mm256_set1_ps, _mm256_setzero_ps,
        _mm256_storeu_ps,
    };
    let n = 8 * V;
    let x = block.x.add(first * block.stride);
    let mut a: [[__m256; V]; R] = [[_mm256_setzero_ps(); V]; R];
    for (r, row) in a.iter_mut().enumerate() {
        for (v, a) in row.iter_mut().enumerate() {
            *a = match block.start {
                Start::Held => _mm256_loadu_ps(acc.add(r * n + 8 * v)),
                Start::Row(start) => _mm256_loadu_ps(start.as_ptr().add(8 * v)),
                Start::Zero => _mm256_setzero_ps(),
            };
        }
    }
    for k in 0..block.width {
        let mut w: [__m256; V] = [_mm256_setzero_ps(); V];
        for (v, w) in w.iter_mut().enumerate() {
            *w = _mm256_loadu_ps(block.columns.add(k * n + 8 * v));
        }
        for (r, row) in a.iter_mut().enumerate() {
            let s = _mm256_set1_ps(*x.add(r * block.stride + k));
            for (a, w) in row.iter_mut().zip(&w) {
                *a = _mm256_add_ps(*a, _mm256_mul_ps(*w, s));
            }
        }
    }
    for (r, row) in a.iter().enumerate() {
        for (v, a) in row.iter().enumerate() {
            let a = if block.relu { _mm256_max_ps(*a, _mm256_setzero_ps()) } else { *a };
            _mm256_storeu_ps(acc.add(r * n + 8 * v), a);
        }
    }
}

/// A network laid out for inference (what [`crate::Predictor`] keeps): the same function as
/// [`Net`], computed with transposed weights, many contacts (or bodies) a layer at once, only
/// for the bodies that have contacts, and with AVX2 where the processor has it (the same
/// operations in the same order: the same bits).
#[derive(Debug, Clone)]
pub struct Plan {
    config: NetConfig,
    encode_contact: Columns,
    encode_body: Columns,
    body: Columns,
    contact: Columns,
    /// The decoder with its two outputs padded to [`DECODE_LANES`] (zero weights), so that it
    /// runs through the same kernels.
    decode: Columns,
}

/// The decoder's outputs as the inference layout holds them (two used).
const DECODE_LANES: usize = 8;

impl Plan {
    pub fn new(net: &Net) -> Plan {
        Plan {
            config: net.config,
            encode_contact: Columns::new(&net.encode_contact),
            encode_body: Columns::new(&net.encode_body),
            body: Columns::new(&net.body),
            contact: Columns::new(&net.contact),
            decode: Columns::new(&Linear {
                inputs: net.decode.inputs,
                outputs: DECODE_LANES,
                weight: net
                    .decode
                    .weight
                    .iter()
                    .copied()
                    .chain(std::iter::repeat(0.0))
                    .take(DECODE_LANES * net.decode.inputs)
                    .collect(),
                bias: net.decode.bias.iter().copied().chain(std::iter::repeat(0.0)).take(DECODE_LANES).collect(),
            }),
        }
    }

    /// The network's output per contact (velocity units): `contact_features` holds
    /// [`CONTACT_FEATURES`] per contact, `body_features` [`BODY_FEATURES`] per body, `pairs` each
    /// contact's bodies.
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
        self.forward(Graph { contact_features, body_features, pairs }, s, true);
        for (o, y) in out.iter_mut().zip(s.acc.chunks_exact(DECODE_LANES)) {
            *o = [y[0], y[1]];
        }
    }

    /// Encodes and runs the message-passing rounds (the final contact states in `s.hc`), then,
    /// with `decode`, the decoder over [h_c, x_c] (into `s.acc`, [`DECODE_LANES`] a contact).
    fn forward(&self, g: Graph<'_>, s: &mut Scratch, decode: bool) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the processor has AVX2 (checked just above).
            unsafe { self.forward_avx2(g, s, decode) };
            return;
        }
        self.forward_with::<Portable>(g, s, decode)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn forward_avx2(&self, g: Graph<'_>, s: &mut Scratch, decode: bool) {
        self.forward_with::<Avx2>(g, s, decode)
    }

    #[inline(always)]
    fn forward_with<K: Kernel>(&self, g: Graph<'_>, s: &mut Scratch, decode: bool) {
        match self.config.hidden {
            8 => self.embed_with::<K>(Fixed::<8>, g, s),
            16 => self.embed_with::<K>(Fixed::<16>, g, s),
            32 => self.embed_with::<K>(Fixed::<32>, g, s),
            h => self.embed_with::<K>(Dynamic(h), g, s),
        }
        if decode {
            let (h, lanes, d) = (self.config.hidden, Fixed::<DECODE_LANES>, &self.decode);
            s.acc.resize(s.hc.len() / h * DECODE_LANES, 0.0);
            d.product::<K>(lanes, 0, Rows::packed(&s.hc, h), Start::Row(&d.bias), false, &mut s.acc);
            d.product::<K>(
                lanes,
                h,
                Rows::packed(g.contact_features, CONTACT_FEATURES),
                Start::Held,
                false,
                &mut s.acc,
            );
        }
    }

    #[inline(always)]
    fn embed_with<K: Kernel>(&self, w: impl Width, g: Graph<'_>, s: &mut Scratch) {
        let Graph { contact_features, body_features, pairs } = g;
        let h = w.get();
        let nc = pairs.len();
        // The bodies that have contacts (the others never reach a contact), numbered in the
        // order the contacts name them; each contact's bodies by that number.
        s.slot.clear();
        s.slot.resize(body_features.len() / BODY_FEATURES, u32::MAX);
        s.touched.clear();
        s.local.clear();
        for &(a, b) in pairs {
            let mut number = |body: u32| {
                let slot = &mut s.slot[body as usize];
                if *slot == u32::MAX {
                    *slot = s.touched.len() as u32;
                    s.touched.push(body);
                }
                *slot as usize
            };
            let local = (number(a), number(b));
            s.local.push(local);
        }
        let nt = s.touched.len();
        s.counts.clear();
        s.counts.resize(nt, 0.0);
        for &(a, b) in &s.local {
            s.counts[a] += 1.0;
            s.counts[b] += 1.0;
        }
        s.xb.clear();
        for &i in &s.touched {
            s.xb.extend_from_slice(&body_features[i as usize * BODY_FEATURES..(i as usize + 1) * BODY_FEATURES]);
        }
        let (ec, eb) = (&self.encode_contact, &self.encode_body);
        s.hc.resize(nc * h, 0.0);
        ec.product::<K>(w, 0, Rows::packed(contact_features, CONTACT_FEATURES), Start::Row(&ec.bias), true, &mut s.hc);
        s.hb.resize(nt * h, 0.0);
        eb.product::<K>(w, 0, Rows::packed(&s.xb, BODY_FEATURES), Start::Row(&eb.bias), true, &mut s.hb);
        s.mb.resize(nt * h, 0.0);
        s.global.resize(h, 0.0);
        for _ in 0..self.config.rounds {
            // Bodies gather the mean of their contacts.
            s.mb.fill(0.0);
            for (&(a, b), hc) in s.local.iter().zip(s.hc.chunks_exact(h)) {
                for body in [a, b] {
                    for (m, v) in s.mb[body * h..(body + 1) * h].iter_mut().zip(hc) {
                        *m += v;
                    }
                }
            }
            for (mb, count) in s.mb.chunks_exact_mut(h).zip(&s.counts) {
                let inv = 1.0 / count;
                mb.iter_mut().for_each(|m| *m *= inv);
            }
            let body = &self.body;
            s.acc.resize(nt * h, 0.0);
            body.product::<K>(w, 0, Rows::packed(&s.hb, h), Start::Row(&body.bias), false, &mut s.acc);
            body.product::<K>(w, h, Rows::packed(&s.mb, h), Start::Held, true, &mut s.acc);
            std::mem::swap(&mut s.hb, &mut s.acc);
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
            let contact = &self.contact;
            s.from_global.resize(h, 0.0);
            contact.product::<K>(
                w,
                3 * h,
                Rows::packed(&s.global, h),
                Start::Row(&contact.bias),
                false,
                &mut s.from_global,
            );
            for (from, first) in [(&mut s.from_a, h), (&mut s.from_b, 2 * h)] {
                from.resize(nt * h, 0.0);
                contact.product::<K>(w, first, Rows::packed(&s.hb, h), Start::Zero, false, from);
            }
            s.acc.resize(nc * h, 0.0);
            contact.product::<K>(w, 0, Rows::packed(&s.hc, h), Start::Row(&s.from_global), false, &mut s.acc);
            for ((&(a, b), hc), u) in s.local.iter().zip(s.hc.chunks_exact_mut(h)).zip(s.acc.chunks_exact(h)) {
                let (fa, fb) = (&s.from_a[a * h..(a + 1) * h], &s.from_b[b * h..(b + 1) * h]);
                for (((v, u), x), y) in hc.iter_mut().zip(u).zip(fa).zip(fb) {
                    *v += (u + x + y).max(0.0);
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
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut out);
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
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut s, &mut before);
        // Every contact hears the others through the pile-wide mean; a neighbour hears more.
        xc[0] += 5.0;
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut s, &mut after);
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

    /// The network as its definition reads (module docs), in f64, weights row by row, every
    /// body included: what the inference layout must compute.
    fn by_definition(net: &Net, xc: &[f32], xb: &[f32], pairs: &[(u32, u32)]) -> Vec<[f64; 2]> {
        let h = net.config.hidden;
        let layer = |l: &Linear, x: &[f64], relu: bool| -> Vec<f64> {
            (0..l.outputs)
                .map(|o| {
                    let row = &l.weight[o * l.inputs..(o + 1) * l.inputs];
                    let s = row.iter().zip(x).map(|(w, x)| *w as f64 * x).sum::<f64>() + l.bias[o] as f64;
                    if relu {
                        s.max(0.0)
                    } else {
                        s
                    }
                })
                .collect()
        };
        let f64s = |x: &[f32]| x.iter().map(|v| *v as f64).collect::<Vec<f64>>();
        let mut hc: Vec<Vec<f64>> =
            xc.chunks_exact(CONTACT_FEATURES).map(|x| layer(&net.encode_contact, &f64s(x), true)).collect();
        let mut hb: Vec<Vec<f64>> =
            xb.chunks_exact(BODY_FEATURES).map(|x| layer(&net.encode_body, &f64s(x), true)).collect();
        for _ in 0..net.config.rounds {
            for (i, hb) in hb.iter_mut().enumerate() {
                let touching = pairs.iter().map(|&(a, b)| (a as usize == i) as usize + (b as usize == i) as usize);
                let count = touching.clone().sum::<usize>();
                let mut m = vec![0.0; h];
                for (c, times) in hc.iter().zip(touching) {
                    for (m, v) in m.iter_mut().zip(c) {
                        *m += *v * times as f64;
                    }
                }
                let input: Vec<f64> = hb
                    .iter()
                    .copied()
                    .chain(m.iter().map(|m| if count > 0 { m / count as f64 } else { 0.0 }))
                    .collect();
                *hb = layer(&net.body, &input, true);
            }
            let g: Vec<f64> = (0..h).map(|k| hc.iter().map(|c| c[k]).sum::<f64>() / hc.len() as f64).collect();
            hc = pairs
                .iter()
                .zip(&hc)
                .map(|(&(a, b), c)| {
                    let input: Vec<f64> =
                        c.iter().chain(&hb[a as usize]).chain(&hb[b as usize]).chain(&g).copied().collect();
                    c.iter().zip(layer(&net.contact, &input, true)).map(|(c, u)| c + u).collect()
                })
                .collect();
        }
        hc.iter()
            .zip(xc.chunks_exact(CONTACT_FEATURES))
            .map(|(c, x)| {
                let y = layer(&net.decode, &c.iter().copied().chain(f64s(x)).collect::<Vec<f64>>(), false);
                [y[0], y[1]]
            })
            .collect()
    }

    /// A trained-looking network: every layer random, the decoder too.
    fn random_net(hidden: usize, rounds: usize, seed: u64) -> Net {
        let mut net = Net::new(NetConfig { hidden, rounds }, seed);
        net.decode = Linear::glorot(hidden + CONTACT_FEATURES, 2, &mut SplitMix64::new(seed + 1));
        for l in [&mut net.encode_contact, &mut net.encode_body, &mut net.body, &mut net.contact, &mut net.decode] {
            let mut rng = SplitMix64::new(seed + l.inputs as u64);
            l.bias.iter_mut().for_each(|b| *b = (unit_f64(&mut rng) as f32 - 0.5) * 0.2);
        }
        net
    }

    #[test]
    fn the_inference_layout_computes_the_network_as_defined() {
        // Every width the plan compiles for, one it does not (12), and bodies without contacts
        // (60..80), which the plan skips.
        for (hidden, rounds) in [(8, 2), (16, 4), (32, 1), (12, 3)] {
            let net = random_net(hidden, rounds, hidden as u64);
            let (xc, xb, mut pairs) = inputs(150, 80);
            pairs.iter_mut().for_each(|p| *p = (p.0 % 60, p.1 % 60));
            let want = by_definition(&net, &xc, &xb, &pairs);
            let mut got = Vec::new();
            Plan::new(&net).predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut got);
            let scale = want.iter().flatten().fold(0f64, |m, v| m.max(v.abs()));
            let worst = want
                .iter()
                .flatten()
                .zip(got.iter().flatten())
                .map(|(w, g)| (w - *g as f64).abs())
                .fold(0f64, f64::max);
            assert!(scale > 0.1, "a non-trivial output: {scale}");
            assert!(worst <= 1e-5 * scale, "hidden {hidden}: max difference {worst} vs output scale {scale}");
        }
    }

    #[test]
    fn every_kernel_gives_the_same_bits_and_scratch_is_reusable() {
        let (xc, xb, pairs) = inputs(97, 41);
        for hidden in [8, 16, 32, 12] {
            let plan = Plan::new(&random_net(hidden, 3, 5));
            let mut s = Scratch::default();
            let graph = Graph { contact_features: &xc, body_features: &xb, pairs: &pairs };
            plan.forward_with::<Portable>(graph, &mut s, false);
            let portable = s.hc.clone();
            // The dispatching path (AVX2 where the processor has it), through a scratch that
            // served a larger problem first.
            let (big_c, big_b, big_p) = inputs(300, 120);
            let mut out = Vec::new();
            plan.predict(&big_c, &big_b, &big_p, &mut s, &mut out);
            plan.forward(graph, &mut s, false);
            assert_eq!(portable.len(), s.hc.len());
            assert!(portable.iter().zip(&s.hc).all(|(a, b)| a.to_bits() == b.to_bits()), "hidden {hidden}");
        }
    }

    #[test]
    fn bodies_without_contacts_do_not_change_the_prediction() {
        let net = random_net(16, 2, 9);
        let (xc, mut xb, pairs) = inputs(40, 30);
        let mut before = Vec::new();
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut before);
        // Ten more bodies nobody touches, with wild features.
        xb.extend((0..10 * BODY_FEATURES).map(|i| 1e3 * i as f32));
        let mut after = Vec::new();
        Plan::new(&net).predict(&xc, &xb, &pairs, &mut Scratch::default(), &mut after);
        assert_eq!(before, after);
    }
}
