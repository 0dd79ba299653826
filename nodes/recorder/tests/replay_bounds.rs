//! `dc-replay` with values that used to panic, hang or spin: a rate beyond its bounds, a log time
//! far ahead, a loop over a file with nothing to publish. Each ends promptly with a clear message.

mod common;

use common::*;
use msgs::StepHeader;
use recorder::{FrameKind, RecordingWriter};
use runtime::BusConfig;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const DC_REPLAY: &str = env!("CARGO_BIN_EXE_dc-replay");

/// Runs `dc-replay` on its own bus namespace; kills it (and fails) past `limit`.
fn replay(test: &str, args: &[&str], limit: Duration) -> (Output, Duration) {
    let bus = BusConfig { namespace: namespace(test), queue_depth: 16, ..Default::default() };
    let mut child = Command::new(DC_REPLAY)
        .args(args)
        .env("DC_BUS", serde_json::to_string(&bus).unwrap())
        .env_remove("DC_LAUNCHED")
        .env_remove("DC_VALIDATE")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start dc-replay");
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!("dc-replay {args:?} still running after {limit:?}:\n{}", String::from_utf8_lossy(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    (child.wait_with_output().unwrap(), start.elapsed())
}

/// A recording of bodies frames at `log_times`; `garbage` frames instead do not decode.
fn recording(path: &Path, log_times: &[u64], garbage: bool) {
    let mut w = RecordingWriter::create(path).unwrap();
    w.add_channel("bodies", FrameKind::Bodies).unwrap();
    for (step, &t) in log_times.iter().enumerate() {
        let data = match garbage {
            true => vec![0xff; 16],
            false => msgs::encode(&bodies(StepHeader { run_id: 1, simulation: 0, step: step as u32 }, 4)).unwrap(),
        };
        w.write("bodies", FrameKind::Bodies, t, t, &data).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn a_rate_beyond_its_bounds_is_refused_without_a_panic() {
    let dir = scratch("replay-rate");
    let file = dir.join("r.mcap");
    recording(&file, &[1_000, 2_000], false);
    for rate in ["1e-300", "1e300", "-1", "nan"] {
        let rate_arg = format!("--rate={rate}");
        let (out, _) = replay("replay-rate", &["--input", file.to_str().unwrap(), &rate_arg], Duration::from_secs(20));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{rate}: {stderr}");
        assert!(stderr.contains("--rate") && stderr.contains("from 0.001 to 1000000"), "{rate}: {stderr}");
        assert!(!stderr.contains("panicked"), "{rate}: {stderr}");
    }
}

#[test]
fn a_log_time_far_ahead_is_replayed_after_a_clamped_gap() {
    let dir = scratch("replay-gap");
    let file = dir.join("r.mcap");
    let ms = 1_000_000u64;
    let mut times: Vec<u64> = (0..5).map(|i| 1_000_000_000 + i * 10 * ms).collect();
    times.push(times[4] + 1_000_000_000_000_000_000);
    recording(&file, &times, false);
    // At rate 10 the clamped gap (5 s recorded) is half a second.
    let (out, took) =
        replay("replay-gap", &["--input", file.to_str().unwrap(), "--rate", "10"], Duration::from_secs(30));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("published 6"), "{}", String::from_utf8_lossy(&out.stdout));
    assert!(took < Duration::from_secs(15), "took {took:?}");
    assert_eq!(stderr.matches("replayed as 5s").count(), 1, "said once:\n{stderr}");
}

#[test]
fn a_loop_over_a_file_with_nothing_to_publish_is_refused() {
    let dir = scratch("replay-loop");
    let file = dir.join("r.mcap");
    recording(&file, &[1_000, 2_000, 3_000], true);
    let input = file.to_str().unwrap();
    // Every message undecodable: the first pass publishes nothing, the loop stops there.
    let (out, _) = replay("replay-loop", &["--input", input, "--loop", "--rate", "0"], Duration::from_secs(20));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("published nothing") && stderr.contains(input), "{stderr}");
    assert!(stderr.matches("skipped an undecodable message").count() <= 3, "{stderr}");
    // No channel selected: refused before the first pass.
    let (out, _) =
        replay("replay-loop", &["--input", input, "--loop", "--topics", "contacts"], Duration::from_secs(20));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("nothing to publish") && stderr.contains("contacts"), "{stderr}");
}
