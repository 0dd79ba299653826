//! Shared by the recorder's tests: synthetic recordings written without a bus, and the paths of
//! built binaries for the multi-process tests.
#![allow(dead_code)]

use msgs::{Body, Contact, ControlKind, ControlMsg, SolveStatsHeader, StepHeader};
use recorder::{FrameKind, RecordingWriter};
use std::path::{Path, PathBuf};

/// Path of a workspace binary (`dc`, `dc-sim`, ...), from the workspace's e2e test support.
pub fn bin(name: &str) -> PathBuf {
    deep_contact::bin(name)
}

/// A fresh scratch folder under the target dir.
pub fn scratch(test: &str) -> PathBuf {
    deep_contact::scratch_dir(test)
}

/// A bus namespace of its own per test (and per run: process ids recycle).
pub fn namespace(test: &str) -> String {
    deep_contact::unique_namespace(test)
}

pub fn bodies(s: StepHeader, n: usize) -> msgs::Bodies {
    let items = (0..n)
        .map(|i| Body {
            id: i as u32,
            x: s.step as f32 + i as f32 * 0.5,
            y: s.simulation as f32,
            mass: 1.0,
            ..Default::default()
        })
        .collect();
    msgs::Frame::new(s, items)
}

pub fn contacts(s: StepHeader, n: usize) -> msgs::Contacts {
    let items = (0..n)
        .map(|i| Contact {
            body_a: i as u32,
            body_b: i as u32 + 1,
            normal_impulse: s.step as f32 * 0.25,
            ny: 1.0,
            ..Default::default()
        })
        .collect();
    msgs::Frame::new(s, items)
}

pub fn stats(s: StepHeader) -> msgs::SolveStats {
    let model = msgs::name16("builtin");
    let header =
        SolveStatsHeader { step: s, model, used_model: model, sweeps: 3 + s.step, converged: 1, ..Default::default() };
    msgs::Frame::new(header, vec![0.1, 0.01, 0.001])
}

/// Writes one run the way `dc-record` lays it out: control, then per step bodies, contacts and
/// stats; flushes at every simulation end. `hook(writer, simulation)` runs after each simulation's
/// flush. Returns the messages written.
pub fn write_run(
    writer: &mut RecordingWriter,
    run_id: u64,
    simulations: u32,
    steps: u32,
    hook: impl FnMut(&mut RecordingWriter, u32),
) -> u64 {
    write_run_flushing(writer, run_id, simulations, steps, steps, hook)
}

/// [`write_run`] with a flush (a chunk closed) also after every `flush_every` steps.
pub fn write_run_flushing(
    writer: &mut RecordingWriter,
    run_id: u64,
    simulations: u32,
    steps: u32,
    flush_every: u32,
    mut hook: impl FnMut(&mut RecordingWriter, u32),
) -> u64 {
    let mut t = 1_000_000_000u64 + run_id * 1_000_000_000_000;
    let mut put = |w: &mut RecordingWriter, topic: &str, data: Vec<u8>| {
        t += 1_000_000;
        w.write(topic, FrameKind::of_topic(topic).unwrap(), t, t, &data).unwrap();
    };
    let run = StepHeader { run_id, simulation: 0, step: 0 };
    let params = msgs::RunParams {
        seeds: (0..simulations as u64).collect(),
        steps,
        model: "builtin".into(),
        dt: 0.01,
        ..Default::default()
    };
    put(writer, "control", msgs::encode(&ControlMsg::run_start(run, &params)).unwrap());
    for sim in 0..simulations {
        let s0 = StepHeader { run_id, simulation: sim, step: 0 };
        let scene = msgs::SceneInfo { seed: sim as u64, side: 15.0, bodies: 8, dynamic: 4, omega: 0.0 };
        put(writer, "control", msgs::encode(&ControlMsg::simulation_start(s0, steps, &scene)).unwrap());
        for step in 0..steps {
            let s = StepHeader { run_id, simulation: sim, step };
            put(writer, "bodies", msgs::encode(&bodies(s, 4)).unwrap());
            put(writer, "contacts", msgs::encode(&contacts(s, step as usize % 3)).unwrap());
            put(writer, "stats/solve", msgs::encode(&stats(s)).unwrap());
            if (step + 1) % flush_every.max(1) == 0 && step + 1 < steps {
                writer.flush().unwrap();
            }
        }
        put(writer, "control", msgs::encode(&ControlMsg::simple(s0, ControlKind::SimulationEnd, steps)).unwrap());
        writer.flush().unwrap();
        hook(writer, sim);
    }
    put(writer, "control", msgs::encode(&ControlMsg::simple(run, ControlKind::RunEnd, simulations)).unwrap());
    writer.messages()
}

/// A finished recording of one run.
pub fn fixture(path: &Path, run_id: u64, simulations: u32, steps: u32) -> u64 {
    chunked_fixture(path, run_id, simulations, steps, steps)
}

/// A finished recording of one run with a chunk per `flush_every` steps. `(2, 100, 20)` is the
/// 606-message kind of file of issue #15: 11 chunks.
pub fn chunked_fixture(path: &Path, run_id: u64, simulations: u32, steps: u32, flush_every: u32) -> u64 {
    let mut w = RecordingWriter::create(path).unwrap();
    for (topic, kind) in [
        ("control", FrameKind::Control),
        ("bodies", FrameKind::Bodies),
        ("contacts", FrameKind::Contacts),
        ("stats/solve", FrameKind::SolveStats),
    ] {
        w.add_channel(topic, kind).unwrap();
    }
    let n = write_run_flushing(&mut w, run_id, simulations, steps, flush_every, |_, _| {});
    assert_eq!(w.finish().unwrap(), n);
    n
}

/// A top-level record of an MCAP file, found by walking its framing (an intact file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordAt {
    pub offset: usize,
    pub opcode: u8,
    /// Length of the content (after the 9-byte opcode and length).
    pub len: usize,
}

impl RecordAt {
    pub fn end(&self) -> usize {
        self.offset + 9 + self.len
    }
}

/// The top-level records of an intact MCAP file, up to the footer.
pub fn records(bytes: &[u8]) -> Vec<RecordAt> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        // A damaged file (the fuzz test walks those too): stop at a length past the end.
        let Some(len) = usize::try_from(len).ok().filter(|&len| len <= bytes.len() - at - 9) else { break };
        let r = RecordAt { offset: at, opcode: bytes[at], len };
        out.push(r);
        if r.opcode == mcap::records::op::FOOTER {
            break;
        }
        at = r.end();
    }
    out
}

/// The chunks of an intact file with the messages of each (from the message indexes after it).
pub fn chunks(bytes: &[u8]) -> Vec<(RecordAt, u64)> {
    let mut out: Vec<(RecordAt, u64)> = Vec::new();
    let mut last_was_chunk_or_index = false;
    for r in records(bytes) {
        match r.opcode {
            mcap::records::op::CHUNK => {
                out.push((r, 0));
                last_was_chunk_or_index = true;
            }
            mcap::records::op::MESSAGE_INDEX if last_was_chunk_or_index && r.len >= 6 => {
                let entries = u32::from_le_bytes(bytes[r.offset + 11..r.offset + 15].try_into().unwrap()) / 16;
                out.last_mut().unwrap().1 += u64::from(entries);
            }
            _ => last_was_chunk_or_index = false,
        }
    }
    out
}

/// The offset of the data end record (where a killed writer's file would stop, at best).
pub fn data_end(bytes: &[u8]) -> usize {
    records(bytes).iter().find(|r| r.opcode == mcap::records::op::DATA_END).unwrap().offset
}
