//! The bus between real processes: `dc launch` starts a publisher process and a subscriber process;
//! 10,000-body slices and 7x128x128 grids must arrive bit-identical, in order, none lost, over
//! iceoryx2 and over zenoh on 127.0.0.1; garbage on a zenoh topic is counted, not fatal.

use deep_contact::{launch, text};

/// A graph with a bodies pair and a grid pair, each verifying every frame.
fn verify_graph(zenoh: bool, garbage_every: u32) -> String {
    let topics = if zenoh { "[topics]\n\"bench/bodies\" = \"zenoh\"\n\"bench/grid\" = \"zenoh\"\n" } else { "" };
    format!(
        r#"
[graph]
name = "verify"
{topics}
[[nodes]]
name = "bodies-sink"
binary = "dc-bench-bus"
params = {{ role = "sink", kind = "bodies", n = 10000, count = 60, verify = true }}

[[nodes]]
name = "bodies-source"
binary = "dc-bench-bus"
params = {{ role = "source", kind = "bodies", n = 10000, count = 60, verify = true, garbage-every = {garbage_every} }}

[[nodes]]
name = "grid-sink"
binary = "dc-bench-bus"
params = {{ role = "sink", kind = "grid", count = 40, verify = true }}

[[nodes]]
name = "grid-source"
binary = "dc-bench-bus"
params = {{ role = "source", kind = "grid", count = 40, verify = true, garbage-every = {garbage_every} }}
"#
    )
}

/// The JSON result line a sink printed (stdout lines are prefixed `[name] `).
fn sink_result(stdout: &str, sink: &str) -> serde_json::Value {
    let prefix = format!("[{sink}");
    let line = stdout
        .lines()
        .filter(|l| l.starts_with(&prefix))
        .filter_map(|l| l.split_once("] ").map(|(_, rest)| rest))
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no result line from {sink} in:\n{stdout}"));
    serde_json::from_str(line).expect("sink result is JSON")
}

fn assert_verified(zenoh: bool, garbage_every: u32, test: &str) -> (serde_json::Value, serde_json::Value) {
    let (_, out) = launch(test, &verify_graph(zenoh, garbage_every), &[]);
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let bodies = sink_result(&stdout, "bodies-sink");
    let grid = sink_result(&stdout, "grid-sink");
    assert_eq!(bodies["verified"], 60, "{bodies}");
    assert_eq!(bodies["bytes_per_frame"], 10_000 * 48);
    assert_eq!(grid["verified"], 40, "{grid}");
    assert_eq!(grid["bytes_per_frame"], 7 * 128 * 128 * 4);
    (bodies, grid)
}

#[test]
fn bodies_and_grids_arrive_bit_identical_in_order_over_iceoryx2() {
    assert_verified(false, 0, "iox-verify");
}

#[test]
fn bodies_and_grids_arrive_bit_identical_in_order_over_zenoh() {
    let (bodies, grid) = assert_verified(true, 0, "zenoh-verify");
    assert_eq!(bodies["decode_errors"], 0);
    assert_eq!(grid["decode_errors"], 0);
}

#[test]
fn garbage_payloads_on_zenoh_are_counted_and_the_subscriber_keeps_running() {
    // A truncated/garbage payload before every 10th frame: 6 of 60 body frames, 4 of 40 grid frames.
    let (bodies, grid) = assert_verified(true, 10, "zenoh-garbage");
    assert_eq!(bodies["decode_errors"], 6, "{bodies}");
    assert_eq!(grid["decode_errors"], 4, "{grid}");
}

#[test]
fn a_subscriber_that_polls_late_still_loses_nothing() {
    // The source's publisher appears after the sink's subscriber, and the sink polls late: 60
    // frames, queue depth 16 — the source must wait for the sleeping sink, not drop frames.
    let graph = r#"
[[nodes]]
name = "late-sink"
binary = "dc-bench-bus"
params = { role = "sink", kind = "bodies", n = 100, count = 60, verify = true, start-delay-ms = 500 }

[[nodes]]
name = "source"
binary = "dc-bench-bus"
params = { role = "source", kind = "bodies", n = 100, count = 60, verify = true, create-delay-ms = 200 }
"#;
    let (_, out) = launch("late-sink", graph, &[]);
    assert!(out.status.success(), "{}", text(&out));
    let r = sink_result(&String::from_utf8_lossy(&out.stdout), "late-sink");
    assert_eq!(r["verified"], 60, "{r}");
}
