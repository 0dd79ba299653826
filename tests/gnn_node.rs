//! The contact-graph network as a node (`dc-gnn` serving `warm/gnn`, the simulator's `gnn-node`
//! model, and `gnn-pipelined`, served one step ahead): over the bus it gives the in-process
//! model's sweeps step for step; killed mid-run, the simulator falls back to builtin (counted)
//! until the launcher has restarted it, then uses it again.

use deep_contact::{bin, report_steps, scratch_dir, text, unique_namespace};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/gnn.dcg");

fn graph(model: &str, gnn_node: bool, report: &std::path::Path, seeds: &str, steps: u32) -> String {
    let node = if gnn_node {
        format!(
            "[[nodes]]\nname = \"gnn\"\nbinary = \"dc-gnn\"\ndaemon = true\non_failure = \"restart\"\nmax_restarts = 2\n\
             params = {{ model = \"{MODEL}\" }}\n"
        )
    } else {
        String::new()
    };
    format!(
        r#"
{node}
[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ models = "{model}", gnn-model = "{MODEL}", seeds = "{seeds}", steps = {steps}, deadline = "none" }}

[[nodes]]
name = "metrics"
binary = "dc-metrics"
params = {{ runs = 1, out = "{}" }}
"#,
        report.display()
    )
}

#[test]
fn served_over_the_bus_the_network_gives_the_in_process_sweeps_step_for_step() {
    let dir = scratch_dir("gnn-node");
    let run = |model: &str, gnn_node: bool| {
        let report = dir.join(model);
        let file = dir.join(format!("{model}.toml"));
        std::fs::write(&file, graph(model, gnn_node, &report, "0..2", 80)).unwrap();
        let out = Command::new(bin("dc"))
            .arg("launch")
            .arg(&file)
            .args(["--namespace", &unique_namespace(model)])
            .output()
            .unwrap();
        assert!(out.status.success(), "{model}: {}", text(&out));
        report_steps(&report)
    };
    let (local, served) = (run("gnn", false), run("gnn-node", true));
    assert_eq!(served.len(), 160);
    assert!(served.values().all(|(_, fallback, used)| !fallback && used == "gnn-node"), "lockstep: no fallback");
    for (key, (sweeps, _, _)) in &local {
        assert_eq!(Some(sweeps), served.get(key).map(|s| &s.0), "simulation {} step {}", key.0, key.1);
    }
}

#[test]
fn a_killed_gnn_node_is_restarted_and_the_simulator_falls_back_meanwhile() {
    killed_node_falls_back_then_serves_again("gnn-node");
}

/// The same for the network served one step ahead: its predictions are asked for after each
/// step; while the node is away every asked-for step falls back, counted, and once restarted it
/// predicts again.
#[test]
fn a_killed_pipelined_gnn_node_is_restarted_and_the_simulator_falls_back_meanwhile() {
    killed_node_falls_back_then_serves_again("gnn-pipelined");
}

/// Kills the `dc-gnn` node serving `model` once the first simulation is done: the steps solved
/// while it is away fall back to builtin (counted), and the restarted node serves again.
fn killed_node_falls_back_then_serves_again(model: &str) {
    let dir = scratch_dir(&format!("{model}-fault"));
    let report = dir.join("report");
    let file = dir.join("graph.toml");
    std::fs::write(&file, graph(model, true, &report, "0..4", 250)).unwrap();
    let mut child = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace(&format!("{model}-fault"))])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let (mut log, mut pid, mut killed) = (Vec::new(), None::<i32>, false);
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        assert!(start.elapsed() < Duration::from_secs(120), "graph did not finish:\n{}", log.join("\n"));
        while let Ok(line) = rx.recv_timeout(Duration::from_millis(20)) {
            if let Some(rest) = line.strip_prefix("[dc] node `gnn` started (pid ") {
                pid = pid.or(rest.trim_end_matches(')').parse().ok());
            }
            // Killed once the first simulation is done: the next ones start without it.
            if !killed && line.contains("[sim") && line.contains("simulation done") {
                assert_eq!(unsafe { libc::kill(pid.expect("the launcher names the pid"), libc::SIGKILL) }, 0);
                killed = true;
            }
            log.push(line);
        }
    }
    log.extend(rx.try_iter());
    let status = child.wait().unwrap();
    let log = log.join("\n");
    assert!(killed && status.success(), "status {status}:\n{log}");
    assert!(log.contains("node `gnn` exited with signal 9: restarting it (1 of at most 2)"), "{log}");
    assert!(log.contains("warm-start producer down: falling back"), "{log}");

    let steps = report_steps(&report);
    assert_eq!(steps.len(), 1000, "every step of 4 simulations x 250");
    let fallbacks: Vec<_> = steps.iter().filter(|(_, (_, f, _))| *f).map(|(k, _)| *k).collect();
    assert!(!fallbacks.is_empty(), "steps solved while the node was away fall back");
    for ((sim, step), (_, fallback, used)) in &steps {
        assert_eq!(used == "builtin", *fallback, "simulation {sim} step {step}: used {used}");
    }
    assert!(fallbacks.iter().all(|(sim, _)| *sim >= 1), "the first simulation ran before the kill: {fallbacks:?}");
    let last_fallback = *fallbacks.last().unwrap();
    assert!(
        steps.iter().any(|(k, (_, _, used))| *k > last_fallback && used == model),
        "the restarted node serves again after the last fallback {last_fallback:?}"
    );
}
