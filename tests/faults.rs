//! A graph that survives a fault: the inference node is killed (SIGKILL) mid-run; the simulator,
//! told by the launcher, falls back to its built-in warm start and says so in its statistics; the
//! launcher restarts the node (its policy) and the simulator uses it again. The report's fallback
//! count is non-zero and exactly the number of steps solved while the node was away, and a
//! recorder's view of the run puts those steps between the launcher's node-down and node-up
//! notices.

use deep_contact::{bin, report_steps, scratch_dir, unique_namespace, UNET_DEMO};
use msgs::{ControlDetails, ControlKind, SolveStatsHeader};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What the recorder took, in its order: the launcher's notices about the U-Net node and the
/// simulator's steps.
#[derive(Debug)]
enum Seen {
    Down,
    Up,
    /// A step; `wait_s`: how long its warm start took (the wait for the node's grid included).
    Step {
        sim: u32,
        step: u32,
        fallback: bool,
        wait_s: f64,
        log_time: u64,
    },
}

fn timeline(file: &Path) -> Vec<Seen> {
    let mut reader = recorder::RecordingReader::open(file).expect("the recording");
    let mut out = Vec::new();
    while let Some(m) = reader.next_message() {
        let m = m.expect("an intact recording");
        match m.channel.topic.as_str() {
            "stats/solve" => {
                let h: SolveStatsHeader = msgs::decode_header(&m.data).unwrap();
                let (sim, step, fallback, wait_s) =
                    (h.step.simulation, h.step.step, h.fallback != 0, h.warm_start_us as f64 * 1e-6);
                out.push(Seen::Step { sim, step, fallback, wait_s, log_time: m.log_time });
            }
            "control" => {
                let c = msgs::decode::<msgs::Control, u8>(&m.data).unwrap();
                match (c.header.kind(), c.details()) {
                    (Some(ControlKind::NodeDown), Ok(ControlDetails::NodeDown(n))) if n.node == "unet" => {
                        out.push(Seen::Down)
                    }
                    (Some(ControlKind::NodeUp), Ok(ControlDetails::NodeUp(n))) if n.node == "unet" => {
                        out.push(Seen::Up)
                    }
                    _ => {}
                }
            }
            _ => {}
        }
    }
    out
}

/// The timeline for an assertion message: steps as `sim:step` (`*` fell back), notices by name.
fn show(seen: &[Seen]) -> String {
    let words: Vec<String> = seen
        .iter()
        .map(|s| match s {
            Seen::Down => "DOWN".to_string(),
            Seen::Up => "UP".to_string(),
            Seen::Step { sim, step, fallback, .. } => format!("{sim}:{step}{}", if *fallback { "*" } else { "" }),
        })
        .collect();
    words.join(" ")
}

#[test]
fn a_killed_inference_node_is_restarted_and_the_simulator_falls_back_meanwhile() {
    let dir = scratch_dir("fault");
    let report = dir.join("report");
    let recording = dir.join("run.mcap");
    let file = dir.join("graph.toml");
    let graph = format!(
        r#"
[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ models = "unet", seeds = "0..3", steps = 60, n = 40, deadline = "none", lockstep-timeout = "60s" }}

[[nodes]]
name = "sph"
binary = "dc-sph"
daemon = true
params = {{ mode = "preserving", temporal = true, pad-to = 128 }}

[[nodes]]
name = "unet"
binary = "dc-unet"
daemon = true
on_failure = "restart"
max_restarts = 2
params = {{ model = "{UNET_DEMO}" }}

[[nodes]]
name = "metrics"
binary = "dc-metrics"
params = {{ runs = 1, out = "{}" }}

[[nodes]]
name = "rec"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "stats/solve,control" }}
"#,
        report.display(),
        recording.display()
    );
    std::fs::write(&file, graph).unwrap();
    let mut child = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace("fault")])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start dc launch");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut log = Vec::new();
    let mut unet_pid: Option<i32> = None;
    let mut killed = false;
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        assert!(start.elapsed() < Duration::from_secs(400), "graph did not finish:\n{}", log.join("\n"));
        while let Ok(line) = rx.recv_timeout(Duration::from_millis(50)) {
            if let Some(rest) = line.strip_prefix("[dc] node `unet` started (pid ") {
                unet_pid = unet_pid.or(rest.trim_end_matches(')').parse().ok());
            }
            // Kill it once the first simulation is done: the second one is solved without it.
            if !killed && line.contains("[sim") && line.contains("simulation done") {
                let pid = unet_pid.expect("the launcher names the node's pid");
                assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0, "kill dc-unet");
                killed = true;
            }
            log.push(line);
        }
    }
    for line in rx.try_iter() {
        log.push(line);
    }
    let status = child.wait().unwrap();
    let log = log.join("\n");
    assert!(killed, "never saw a simulation finish:\n{log}");
    assert!(status.success(), "status {status}:\n{log}");
    assert!(log.contains("node `unet` exited with signal 9: restarting it (1 of at most 2)"), "{log}");
    assert!(log.contains("node `unet` is back (restart 1)"), "{log}");
    assert!(log.contains("producer down: falling back"), "{log}");

    let steps = report_steps(&report);
    assert_eq!(steps.len(), 180, "every step of 3 simulations x 60 is in the report");
    let fallbacks: Vec<_> = steps.iter().filter(|(_, (_, fallback, _))| *fallback).map(|(k, _)| *k).collect();
    assert!(!fallbacks.is_empty(), "steps solved while the node was away fall back");
    // Fell back to builtin exactly on those steps; every other step used the U-Net.
    for ((sim, step), (_, fallback, used)) in &steps {
        assert_eq!(used == "builtin", *fallback, "simulation {sim} step {step}: used {used}, fallback {fallback}");
    }
    // The first simulation ran before the kill; the last one after the restart uses the U-Net again.
    assert!(fallbacks.iter().all(|(sim, _)| *sim >= 1), "{fallbacks:?}");
    assert!(steps.iter().any(|((sim, _), (_, _, used))| *sim == 2 && used == "unet"), "resumed after the restart");
    // The summary counts the same fallbacks.
    let summary = std::fs::read_to_string(report.join("summary.csv")).unwrap();
    let header: Vec<&str> = summary.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "fallbacks").unwrap();
    let row: Vec<&str> = summary.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(row[col].parse::<usize>().unwrap(), fallbacks.len(), "{summary}\n{}", text_hint(&log));

    // The fallbacks against the launcher's timeline, in the order the recorder took them.
    let seen = timeline(&recording);
    let at = |notice: fn(&Seen) -> bool| {
        let found: Vec<usize> = seen.iter().enumerate().filter(|(_, s)| notice(s)).map(|(i, _)| i).collect();
        assert_eq!(found.len(), 1, "one such notice: {}", show(&seen));
        found[0]
    };
    let (down, up) = (at(|s| matches!(s, Seen::Down)), at(|s| matches!(s, Seen::Up)));
    assert!(down < up, "{}", show(&seen));
    // (position, fell back, log time, warm-start wait, step) of each step.
    let recorded: Vec<(usize, bool, u64, f64, u32)> = seen
        .iter()
        .enumerate()
        .filter_map(|(i, s)| match s {
            Seen::Step { fallback, log_time, wait_s, step, .. } => Some((i, *fallback, *log_time, *wait_s, *step)),
            _ => None,
        })
        .collect();
    // A simulation's step 0 has no previous step, hence no grid to wait for: zero is the model's
    // own answer there, never a fallback, even while the node is down (an outage can span a
    // simulation's start).
    let asks_the_node = |s: &&(usize, bool, u64, f64, u32)| s.4 > 0;
    assert_eq!(recorded.len(), 180, "every step recorded: {}", show(&seen));
    let fell: Vec<usize> = recorded.iter().filter(|s| s.1).map(|s| s.0).collect();
    let (first, last) = (fell[0], fell[fell.len() - 1]);
    // One outage, one unbroken run of fallbacks: no step between them used the U-Net.
    assert!(recorded.iter().filter(asks_the_node).all(|s| s.1 == (first..=last).contains(&s.0)), "{}", show(&seen));
    // It began with the node-down notice. The recorder takes each pass's steps before its control
    // messages, so steps of the notice's own pass (one log time, just before it) may have been
    // solved after the notice; no earlier step fell back.
    let notice_pass = match recorded.iter().rev().find(|s| s.0 < down) {
        Some(&(_, _, t, _, _)) => recorded.iter().find(|s| s.0 < down && s.2 == t).map_or(down, |s| s.0),
        None => down,
    };
    assert!(first >= notice_pass, "a step fell back before the node was down: {}", show(&seen));
    // Between the notices every step fell back, but for at most 2 just after the down notice: one
    // solved from a grid the node sent before it died, one the recorder took in the same instant.
    let used_between = recorded.iter().filter(asks_the_node).filter(|s| s.0 > down && s.0 < up && !s.1).count();
    assert!(used_between <= 2, "{used_between} steps used the U-Net while it was down: {}", show(&seen));
    // After the node-up notice at most 2 steps fell back: the one in flight, whose input the
    // restarted node never saw (it waits --resume-patience, then falls back), and one in the
    // same instant. The U-Net is used again from then on (one unbroken run, above).
    let after_up = recorded.iter().filter(|s| s.0 > up && s.1).count();
    assert!(after_up <= 2, "{after_up} steps fell back after the node-up notice: {}", show(&seen));
    // The simulator heard the notices: a step falls back at once while the node is down and
    // after --resume-patience (2 s) once it is back, never after the 60 s lockstep timeout it
    // would wait out without them. 10 s: a wide bound for a loaded machine.
    let longest = recorded.iter().filter(|s| s.1).map(|s| s.3).fold(0.0, f64::max);
    assert!(longest < 10.0, "a step waited {longest:.1} s for the node before falling back: {}", show(&seen));
    eprintln!(
        "{} steps fell back: {} between the notices, {after_up} after the node-up notice; longest wait {longest:.2} s",
        fell.len(),
        fell.iter().filter(|&&i| i > down && i < up).count()
    );
}

fn text_hint(log: &str) -> &str {
    &log[log.len().saturating_sub(3000)..]
}
