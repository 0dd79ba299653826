//! The bus between real processes: `dc launch` starts a publisher process and a subscriber process;
//! 10,000-body slices and 7x128x128 grids must arrive bit-identical, in order, none lost, over
//! iceoryx2 and over zenoh on 127.0.0.1; garbage on a zenoh topic is counted, not fatal. What
//! arrived is checked twice: by the sinks (which fail on a lost, late or altered frame) and by a
//! recorder tapping both topics, whose frames this test compares with the bench's contents.

use deep_contact::{launch, scratch_dir, text};
use msgs::{Body, GridHeader, StepHeader};
use std::path::Path;

/// Frames of each kind the sources publish.
const BODY_FRAMES: u32 = 60;
const GRID_FRAMES: u32 = 40;
/// Bodies per body frame.
const N: usize = 10_000;

/// A graph with a bodies pair and a grid pair, each verifying every frame, and a recorder tapping
/// both topics into `tap`.
fn verify_graph(zenoh: bool, garbage_every: u32, tap: &Path) -> String {
    let topics = if zenoh { "[topics]\n\"bench/bodies\" = \"zenoh\"\n\"bench/grid\" = \"zenoh\"\n" } else { "" };
    format!(
        r#"
[graph]
name = "verify"
{topics}
[[nodes]]
name = "bodies-sink"
binary = "dc-bench-bus"
params = {{ role = "sink", kind = "bodies", n = {N}, count = {BODY_FRAMES}, verify = true }}

[[nodes]]
name = "bodies-source"
binary = "dc-bench-bus"
params = {{ role = "source", kind = "bodies", n = {N}, count = {BODY_FRAMES}, verify = true, garbage-every = {garbage_every} }}

[[nodes]]
name = "grid-sink"
binary = "dc-bench-bus"
params = {{ role = "sink", kind = "grid", count = {GRID_FRAMES}, verify = true }}

[[nodes]]
name = "grid-source"
binary = "dc-bench-bus"
params = {{ role = "source", kind = "grid", count = {GRID_FRAMES}, verify = true, garbage-every = {garbage_every} }}

[[nodes]]
name = "tap"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "bench/bodies,bench/grid" }}
"#,
        tap.display()
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

/// What the bench source published as body frame `seq` (its own generator).
fn bench_bodies(seq: u32) -> Vec<Body> {
    let mut bodies = vec![Body::default(); N];
    bench_bus::fill_bodies(seq, &mut bodies);
    bodies
}

/// The bits of grid frame `seq` as the bench source published it.
fn bench_grid(seq: u32) -> Vec<u32> {
    let mut values = vec![0f32; 7 * 128 * 128];
    bench_bus::fill_grid(seq, &mut values);
    values.iter().map(|v| v.to_bits()).collect()
}

/// Checks the tap's recording: every frame of both sources, once, in order, bit for bit.
fn assert_tapped(tap: &Path, report: &str) {
    let mut reader =
        recorder::RecordingReader::open(tap).unwrap_or_else(|e| panic!("the tap's recording: {e}\n{report}"));
    let (mut bodies, mut grids) = (0u32, 0u32);
    while let Some(m) = reader.next_message() {
        let m = m.expect("an intact recording");
        match m.channel.topic.as_str() {
            "bench/bodies" => {
                let f = msgs::decode::<StepHeader, Body>(&m.data).unwrap();
                // Throughput phase (simulation 1), frame `bodies` next.
                assert_eq!((f.header.simulation, f.header.step), (1, bodies), "body frame out of order or lost");
                let expected = bench_bodies(bodies);
                let same = f.items.len() == N && f.items.iter().zip(&expected).all(|(a, b)| same_bits(a, b));
                assert!(same, "body frame {bodies}: {} bodies, contents differ from what was sent", f.items.len());
                bodies += 1;
            }
            "bench/grid" => {
                let f = msgs::decode::<GridHeader, f32>(&m.data).unwrap();
                let h = f.header;
                assert_eq!((h.step.simulation, h.step.step), (1, grids), "grid frame out of order or lost");
                assert_eq!((h.width, h.height, h.channels), (128, 128, 7), "grid frame {grids}");
                let names: Vec<String> = (0..7).map(|c| h.channel_name(c).to_string()).collect();
                assert_eq!(names, ["vx", "vy", "omega", "mass", "inertia", "normal", "tangent"]);
                let bits: Vec<u32> = f.items.iter().map(|v| v.to_bits()).collect();
                assert!(bits == bench_grid(grids), "grid frame {grids}: contents differ from what was sent");
                grids += 1;
            }
            other => panic!("unexpected topic `{other}` in the tap"),
        }
    }
    assert_eq!((bodies, grids), (BODY_FRAMES, GRID_FRAMES), "frames tapped (bodies, grids):\n{report}");
}

/// Bitwise equality of two bodies (floats compared by their bits).
fn same_bits(a: &Body, b: &Body) -> bool {
    let bits = |x: &Body| {
        [x.id, x.shape, x.size[0].to_bits(), x.size[1].to_bits(), x.mass.to_bits(), x.inertia.to_bits(), x.x.to_bits()]
            .into_iter()
            .chain([x.y.to_bits(), x.angle.to_bits(), x.vx.to_bits(), x.vy.to_bits(), x.omega.to_bits()])
            .collect::<Vec<u32>>()
    };
    bits(a) == bits(b)
}

/// Runs the graph; returns the sinks' result lines (decode errors are theirs to count).
fn assert_verified(zenoh: bool, garbage_every: u32, test: &str) -> (serde_json::Value, serde_json::Value) {
    let tap = scratch_dir(&format!("{test}-tap")).join("tap.mcap");
    let (_, out) = launch(test, &verify_graph(zenoh, garbage_every, &tap), &[]);
    // A sink that lost a frame, got one out of order or altered exits non-zero: the graph fails.
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let bodies = sink_result(&stdout, "bodies-sink");
    let grid = sink_result(&stdout, "grid-sink");
    assert_tapped(&tap, &text(&out));
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
params = { role = "sink", kind = "bodies", n = 100, count = 60, verify = true, start-delay-ms = 500, timeout-s = 10 }

[[nodes]]
name = "source"
binary = "dc-bench-bus"
params = { role = "source", kind = "bodies", n = 100, count = 60, verify = true, create-delay-ms = 200 }
"#;
    let (_, out) = launch("late-sink", graph, &[]);
    // The sink fails (`lost frames`, after its 10 s timeout) on a frame that never came, and on
    // one out of order or altered; its result line comes only once all 60 arrived.
    assert!(out.status.success(), "{}", text(&out));
    let r = sink_result(&String::from_utf8_lossy(&out.stdout), "late-sink");
    assert_eq!(r["decode_errors"], 0, "{r}");
}

/// The raw baseline (`--raw`: the transports' own APIs) carries the same frames as the runtime's
/// ports: every one arrives bit-identical and in order, over iceoryx2 and over zenoh, so the
/// benchmark compares like with like.
#[test]
fn the_raw_baseline_carries_the_same_frames_over_both_transports() {
    for zenoh in [false, true] {
        let topics = if zenoh { "[topics]\n\"bench/bodies\" = \"zenoh\"\n\"bench/grid\" = \"zenoh\"\n" } else { "" };
        let pair = |kind: &str, n: usize, count: u32| {
            (["sink", "source"].map(|role| {
                format!(
                    "[[nodes]]\nname = \"{kind}-{role}\"\nbinary = \"dc-bench-bus\"\nparams = {{ role = \"{role}\", kind = \"{kind}\", n = {n}, count = {count}, verify = true, raw = true }}\n"
                )
            }))
            .join("\n")
        };
        let graph = format!("{topics}\n{}\n{}", pair("bodies", N, BODY_FRAMES), pair("grid", N, GRID_FRAMES));
        let test = if zenoh { "raw-zenoh" } else { "raw-iox" };
        let (_, out) = launch(test, &graph, &[]);
        assert!(out.status.success(), "{test}: {}", text(&out));
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert_eq!(sink_result(&stdout, "bodies-sink")["verified"], BODY_FRAMES, "{test}");
        assert_eq!(sink_result(&stdout, "grid-sink")["verified"], GRID_FRAMES, "{test}");
    }
}

/// `dc bench bus --csv`: a row per payload and transport (in-process, raw and ours over
/// iceoryx2 and zenoh) with positive figures, and the ours/raw ratios on our rows only. Figures
/// are not judged here (they are the benchmark's to print).
#[test]
fn bench_bus_writes_every_case_and_the_ratios_to_raw() {
    let csv = scratch_dir("bench-bus-csv").join("bench-bus.csv");
    let out = std::process::Command::new(deep_contact::bin("dc"))
        .args(["bench", "bus", "--repeat", "1", "--count", "20", "--latency-count", "20", "--csv"])
        .arg(&csv)
        .output()
        .expect("run dc bench bus");
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.matches("ours / raw: iceoryx2 p50").count(), 3, "{stdout}");
    let table = std::fs::read_to_string(&csv).expect("the CSV");
    let mut lines = table.lines();
    assert_eq!(
        lines.next(),
        Some("payload,transport,p50_us,p99_us,frames_per_s,mb_per_s,p50_vs_raw,throughput_vs_raw")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 15, "{table}");
    for row in &rows {
        assert_eq!(row.len(), 8, "{row:?}");
        for figure in &row[2..6] {
            assert!(figure.parse::<f64>().is_ok_and(|v| v > 0.0), "{row:?}");
        }
        let ours = row[1] == "iceoryx2" || row[1] == "zenoh";
        assert_eq!(row[6].parse::<f64>().is_ok_and(|v| v > 0.0), ours, "{row:?}");
        assert_eq!(row[7].parse::<f64>().is_ok_and(|v| v > 0.0), ours, "{row:?}");
    }
    let transports: Vec<&str> = rows.iter().take(5).map(|r| r[1]).collect();
    assert_eq!(transports, ["inproc", "iceoryx2 raw", "iceoryx2", "zenoh raw", "zenoh"]);
}
