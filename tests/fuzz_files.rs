//! Seeded fuzzing of the files users hand the tools besides recordings (those have their own
//! fuzzer, `nodes/recorder/tests/fuzz.rs`): contact-graph models (`.dcg`), U-Net models (`.dcu`)
//! and a report's `steps.csv` (`dc-metrics --from-steps`). Each gets `DC_FUZZ_CASES` (10,000 by
//! default) damaged files, through the same functions the binaries call, and:
//! - no case panics, allocates more than [`ALLOCATION_LIMIT`] in one piece, or takes longer than
//!   [`CASE_LIMIT`];
//! - an error names the file;
//! - a file that is accepted is usable: a model that loads predicts finite values on a small
//!   problem, a steps file that loads gives every table of the report (and, for some, the whole
//!   report folder with its plots).
//!
//! The damage is of two kinds: raw (bit flips, overwritten, inserted or duplicated bytes,
//! truncation, huge lengths) and *sealed* — content changed and the checksum computed again, as a
//! buggy writer would leave it, so that the parsers behind the checksum are reached too.
//! `DC_FUZZ_SEED` picks other cases.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// The largest single allocation since the last reset: a reader that trusts a length asks for
/// gigabytes; above the limit the allocation fails (and the test with it) instead of swapping.
struct Largest;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        if layout.size() > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        if layout.size() > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        if new_size > ALLOCATION_LIMIT {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Largest = Largest;

/// No single allocation above this (the files are < 100 KiB; a report's plot buffers ~2 MB).
const ALLOCATION_LIMIT: usize = 64 << 20;
/// No case may take longer than this (they take about a millisecond).
const CASE_LIMIT: Duration = Duration::from_secs(5);

fn cases() -> u64 {
    env_u64("DC_FUZZ_CASES", 10_000)
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// SplitMix64: small, seeded, the same cases everywhere.
struct Rng(u64);

impl Rng {
    fn new(salt: u64) -> Rng {
        Rng(env_u64("DC_FUZZ_SEED", 24) ^ salt)
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (0 when `n` is 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
    /// A length or count field's worst values.
    fn huge(&mut self) -> u64 {
        let random = self.next();
        *self.pick(&[u64::MAX, u64::MAX / 2, 1 << 32, u32::MAX as u64, 1 << 40, 1 << 20, 0, random])
    }
}

/// Raw damage, as a disk, a copy or an editor leaves it; returns its name for the tally.
fn damage(rng: &mut Rng, b: &mut Vec<u8>) -> &'static str {
    let len = b.len().max(1);
    match rng.below(7) {
        0 => {
            for _ in 0..1 + rng.below(8) {
                let at = rng.below(len);
                if let Some(x) = b.get_mut(at) {
                    *x ^= 1 << rng.below(8);
                }
            }
            "bit flips"
        }
        1 => {
            for _ in 0..1 + rng.below(32) {
                let at = rng.below(len);
                if let Some(x) = b.get_mut(at) {
                    *x = rng.next() as u8;
                }
            }
            "overwritten bytes"
        }
        2 => {
            b.truncate(rng.below(len));
            "truncation"
        }
        3 => {
            let junk: Vec<u8> = (0..1 + rng.below(64)).map(|_| rng.next() as u8).collect();
            let at = rng.below(b.len() + 1);
            b.splice(at..at, junk);
            "inserted junk"
        }
        4 => {
            let from = rng.below(len);
            let to = (from + 1 + rng.below(4096)).min(b.len());
            let region = b.get(from..to).unwrap_or_default().to_vec();
            let at = rng.below(b.len() + 1);
            b.splice(at..at, region);
            "duplicated region"
        }
        5 => {
            // Eight bytes anywhere become a huge little-endian number (a length field's worst).
            let at = rng.below(len);
            let value = rng.huge().to_le_bytes();
            for (i, v) in value.iter().enumerate() {
                if let Some(x) = b.get_mut(at + i) {
                    *x = *v;
                }
            }
            "huge number"
        }
        _ => {
            // A CBOR head with an 8-byte argument (byte/text string, array, map of 2^64 - 1 ...).
            let major = *rng.pick(&[0x40u8, 0x60, 0x80, 0xa0]) | 0x1b;
            let at = rng.below(len);
            let mut head = vec![major];
            head.extend_from_slice(&rng.huge().to_be_bytes());
            b.splice(at..(at + 9).min(b.len()), head);
            "huge CBOR length"
        }
    }
}

/// Runs `case` with the allocation and time limits; `what` names the case in a failure.
fn limited<T>(what: impl Fn() -> String, case: impl FnOnce() -> T) -> T {
    LARGEST.store(0, Ordering::Relaxed);
    let started = Instant::now();
    let out = case();
    let took = started.elapsed();
    assert!(took < CASE_LIMIT, "{}: took {took:?}", what());
    let largest = LARGEST.load(Ordering::Relaxed);
    assert!(largest <= ALLOCATION_LIMIT, "{}: asked for {largest} bytes at once", what());
    out
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dc-fuzz-files-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Counts per kind of damage: cases, and how many a reader accepted.
#[derive(Default)]
struct Tally(std::collections::BTreeMap<&'static str, (u64, u64)>);

impl Tally {
    fn add(&mut self, kind: &'static str, accepted: bool) {
        let e = self.0.entry(kind).or_default();
        e.0 += 1;
        e.1 += accepted as u64;
    }
    fn print(&self, file: &str) {
        for (kind, (n, ok)) in &self.0 {
            eprintln!("{file}: {kind}: {n} cases, {ok} accepted");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// .dcg: the contact-graph network

/// A problem of a few bodies and contacts, for the prediction of a model that loaded.
fn small_problem() -> (Vec<msgs::ProblemBody>, Vec<msgs::ProblemContact>) {
    let bodies: Vec<msgs::ProblemBody> = (0..4)
        .map(|i| msgs::ProblemBody { v: [0.1 * i as f32, -1.0], w: 0.2, inv_mass: 1.0, inv_inertia: 2.0 })
        .chain([msgs::ProblemBody::default()]) // the ground: infinite mass
        .collect();
    let contacts = (0..6u32)
        .map(|i| msgs::ProblemContact {
            body_a: i % 4,
            body_b: if i < 3 { 4 } else { (i + 1) % 4 },
            age: i,
            ra: [0.1, -0.2],
            rb: [-0.1, 0.2],
            normal: [0.0, 1.0],
            friction: 0.5,
            penetration: 0.01,
            previous: [0.3, -0.05],
            ..Default::default()
        })
        .collect();
    (bodies, contacts)
}

/// A sealed change to a loaded `.dcg`: the configuration, a layer's shape or a weight changed,
/// then the checksum computed again.
fn reseal_gnn(rng: &mut Rng, file: &mut gnn::ModelFile) -> &'static str {
    let net = &mut file.net;
    let kind = match rng.below(6) {
        0 => {
            net.config.hidden = rng.huge() as usize;
            "sealed: hidden"
        }
        1 => {
            net.config.rounds = rng.huge() as usize;
            "sealed: rounds"
        }
        2 => {
            let i = rng.below(5);
            let layer =
                [&mut net.encode_contact, &mut net.encode_body, &mut net.body, &mut net.contact, &mut net.decode]
                    .into_iter()
                    .nth(i)
                    .unwrap();
            if rng.below(2) == 0 {
                layer.inputs = rng.huge() as usize;
            } else {
                layer.outputs = rng.huge() as usize;
            }
            "sealed: layer shape"
        }
        3 => {
            let i = rng.below(3);
            let layer = [&mut net.encode_contact, &mut net.body, &mut net.decode].into_iter().nth(i).unwrap();
            let n = rng.below(layer.weight.len() + 8);
            layer.weight.resize(n, 0.5);
            "sealed: weight count"
        }
        4 => {
            let w = &mut net.contact.weight;
            let at = rng.below(w.len());
            if let Some(x) = w.get_mut(at) {
                *x = *rng.pick(&[f32::NAN, f32::INFINITY, f32::MAX, -f32::MAX, 1e30, 0.0]);
            }
            "sealed: weight value"
        }
        _ => {
            file.format = *rng.pick(&[0, 1, 3, u32::MAX]);
            "sealed: format"
        }
    };
    file.checksum = gnn::content_checksum(file.format, &file.net, &file.provenance);
    kind
}

#[test]
fn damaged_contact_graph_model_files_are_errors_or_usable_models() {
    let dir = scratch("dcg");
    let good = gnn::ModelFile::new(gnn::net::Net::new(gnn::net::NetConfig { hidden: 8, rounds: 2 }, 3), "fuzz base");
    let base_path = dir.join("base.dcg");
    good.save(&base_path).unwrap();
    let base = std::fs::read(&base_path).unwrap();
    let (bodies, contacts) = small_problem();
    let path = dir.join("case.dcg");
    let mut rng = Rng::new(0xdc6);
    let mut tally = Tally::default();
    for case in 0..cases() {
        let mut file = good.clone();
        let (kind, bytes) = if rng.below(3) == 0 {
            let kind = reseal_gnn(&mut rng, &mut file);
            file.save(&path).unwrap();
            (kind, std::fs::read(&path).unwrap())
        } else {
            let mut bytes = base.clone();
            (damage(&mut rng, &mut bytes), bytes)
        };
        std::fs::write(&path, &bytes).unwrap();
        let what = || format!("case {case} ({kind}, seed {})", env_u64("DC_FUZZ_SEED", 24));
        let accepted = limited(what, || match gnn::ModelFile::load(&path) {
            Ok(model) => {
                let mut predictor = gnn::Predictor::new(model.net);
                let mut out = vec![[0.0f32; 2]; contacts.len()];
                // Finite warm starts, or an error saying they are not (never NaN to a solver).
                if predictor.warm_start(&bodies, &contacts, &mut out).is_ok() {
                    assert!(out.iter().flatten().all(|v| v.is_finite()), "{}: predicted {out:?}", what());
                }
                true
            }
            Err(e) => {
                assert!(e.to_string().contains("case.dcg"), "{}: the error does not name the file: {e}", what());
                false
            }
        });
        tally.add(kind, accepted);
    }
    tally.print(".dcg");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------------
// .dcu: the U-Net

/// The metadata and weight sections of a `.dcu` (magic + version, length + JSON, length +
/// weights, checksum), as offsets.
fn dcu_sections(b: &[u8]) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
    let json_len = u64::from_le_bytes(b[8..16].try_into().unwrap()) as usize;
    let json = 16..16 + json_len;
    let weights_len = u64::from_le_bytes(b[json.end..json.end + 8].try_into().unwrap()) as usize;
    let weights = json.end + 8..json.end + 8 + weights_len;
    (json, weights)
}

/// FNV-1a 64, the `.dcu` checksum.
fn fnv(parts: &[&[u8]]) -> u64 {
    parts
        .iter()
        .flat_map(|p| p.iter())
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// A sealed change to a `.dcu`: a number of the metadata replaced by an extreme one, or the
/// metadata or weights damaged, then the lengths and checksum written again.
fn reseal_dcu(rng: &mut Rng, base: &[u8]) -> (&'static str, Vec<u8>) {
    let (json, weights) = dcu_sections(base);
    let mut meta = base[json].to_vec();
    let mut w = base[weights].to_vec();
    let kind = match rng.below(3) {
        0 => {
            // Every number of the JSON is a place a configuration, shape or statistic sits.
            let text = String::from_utf8(meta.clone()).unwrap();
            let numbers: Vec<(usize, usize)> = text
                .char_indices()
                .filter(|&(i, c)| {
                    (c.is_ascii_digit() || c == '-') && !text[..i].ends_with(|p: char| p.is_ascii_digit() || p == '.')
                })
                .map(|(i, _)| {
                    let end = text[i + 1..]
                        .find(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '-' | '+')))
                        .map_or(text.len(), |e| i + 1 + e);
                    (i, end)
                })
                .collect();
            let (from, to) = *rng.pick(&numbers);
            let value = rng
                .pick(&[
                    "0",
                    "-1",
                    "1e308",
                    "-1e308",
                    "18446744073709551615",
                    "4294967296",
                    "1000000",
                    "129",
                    "0.0",
                    "1e-45",
                ])
                .to_string();
            meta.splice(from..to, value.into_bytes());
            "sealed: metadata number"
        }
        1 => {
            damage(rng, &mut meta);
            "sealed: metadata bytes"
        }
        _ => {
            damage(rng, &mut w);
            "sealed: weight bytes"
        }
    };
    let mut out = base[..8].to_vec();
    out.extend_from_slice(&(meta.len() as u64).to_le_bytes());
    out.extend_from_slice(&meta);
    out.extend_from_slice(&(w.len() as u64).to_le_bytes());
    out.extend_from_slice(&w);
    out.extend_from_slice(&fnv(&[&meta, &w]).to_le_bytes());
    (kind, out)
}

#[test]
fn damaged_unet_model_files_are_errors_or_usable_models() {
    let dir = scratch("dcu");
    let device = unet::device("flex").unwrap();
    let config = unet::UNetConfig { levels: 1, base_width: 2, dilations: vec![2], ..unet::UNetConfig::default() };
    let grid = unet::GridSpec { res: 0.25, pad_to: 16, ..unet::GridSpec::default() };
    let channels = grid.input_channels();
    let meta = unet::ModelMeta {
        config: config.clone(),
        grid,
        normalization: unet::Normalization {
            input_mean: vec![0.1; config.in_channels],
            input_std: vec![2.0; config.in_channels],
            target_mean: vec![0.2, -0.1],
            target_std: vec![3.0, 0.5],
        },
        input_channels: channels.clone(),
        output_channels: vec!["normal".into(), "tangent".into()],
        grid_shape: [16, 16],
        training: Default::default(),
    };
    let base_path = dir.join("base.dcu");
    unet::ModelFile::save(&meta, &config.init(&device), &base_path).unwrap();
    let base = std::fs::read(&base_path).unwrap();
    let path = dir.join("case.dcu");
    let mut rng = Rng::new(0xdc0);
    let mut tally = Tally::default();
    for case in 0..cases() {
        let (kind, bytes) = if rng.below(2) == 0 {
            reseal_dcu(&mut rng, &base)
        } else {
            let mut bytes = base.clone();
            (damage(&mut rng, &mut bytes), bytes)
        };
        std::fs::write(&path, &bytes).unwrap();
        let what = || format!("case {case} ({kind}, seed {})", env_u64("DC_FUZZ_SEED", 24));
        let accepted = limited(what, || match unet::Predictor::load(&path, &device) {
            Ok(predictor) => {
                let names: Vec<&str> = predictor.meta().input_channels.iter().map(String::as_str).collect();
                let input = msgs::Grid::zeros(msgs::StepHeader::default(), [0.0, 0.0], 0.25, 16, 16, &names);
                if let Ok(out) = predictor.predict(&input) {
                    assert!(
                        out.items.iter().all(|v| v.is_finite()),
                        "{}: a loaded model predicted non-finite values",
                        what()
                    );
                }
                true
            }
            Err(e) => {
                assert!(e.to_string().contains("case.dcu"), "{}: the error does not name the file: {e}", what());
                false
            }
        });
        tally.add(kind, accepted);
    }
    tally.print(".dcu");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------------
// steps.csv: a report's steps, read back by `dc-metrics --from-steps`

/// A cell's worst values.
const CELLS: &[&str] = &[
    "",
    "0",
    "-1",
    "-0",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e-320",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999",
    "0.5",
    "abc",
    "\"",
    "\"\"",
    ",",
    "\n",
    "\r\n",
    "\u{0}",
    "é",
    "builtin",
    "gnn",
];

/// Text-level damage to a CSV: a cell, a row, the header, or raw bytes.
fn damage_csv(rng: &mut Rng, text: &str) -> (&'static str, Vec<u8>) {
    let mut rows: Vec<Vec<String>> = text.lines().map(|l| l.split(',').map(String::from).collect()).collect();
    let join = |rows: &[Vec<String>]| rows.iter().map(|r| r.join(",")).collect::<Vec<_>>().join("\n").into_bytes();
    let n = rows.len();
    match rng.below(6) {
        0 => {
            for _ in 0..1 + rng.below(4) {
                let r = 1 + rng.below(n - 1);
                let c = rng.below(rows[r].len());
                rows[r][c] =
                    if rng.below(8) == 0 { "9".repeat(1 + rng.below(5000)) } else { rng.pick(CELLS).to_string() };
            }
            ("cells", join(&rows))
        }
        1 => {
            let r = 1 + rng.below(n - 1);
            match rng.below(3) {
                0 => {
                    let copy = rows[r].clone();
                    let at = 1 + rng.below(n - 1);
                    rows.insert(at, copy);
                }
                1 => {
                    rows.remove(r);
                }
                _ => {
                    let other = 1 + rng.below(n - 1);
                    rows.swap(r, other);
                }
            }
            ("rows", join(&rows))
        }
        2 => {
            let r = 1 + rng.below(n - 1);
            if rng.below(2) == 0 {
                let keep = rng.below(rows[r].len());
                rows[r].truncate(keep);
            } else {
                rows[r].push(rng.pick(CELLS).to_string());
            }
            ("ragged row", join(&rows))
        }
        3 => {
            let c = rng.below(rows[0].len());
            if rng.below(2) == 0 {
                rows[0][c] = rng.pick(&["", "step", "model", "sweeps", "unknown_column"]).to_string();
            } else {
                let other = rng.below(rows[0].len());
                rows[0].swap(c, other);
            }
            ("header", join(&rows))
        }
        4 => {
            // One column set to one extreme value in every row (a shifted writer).
            let c = rng.below(rows[0].len());
            let v = rng.pick(CELLS).to_string();
            for r in rows.iter_mut().skip(1) {
                if let Some(cell) = r.get_mut(c) {
                    cell.clone_from(&v);
                }
            }
            ("column", join(&rows))
        }
        _ => {
            let mut b = text.as_bytes().to_vec();
            (damage(rng, &mut b), b)
        }
    }
}

/// A small real report's `steps.csv`: two models, two simulations each, through every phase.
fn steps_csv(dir: &Path) -> String {
    let mut a = metrics::Aggregate::new();
    for (model, extra) in [("builtin", 0), ("gnn", 3)] {
        for simulation in 0..2 {
            for step in 0..40u32 {
                let sweeps = 20 + (step * 7 + simulation * 3) % 11 + extra;
                let h = msgs::SolveStatsHeader {
                    step: msgs::StepHeader { run_id: 5, simulation, step },
                    model: msgs::name16(model),
                    used_model: msgs::name16(model),
                    contacts: 10 + step,
                    persisting_contacts: step,
                    sweeps,
                    converged: 1,
                    warm_error_normal_mse: 0.5 / (step + 1) as f32,
                    warm_error_tangent_mse: 0.1,
                    solve_us: 3.0 * sweeps as f32,
                    step_us: 50.0,
                    max_speed: 2.0 / (step + 1) as f32,
                    kinetic_energy: 10.0 / (step + 1) as f32,
                    natural_rms: 0.01,
                    natural_max: 0.02,
                    ..Default::default()
                };
                a.add(metrics::StepRecord::from_msg(&h, &[]));
            }
        }
    }
    metrics::report::write(&a, &dir.join("base"), "fuzz base", &[]).unwrap();
    std::fs::read_to_string(dir.join("base/steps.csv")).unwrap()
}

#[test]
fn damaged_steps_files_are_errors_or_whole_reports() {
    let dir = scratch("steps");
    let base = steps_csv(&dir);
    let path = dir.join("case.csv");
    let mut rng = Rng::new(0xc5f);
    let mut tally = Tally::default();
    let mut reports = 0;
    for case in 0..cases() {
        let (kind, bytes) = damage_csv(&mut rng, &base);
        std::fs::write(&path, &bytes).unwrap();
        let what = || format!("case {case} ({kind}, seed {})", env_u64("DC_FUZZ_SEED", 24));
        let accepted = limited(what, || match metrics::report::aggregate_steps(&path, 0.1, Some(&[10, 20])) {
            Ok(aggregate) => {
                // Every table the report is made of; every 500th accepted case the whole folder.
                let summaries = aggregate.summaries();
                let _ = metrics::report::summary_markdown(&summaries);
                let _ = (aggregate.phase_rows(), aggregate.accuracy(), aggregate.sweeps_histograms());
                if reports % 500 == 0 {
                    let out = dir.join("report");
                    metrics::report::write(&aggregate, &out, "fuzz", &[])
                        .unwrap_or_else(|e| panic!("{}: an accepted file's report failed: {e}", what()));
                }
                reports += 1;
                true
            }
            Err(e) => {
                assert!(e.to_string().contains("case.csv"), "{}: the error does not name the file: {e}", what());
                false
            }
        });
        tally.add(kind, accepted);
    }
    tally.print("steps.csv");
    let _ = std::fs::remove_dir_all(&dir);
}
