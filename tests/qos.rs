//! Per-topic delivery (`[qos]` in launch files): a viewer that subscribes to the simulator's
//! `bodies` and never reads cannot hold the simulator back when the topic is best effort (over
//! iceoryx2 and over zenoh), while the reliable topics beside it lose nothing. (On a reliable
//! topic the same viewer stops the simulator as soon as its queue is full: the graph would never
//! end.) The steps per second with and without the viewer are printed, not asserted; the README
//! quotes them.

use deep_contact::{bin, scratch_dir, text, unique_namespace};
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const SEEDS: &str = "0..2";
const STEPS: u32 = 150;

fn graph(out: &Path, viewer: bool, over_zenoh: bool) -> String {
    let topics = if over_zenoh { "[topics]\n\"bodies\" = \"zenoh\"\n" } else { "" };
    let viewer = if viewer {
        "[[nodes]]\nname = \"viewer\"\nbinary = \"dc-bench-bus\"\ndaemon = true\n\
         params = { role = \"sink\", kind = \"bodies\", topic = \"bodies\", stall = true }\n"
    } else {
        ""
    };
    format!(
        r#"
[qos]
"bodies" = "best-effort"
{topics}
{viewer}
[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "stats/solve,control" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ model = "builtin", seeds = "{SEEDS}", steps = {STEPS} }}
"#,
        out.display()
    )
}

/// Runs `dc launch` on `text`, failing the test if it does not end within two minutes (a
/// publisher held back for good).
fn launch_within(test: &str, text_: &str) -> Output {
    let dir = scratch_dir(test);
    let file = dir.join("graph.toml");
    std::fs::write(&file, text_).unwrap();
    let mut child = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace(test)])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("{test}: the graph did not end within 120 s: {}", text(&child.wait_with_output().unwrap()));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// (steps per second of the simulator's loop, stats/solve frames recorded).
fn run(test: &str, viewer: bool, over_zenoh: bool) -> (f64, usize) {
    let out_file = scratch_dir(&format!("{test}-rec")).join("stats.mcap");
    let out = launch_within(test, &graph(&out_file, viewer, over_zenoh));
    assert!(out.status.success(), "{test}: {}", text(&out));
    let all = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    let runs = msgs::control::RunSummary::find_in(all.lines()).unwrap();
    assert_eq!(runs.len(), 1, "{}", text(&out));
    let mut reader = recorder::RecordingReader::open(&out_file).expect("the recording");
    let mut stats = 0;
    while let Some(m) = reader.next_message() {
        if m.expect("an intact recording").channel.topic == "stats/solve" {
            stats += 1;
        }
    }
    (runs[0].steps as f64 / runs[0].loop_secs, stats)
}

#[test]
fn a_stuck_viewer_on_a_best_effort_topic_never_holds_the_simulator_back() {
    let expected = 2 * STEPS as usize;
    let (alone, n) = run("qos-alone", false, false);
    assert_eq!(n, expected, "every statistics frame recorded");
    for (label, over_zenoh) in [("iceoryx2", false), ("zenoh", true)] {
        let (with_viewer, n) = run(&format!("qos-{label}"), true, over_zenoh);
        // The reliable topic beside the best-effort one lost nothing.
        assert_eq!(n, expected, "{label}: every statistics frame recorded");
        eprintln!(
            "{label}: simulator {with_viewer:.0} steps/s with a stuck viewer on best-effort `bodies`, \
             {alone:.0} without: ratio {:.2}",
            with_viewer / alone
        );
    }
}
