//! Seeded fuzzing of the frame decoder: real frames of every kind, mutated (bit flips, overwritten
//! and inserted bytes, truncations, CBOR lengths replaced by huge ones, spliced frames), decoded
//! as their own type and as other types. Nothing may panic or allocate by a claimed length; a bad
//! payload is an `Err`. `DC_FUZZ_CASES` / `DC_FUZZ_SEED` change the run.

use msgs::*;

/// xorshift64*: enough for mutations, and the same cases for the same seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// One encoded frame of every kind the graph sends.
fn corpus() -> Vec<Vec<u8>> {
    let step = StepHeader { run_id: 7, simulation: 3, step: 42 };
    let bodies: Bodies = Frame::new(
        step,
        (0..20)
            .map(|i| Body {
                id: i,
                shape: Shape::Ball as u32,
                size: [0.5, 0.5],
                mass: 1.0,
                x: i as f32,
                ..Default::default()
            })
            .collect(),
    );
    let contacts: Contacts = Frame::new(
        step,
        (0..30).map(|i| Contact { body_a: i, body_b: i + 1, normal_impulse: 0.5, ..Default::default() }).collect(),
    );
    let grid = Grid::zeros(step, [0.0, 0.0], 0.125, 8, 8, &["normal", "tangent"]);
    let stats: SolveStats = Frame::new(
        SolveStatsHeader { step, model: name16("builtin"), sweeps: 300, contacts: 30, ..Default::default() },
        vec![1e-3; 50],
    );
    let params = RunParams { seeds: vec![0, 1], steps: 250, model: "builtin".into(), dt: 0.016, ..Default::default() };
    let control = ControlMsg::run_start(step, &params);
    let problem: problem::ProblemContacts =
        Frame::new(problem::ProblemHeader { bodies: 21, ..Default::default() }, vec![Default::default(); 10]);
    vec![
        encode(&bodies).unwrap(),
        encode(&contacts).unwrap(),
        encode(&grid).unwrap(),
        encode(&stats).unwrap(),
        encode(&control).unwrap(),
        encode(&problem).unwrap(),
    ]
}

fn mutate(rng: &mut Rng, base: &[u8], corpus: &[Vec<u8>]) -> Vec<u8> {
    let mut b = base.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(b.len());
        match rng.below(7) {
            0 => b[at] ^= 1 << rng.below(8),
            1 => b[at] = rng.next() as u8,
            2 => b.truncate(at),
            3 => {
                let junk: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.next() as u8).collect();
                b.splice(at..at, junk);
            }
            // A CBOR major type with an 8-byte length (0x1b-style) claiming up to 2^64 - 1.
            4 => {
                let major = [0x40u8, 0x60, 0x80, 0xa0][rng.below(4)] | 0x1b;
                let huge = u64::MAX >> rng.below(40);
                let end = (at + 9).min(b.len());
                b.splice(at..end, std::iter::once(major).chain(huge.to_be_bytes()));
            }
            // A 4-byte length just past what is there.
            5 => {
                let major = [0x40u8, 0x60, 0x80][rng.below(3)] | 0x1a;
                let claim = (b.len() as u32).saturating_add(rng.below(1 << 20) as u32);
                let end = (at + 5).min(b.len());
                b.splice(at..end, std::iter::once(major).chain(claim.to_be_bytes()));
            }
            _ => {
                let other = &corpus[rng.below(corpus.len())];
                let from = rng.below(other.len());
                b.splice(at.., other[from..].iter().copied());
            }
        }
        if b.is_empty() {
            break;
        }
    }
    b
}

/// Decodes `bytes` as every frame type; returns how many decoded.
fn decode_all(bytes: &[u8]) -> usize {
    [
        decode::<StepHeader, Body>(bytes).is_ok(),
        decode::<StepHeader, Contact>(bytes).is_ok(),
        decode::<GridHeader, f32>(bytes).is_ok(),
        decode::<SolveStatsHeader, f32>(bytes).is_ok(),
        decode::<Control, u8>(bytes).map(|c| control::details_of(&c.header, &c.items).is_ok()).unwrap_or(false),
        decode::<problem::ProblemHeader, problem::ProblemContact>(bytes).is_ok(),
        decode_header::<SolveStatsHeader>(bytes).is_ok(),
    ]
    .into_iter()
    .filter(|ok| *ok)
    .count()
}

#[test]
fn mutated_frames_never_panic_and_bad_ones_are_errors() {
    let corpus = corpus();
    for frame in &corpus {
        assert!(decode_all(frame) >= 1, "every corpus frame decodes as its own type");
    }
    let cases = env_or("DC_FUZZ_CASES", 20_000);
    let mut rng = Rng(env_or("DC_FUZZ_SEED", 0x5eed_cb0f) | 1);
    let (mut decoded, start) = (0usize, std::time::Instant::now());
    for _ in 0..cases {
        let base = &corpus[rng.below(corpus.len())];
        let bytes = mutate(&mut rng, base, &corpus);
        decoded += decode_all(&bytes);
    }
    eprintln!("{cases} mutated frames x 7 decoders in {:.1?}: {decoded} decodes succeeded", start.elapsed());
}
