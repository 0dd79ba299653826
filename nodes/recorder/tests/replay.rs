//! `dc-replay`'s options, checked by what a subscriber on the bus receives: `--input` a folder
//! (its recordings in name order), `--topics`, `--remap`, `--loop` and `--rate`.

mod common;

use common::*;
use msgs::{Body, Contact, StepHeader};
use recorder::{FrameKind, RecordingWriter};
use runtime::{BusConfig, Node};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const DC_REPLAY: &str = env!("CARGO_BIN_EXE_dc-replay");

/// Steps per recording.
const STEPS: u32 = 4;
/// Recorded time between two steps.
const SPACING: Duration = Duration::from_millis(100);
/// `--rate`: half the recorded pace, so a file's steps take twice their recorded span.
const RATE: f64 = 0.5;
/// Bodies per frame.
const N: usize = 4;

/// A recording of run `run_id`: per step a bodies and a contacts frame, steps `SPACING` apart.
fn recording(path: &Path, run_id: u64) {
    let mut w = RecordingWriter::create(path).unwrap();
    w.add_channel("bodies", FrameKind::Bodies).unwrap();
    w.add_channel("contacts", FrameKind::Contacts).unwrap();
    for step in 0..STEPS {
        let s = StepHeader { run_id, simulation: 0, step };
        let t = 1_000_000_000 + step as u64 * SPACING.as_nanos() as u64;
        w.write("bodies", FrameKind::Bodies, t, t, &msgs::encode(&bodies(s, N)).unwrap()).unwrap();
        w.write("contacts", FrameKind::Contacts, t + 1, t + 1, &msgs::encode(&contacts(s, 2)).unwrap()).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn replay_of_a_folder_selects_remaps_loops_and_paces_what_subscribers_receive() {
    let dir = scratch("replay-options");
    let input = dir.join("recordings");
    std::fs::create_dir_all(&input).unwrap();
    // Written in another order than their names (a, c, b: another cycle, which a loop cannot
    // rotate into a, b, c): the folder plays in name order.
    recording(&input.join("a.mcap"), 1);
    recording(&input.join("c.mcap"), 3);
    recording(&input.join("b.mcap"), 2);

    let bus = BusConfig { namespace: namespace("replay-options"), queue_depth: 16, ..Default::default() };
    // Our subscribers first: the replay publishes as soon as it runs (no launcher to wait for).
    let node = Node::new("replay-test", bus.clone(), false);
    let mut remapped = node.subscriber_named::<StepHeader, Body>("bench/bodies").unwrap();
    let mut original = node.subscriber_named::<StepHeader, Body>("bodies").unwrap();
    let mut unselected = node.subscriber_named::<StepHeader, Contact>("contacts").unwrap();
    let mut replay = Command::new(DC_REPLAY)
        .arg("--input")
        .arg(&input)
        .args(["--topics", "bodies", "--remap", "bodies=bench/bodies", "--loop", "--rate", &RATE.to_string()])
        .env("DC_BUS", serde_json::to_string(&bus).unwrap())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start dc-replay");

    // What arrives, until it holds a whole pass of a, b, c, then a again (the first frames may go
    // out before our subscriber attached: the loop replays them).
    let expected: Vec<(u64, u32)> = [1, 2, 3, 1].iter().flat_map(|&run| (0..STEPS).map(move |s| (run, s))).collect();
    let mut got: Vec<(u64, u32, Instant)> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    let found = loop {
        assert!(Instant::now() < deadline, "no a, b, c, a sequence within 60 s; got {:?}", keys(&got));
        if let Some(r) = remapped.recv_timeout(Duration::from_millis(100)).unwrap() {
            let f = r.into_frame();
            assert_eq!(f.items, bodies(f.header, N).items, "frame {:?} differs from the recorded one", f.header);
            got.push((f.header.run_id, f.header.step, Instant::now()));
        }
        assert!(original.try_recv().unwrap().is_none(), "a frame arrived on `bodies`: it was remapped");
        assert!(unselected.try_recv().unwrap().is_none(), "a frame arrived on `contacts`: it was not selected");
        let first_a = got.iter().position(|g| (g.0, g.1) == (1, 0));
        if let Some(i) = first_a.filter(|i| got.len() >= i + expected.len()) {
            break i;
        }
    };
    unsafe { libc::kill(replay.id() as libc::pid_t, libc::SIGINT) };
    let stop = Instant::now() + Duration::from_secs(10);
    while replay.try_wait().unwrap().is_none() && Instant::now() < stop {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = replay.kill();
    let out = replay.wait_with_output().unwrap();
    assert!(out.status.success(), "dc-replay stopped with {}:\n{}", out.status, String::from_utf8_lossy(&out.stderr));

    // Every frame of a, b, c (name order), then a again (the loop), each once, in step order.
    let window = &got[found..found + expected.len()];
    assert_eq!(keys(window), expected, "all received: {:?}", keys(&got));
    // Paced at half the recorded speed: a file's first to last step is 3 x 100 ms recorded, so at
    // least 0.6 s received (less a few ms of delivery of the first frame); at the recorded pace
    // (rate 1) it would be 0.3 s.
    let least = SPACING.as_secs_f64() * (STEPS - 1) as f64 / RATE - 0.05;
    for pass in window.chunks(STEPS as usize) {
        let span = pass[pass.len() - 1].2.duration_since(pass[0].2).as_secs_f64();
        assert!(span >= least, "run {}: its steps arrived within {span:.3} s, expected >= {least:.3} s", pass[0].0);
    }
    // The replay counted what it published; nothing was undecodable.
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("skipped 0 undecodable"), "{stdout}");
}

fn keys(got: &[(u64, u32, Instant)]) -> Vec<(u64, u32)> {
    got.iter().map(|g| (g.0, g.1)).collect()
}
