//! A graph that survives a fault: the inference node is killed (SIGKILL) mid-run; the simulator,
//! told by the launcher, falls back to its built-in warm start and says so in its statistics; the
//! launcher restarts the node (its policy) and the simulator uses it again. The report's fallback
//! count is non-zero and exactly the number of steps solved while the node was away.

use deep_contact::{bin, report_steps, scratch_dir, unique_namespace};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_killed_inference_node_is_restarted_and_the_simulator_falls_back_meanwhile() {
    let dir = scratch_dir("fault");
    let report = dir.join("report");
    let file = dir.join("graph.toml");
    let graph = format!(
        r#"
[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ models = "unet", seeds = "0..3", steps = 60, n = 40, deadline = "none" }}

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
params = {{ model = "models/unet-demo.dcu" }}

[[nodes]]
name = "metrics"
binary = "dc-metrics"
params = {{ runs = 1, out = "{}" }}
"#,
        report.display()
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
    assert!(log.contains("grid producer down: falling back"), "{log}");

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
}

fn text_hint(log: &str) -> &str {
    &log[log.len().saturating_sub(3000)..]
}
