//! Seeded random damage to real recordings (bit flips, overwritten bytes, truncations, inserted
//! junk, lengths overwritten with huge values, duplicated regions, chunks re-packed around damaged
//! records so that their CRC still checks out), fed to every reader of the crate: `info` (strict
//! and lenient), `recover`, the trainer's `Steps` and the `RecordingReader` pass that `dc-replay`
//! and `dc-foxglove` make. No case may panic (a panic fails the test), take long, or allocate
//! much more than the file holds; every error names the file. Where the strict reader accepts a
//! case, the lenient one must agree with it; every recovered file must read back strictly.
//!
//! Longer runs: `DC_FUZZ_CASES=1000000 cargo test -p recorder --test fuzz -- --nocapture`
//! (`DC_FUZZ_SEED` picks another seed), or the libFuzzer target in `nodes/recorder/fuzz/`.

mod common;
#[path = "../fuzz/every_reader.rs"]
mod every_reader;

use common::*;
use recorder::read::ReadOptions;
use recorder::{Info, Steps};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// The largest single allocation of this test binary: a reader that trusts a length asks for
/// gigabytes.
struct Largest;

static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Largest = Largest;

/// No allocation above this (the writer's own chunk buffers are 1 MiB; the files are < 64 KiB).
const ALLOCATION_LIMIT: usize = 16 << 20;
/// No case may take longer than this (all readers together; they take about a millisecond).
const CASE_LIMIT: Duration = Duration::from_secs(5);

/// SplitMix64: small, seeded, the same sequence everywhere.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }

    /// A length field's worst values: huge, overflowing, just past the end, or random.
    fn length(&mut self, file_len: usize) -> u64 {
        match self.below(8) {
            0 => u64::MAX,
            1 => u64::MAX - self.below(64) as u64,
            2 => 1 << (32 + self.below(31)),
            3 => u32::MAX as u64,
            4 => file_len as u64 + self.below(16) as u64,
            5 => self.below(file_len + 1) as u64,
            6 => 0,
            _ => self.next(),
        }
    }
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// One of the ways a file gets damaged; returns its name (for the tally).
fn mutate(rng: &mut Rng, bytes: &mut Vec<u8>) -> &'static str {
    let len = bytes.len().max(1);
    let records = records(bytes);
    match rng.below(9) {
        0 => {
            for _ in 0..1 + rng.below(8) {
                let at = rng.below(len).min(bytes.len().saturating_sub(1));
                if let Some(b) = bytes.get_mut(at) {
                    *b ^= 1 << rng.below(8);
                }
            }
            "bit flips"
        }
        1 => {
            for _ in 0..1 + rng.below(50) {
                let at = rng.below(len);
                if let Some(b) = bytes.get_mut(at) {
                    *b = rng.next() as u8;
                }
            }
            "overwritten bytes"
        }
        2 => {
            bytes.truncate(rng.below(len));
            "truncation"
        }
        3 => {
            let n = 1 + rng.below(64);
            let junk = rng.bytes(n);
            let at = rng.below(bytes.len() + 1);
            bytes.splice(at..at, junk);
            "inserted junk"
        }
        4 => {
            // A record's length, or a length field inside a record (a chunk's sizes, a string's
            // or a map's byte count), made huge.
            let Some(r) = records.get(rng.below(records.len().max(1))).copied() else { return "huge length" };
            let file_len = bytes.len();
            let value = rng.length(file_len);
            let field = match (r.opcode, rng.below(3)) {
                (_, 0) => Some((r.offset + 1, 8)),
                (0x06, 1) => Some((r.offset + 9 + 16, 8)), // uncompressed size
                (0x06, _) => {
                    let name =
                        bytes.get(r.offset + 37..r.offset + 41).map(|b| u32::from_le_bytes(b.try_into().unwrap()));
                    let name = name.unwrap_or(0).min(1 << 20) as usize;
                    [(r.offset + 37, 4), (r.offset + 41 + name, 8)].get(rng.below(2)).copied()
                }
                _ => Some((r.offset + 9 + 4 * rng.below(4), 4)),
            };
            if let Some((at, n)) = field.filter(|(at, n)| at + n <= bytes.len()) {
                bytes[at..at + n].copy_from_slice(&value.to_le_bytes()[..n]);
            }
            "huge length"
        }
        5 => {
            let from = rng.below(len);
            let to = (from + 1 + rng.below(4096)).min(bytes.len());
            let region = bytes.get(from..to).unwrap_or_default().to_vec();
            let at = rng.below(bytes.len() + 1);
            bytes.splice(at..at, region);
            "duplicated region"
        }
        6 => {
            // A whole record twice (a chunk twice: its messages twice), or one dropped.
            let Some(r) = records.get(rng.below(records.len().max(1))).copied() else {
                return "record twice or dropped";
            };
            if r.end() <= bytes.len() {
                if rng.below(2) == 0 {
                    let copy = bytes[r.offset..r.end()].to_vec();
                    bytes.splice(r.end()..r.end(), copy);
                } else {
                    bytes.drain(r.offset..r.end());
                }
            }
            "record twice or dropped"
        }
        _ => {
            repack_chunk(rng, bytes, &records);
            "chunk re-packed around damage"
        }
    }
}

/// Decompresses a chunk, damages its records (bits, a record's length, a string's length, a
/// channel id), and writes it back compressed or not, with sizes and CRC that check out: what
/// only the parsers of the records inside a chunk can catch.
fn repack_chunk(rng: &mut Rng, bytes: &mut Vec<u8>, records: &[RecordAt]) {
    let chunks: Vec<RecordAt> =
        records.iter().filter(|r| r.opcode == 0x06 && r.end() <= bytes.len()).copied().collect();
    if chunks.is_empty() {
        return;
    }
    let r = chunks[rng.below(chunks.len())];
    let body = &bytes[r.offset + 9..r.end()];
    let Some(name_len) = body.get(28..32).map(|b| u32::from_le_bytes(b.try_into().unwrap()) as usize) else { return };
    let Some(compressed) = body.get(32 + name_len.min(1 << 20)..40 + name_len.min(1 << 20)) else { return };
    let compressed = u64::from_le_bytes(compressed.try_into().unwrap()).min(body.len() as u64) as usize;
    let Some(data) = body.get(40 + name_len..40 + name_len + compressed) else { return };
    let Ok(mut inner) = zstd::stream::decode_all(data) else { return };
    // The records inside: (offset, opcode, len).
    let mut inner_records = Vec::new();
    let mut at = 0;
    while at + 9 <= inner.len() {
        let len = u64::from_le_bytes(inner[at + 1..at + 9].try_into().unwrap());
        let Some(len) = usize::try_from(len).ok().filter(|&len| len <= inner.len() - at - 9) else { break };
        inner_records.push((at, inner[at], len));
        at += 9 + len;
    }
    if inner_records.is_empty() {
        return;
    }
    let (at, opcode, _) = inner_records[rng.below(inner_records.len())];
    let value = rng.length(inner.len());
    let field = match (opcode, rng.below(4)) {
        (_, 0) => Some((at + 1, 8)),        // the record's length
        (0x04, 1) => Some((at + 9 + 4, 4)), // a channel's topic length
        (0x04, 2) => Some((at + 9, 2)),     // a channel's id
        (0x05, 1 | 2) => Some((at + 9, 2)), // a message's channel id
        _ => None,
    };
    match field {
        Some((f, n)) if f + n <= inner.len() => inner[f..f + n].copy_from_slice(&value.to_le_bytes()[..n]),
        _ => {
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(inner.len());
                inner[i] ^= 1 << rng.below(8);
            }
        }
    }
    let (name, data): (&[u8], Vec<u8>) = if rng.below(2) == 0 {
        (b"zstd", zstd::stream::encode_all(&inner[..], 1).unwrap())
    } else {
        (b"", inner.clone())
    };
    let mut content = body[..24].to_vec(); // start and end time, then the new uncompressed size
    content[16..24].copy_from_slice(&(inner.len() as u64).to_le_bytes());
    content.extend(crc32fast::hash(&inner).to_le_bytes());
    content.extend((name.len() as u32).to_le_bytes());
    content.extend(name);
    content.extend((data.len() as u64).to_le_bytes());
    content.extend(&data);
    let mut record = vec![0x06];
    record.extend((content.len() as u64).to_le_bytes());
    record.extend(content);
    bytes.splice(r.offset..r.end(), record);
}

/// What the readers made of the cases.
#[derive(Default)]
struct Tally {
    cases: u64,
    strict_ok: u64,
    recovered_ok: u64,
    damaged_regions: u64,
    steps: u64,
    by_kind: std::collections::BTreeMap<&'static str, u64>,
}

/// Every reader on one damaged file: in memory through `every_reader` (info strict and lenient,
/// the replay pass, recover and its output read back), then from the file as the trainer reads it
/// (`Steps`) and, every 64th case, `recover` from file to file.
fn read_every_way(file: &Path, bytes: &[u8], out: &Path, case: u64, tally: &mut Tally) {
    let started = Instant::now();
    let outcome = every_reader::every_reader(file, bytes);
    tally.strict_ok += u64::from(outcome.strict.is_some());
    tally.recovered_ok += u64::from(outcome.recovered.is_some());
    tally.damaged_regions += outcome.damaged as u64;
    std::fs::write(file, bytes).unwrap();
    match Steps::open(file) {
        Ok(steps) => {
            for step in steps {
                match step {
                    Ok(_) => tally.steps += 1,
                    Err(e) => assert!(e.to_string().contains(&file.display().to_string()), "case {case}, steps: {e}"),
                }
            }
        }
        Err(e) => panic!("case {case}: Steps::open of a file: {e}"),
    }
    if case.is_multiple_of(64) {
        match recorder::recover::recover(file, out) {
            Ok(r) => {
                assert_eq!(Some(r.messages), outcome.recovered, "case {case}");
                let any_version = ReadOptions { any_wire_version: true, lenient: false };
                let back = Info::read_with(out, any_version).unwrap_or_else(|e| panic!("case {case}: {e}"));
                assert_eq!(back.messages, r.messages, "case {case}");
            }
            Err(e) => {
                assert!(outcome.recovered.is_none(), "case {case}: from memory it recovered, from the file: {e}");
                assert!(e.to_string().contains(&file.display().to_string()), "case {case}, recover: {e}");
            }
        }
    }
    let took = started.elapsed();
    assert!(took < CASE_LIMIT, "case {case} took {took:?}");
}

/// The recordings damaged: a finished one, the same cut where a killed recorder's would end, a
/// 606-message one of 11 chunks, and the committed recording of the real simulator.
fn originals(dir: &Path) -> Vec<Vec<u8>> {
    let small = dir.join("small.mcap");
    chunked_fixture(&small, 3, 2, 12, 4);
    let large = dir.join("large.mcap");
    chunked_fixture(&large, 4, 2, 100, 20);
    let small = std::fs::read(&small).unwrap();
    let killed = small[..data_end(&small)].to_vec();
    // A recording of the real simulator, committed (one chunk of 19 messages).
    let real = concat!(env!("CARGO_MANIFEST_DIR"), "/../../recordings/fixtures/ball-box-seed0-steps.mcap");
    vec![small, killed, std::fs::read(&large).unwrap(), std::fs::read(real).unwrap()]
}

fn fuzz(test: &str, seed: u64, cases: u64) {
    let dir = scratch(test);
    let originals = originals(&dir);
    let file = dir.join("case.mcap");
    let out = dir.join("recovered.mcap");
    let mut rng = Rng(env_u64("DC_FUZZ_SEED", 0) ^ seed);
    let mut tally = Tally::default();
    let started = Instant::now();
    for case in 0..cases {
        let original = &originals[rng.below(originals.len())];
        let mut bytes = original.clone();
        for _ in 0..1 + rng.below(3) {
            let kind = mutate(&mut rng, &mut bytes);
            *tally.by_kind.entry(kind).or_default() += 1;
        }
        read_every_way(&file, &bytes, &out, case, &mut tally);
        tally.cases += 1;
    }
    let largest = LARGEST.load(Ordering::Relaxed);
    eprintln!(
        "{test}: {} cases, each through info (strict and lenient), the replay reader, Steps and recover, in {:.1} s; \
         strict reads accepted {}, recover kept something of {}, {} damaged regions skipped, {} steps read; \
         largest allocation {} KiB; mutations {:?}",
        tally.cases,
        started.elapsed().as_secs_f64(),
        tally.strict_ok,
        tally.recovered_ok,
        tally.damaged_regions,
        tally.steps,
        largest >> 10,
        tally.by_kind
    );
    assert!(largest < ALLOCATION_LIMIT, "an allocation of {largest} bytes");
    // The mutations must not be so mild that everything reads, nor so wild that nothing does.
    assert!(tally.strict_ok < tally.cases && tally.recovered_ok > tally.cases / 4, "weak mix");
}

// Two halves with their own seeds, run in parallel by the test harness.
#[test]
fn damaged_recordings_never_panic_and_errors_name_the_file_a() {
    fuzz("fuzz-a", 0x5eed_0001, env_u64("DC_FUZZ_CASES", 12_000) / 2);
}

#[test]
fn damaged_recordings_never_panic_and_errors_name_the_file_b() {
    fuzz("fuzz-b", 0x5eed_0002, env_u64("DC_FUZZ_CASES", 12_000) / 2);
}
