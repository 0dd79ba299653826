//! One possibly damaged recording, in memory, through every reader of the `recorder` crate, with
//! the properties that must hold whatever the bytes: no panic, every error naming the file,
//! strict and lenient reads agreeing where the strict one succeeds, and a recovered file that
//! reads back strictly with the messages `recover` counted.
//!
//! Shared by the seeded fuzz test (`tests/fuzz.rs`, through `#[path]`) and the libFuzzer target
//! (`fuzz_targets/read.rs`), so that `cargo test` compiles and runs what `cargo fuzz` runs.

use recorder::read::{ReadOptions, RecordingReader};
use recorder::{Error, Info, RecordingWriter};
use std::io::{Cursor, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};

/// What the readers made of one input.
#[derive(Debug, Default, Clone, Copy)]
pub struct Outcome {
    /// The strict reader read it all (its messages).
    pub strict: Option<u64>,
    /// `recover` kept something (its messages).
    pub recovered: Option<u64>,
    /// Damaged regions the lenient reader skipped.
    pub damaged: usize,
}

const STRICT: ReadOptions = ReadOptions { any_wire_version: false, lenient: false };
const LENIENT: ReadOptions = ReadOptions { any_wire_version: false, lenient: true };
const RECOVERY: ReadOptions = ReadOptions { any_wire_version: true, lenient: true };

fn reader(name: &Path, bytes: &[u8], options: ReadOptions) -> Result<RecordingReader, Error> {
    RecordingReader::from_source(name, Cursor::new(bytes.to_vec()), options)
}

fn names_file(e: &Error, name: &Path, what: &str) {
    let text = e.to_string();
    assert!(text.contains(&name.display().to_string()), "{what}: the error does not name the file: {text}");
}

/// An output whose bytes stay readable after the writer is gone.
#[derive(Clone, Default)]
struct Shared(Arc<Mutex<Vec<u8>>>);

impl Write for Shared {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// `bytes`, named `name` in errors, through info (strict and lenient), the replay pass (every
/// item, strictly, every payload's step decoded) and recover; panics when a property breaks.
pub fn every_reader(name: &Path, bytes: &[u8]) -> Outcome {
    let mut outcome = Outcome::default();
    // info, strict (what `dc-unet` lists simulations with) and lenient (`dc-record info`).
    let strict = reader(name, bytes, STRICT).and_then(Info::from_reader);
    let lenient = reader(name, bytes, LENIENT).and_then(Info::from_reader);
    match (&strict, &lenient) {
        (Err(e), _) => names_file(e, name, "strict info"),
        (Ok(s), _) => outcome.strict = Some(s.messages),
    }
    match (&strict, &lenient) {
        (_, Err(e)) => names_file(e, name, "lenient info"),
        (Ok(s), Ok(l)) => {
            assert!(l.damage.is_empty(), "the strict read took it whole, the lenient one found {:?}", l.damage);
            assert_eq!(s.messages, l.messages);
        }
        (Err(_), Ok(l)) => {
            outcome.damaged = l.damage.len();
            for pair in l.damage.windows(2) {
                assert!(pair[0].offset < pair[1].offset, "damage out of order: {pair:?}");
            }
            for d in &l.damage {
                assert!(d.resumed_at.is_none_or(|r| r > d.offset && r <= bytes.len() as u64), "{d}");
            }
        }
    }
    // The replay pass (`dc-replay`, `dc-foxglove`): every item strictly, payloads decoded.
    match reader(name, bytes, STRICT) {
        Ok(mut r) => {
            while let Some(item) = r.next_item() {
                match item {
                    Ok(recorder::Item::Message(m)) => {
                        if let Some(kind) = m.channel.kind {
                            let _ = kind.step_of(&m.data);
                        }
                    }
                    Ok(_) => {}
                    Err(e) => {
                        names_file(&e, name, "reader");
                        assert!(r.next_item().is_none(), "items after an error");
                        break;
                    }
                }
            }
        }
        Err(e) => names_file(&e, name, "reader open"),
    }
    // recover, into memory, then read back strictly.
    let out = Shared::default();
    let recovered = reader(name, bytes, RECOVERY).and_then(|r| {
        let writer = RecordingWriter::to_output(&name.with_extension("recovered.mcap"), out.clone())?;
        recorder::recover::recover_into(r, writer)
    });
    match recovered {
        Ok(r) => {
            outcome.recovered = Some(r.messages);
            if let Some(n) = outcome.strict {
                assert_eq!(r.messages, n, "recover lost messages of an intact file");
            }
            let written = out.0.lock().unwrap().clone();
            let back = reader(name, &written, ReadOptions { any_wire_version: true, lenient: false })
                .and_then(Info::from_reader)
                .unwrap_or_else(|e| panic!("the recovered file does not read back: {e}"));
            assert_eq!(back.messages, r.messages);
        }
        Err(e) => names_file(&e, name, "recover"),
    }
    outcome
}
