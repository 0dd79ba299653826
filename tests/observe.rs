//! A running graph seen from another terminal: `dc topic list | echo | hz | bw`, `dc record -a`
//! and `dc play`, run as users run them (real processes, beside a graph started by `dc launch`),
//! their output checked against what the simulator published (the graph's own recorder), and
//! the simulator's sweeps checked unchanged by them.

use deep_contact::{bin, scratch_dir, text, unique_namespace};
use recorder::read::RecordingReader;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A simulator paced at 100 steps/s (so observers started after it see most of it) and the
/// graph's own recorder of every topic: the reference.
fn graph(recording: &Path, topics: &str, steps: u32) -> String {
    format!(
        r#"[graph]
name = "observed"
{topics}
[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "control,bodies,contacts,stats/solve", "flush-ms" = 200 }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0..2", steps = {steps}, model = "builtin", n = 30, "step-period" = "10ms" }}
"#,
        recording.display()
    )
}

fn start(dir: &Path, name: &str, graph_text: &str, namespace: &str) -> Child {
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, graph_text).unwrap();
    Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", namespace])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run dc")
}

/// Every frame of `topic` in a recording, by (simulation, step), read strictly.
fn frames(recording: &Path, topic: &str) -> BTreeMap<(u32, u32), Vec<u8>> {
    recorder::Info::read(recording).unwrap_or_else(|e| panic!("{}: not intact: {e}", recording.display()));
    let mut reader = RecordingReader::open(recording).unwrap();
    let mut out = BTreeMap::new();
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        if m.channel.topic == topic {
            let step = m.channel.kind.unwrap().step_of(&m.data).unwrap();
            out.insert((step.simulation, step.step), m.data.clone());
        }
    }
    out
}

fn sweeps(recording: &Path) -> BTreeMap<(u32, u32), u32> {
    frames(recording, "stats/solve")
        .into_iter()
        .map(|(k, data)| (k, msgs::decode_header::<msgs::SolveStatsHeader>(&data).unwrap().sweeps))
        .collect()
}

fn dc(args: &[&str]) -> Command {
    let mut c = Command::new(bin("dc"));
    c.args(args).stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

/// Ctrl-C to `child`, then [`finish`]: its output once it has stopped.
fn interrupt(child: Child, limit: Duration, what: &str) -> Output {
    let _ = Command::new("kill").arg("-INT").arg(child.id().to_string()).status();
    finish(child, limit, what)
}

/// Waits for `child` at most `limit` (then kills it and fails, with what it said).
fn finish(child: Child, limit: Duration, what: &str) -> Output {
    let pid = child.id();
    let started = Instant::now();
    let watchdog = std::thread::spawn(move || {
        while started.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(100));
            if unsafe { libc::kill(pid as i32, 0) } != 0 {
                return false;
            }
        }
        unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        true
    });
    let out = child.wait_with_output().unwrap();
    let killed = watchdog.join().unwrap();
    assert!(!killed, "{what} still running after {limit:?}: {}", text(&out));
    out
}

/// A zenoh session of our own on a graph's router, as a foreign peer opens one (no TLS).
fn foreign_session(endpoint: &str) -> runtime::zenoh::Session {
    use runtime::zenoh::Wait;
    let mut config = runtime::zenoh::Config::default();
    let settings = [
        ("mode", "\"peer\"".to_string()),
        ("connect/endpoints", format!("[\"{endpoint}\"]")),
        ("listen/endpoints", "[\"tcp/127.0.0.1:0\"]".to_string()),
        ("scouting/multicast/enabled", "false".to_string()),
    ];
    for (k, v) in settings {
        config.insert_json5(k, &v).unwrap();
    }
    runtime::zenoh::open(config).wait().unwrap()
}

/// Waits until `dc topic list` shows `topic` written in `namespace` (the graph is up).
fn wait_for_writer(namespace: &str, topic: &str, zenoh: Option<&str>) {
    let started = Instant::now();
    loop {
        let mut args = vec!["topic", "list", "--namespace", namespace];
        if let Some(e) = zenoh {
            args.extend(["--zenoh", e]);
        }
        let out = dc(&args).output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        if stdout.lines().any(|l| {
            let cols: Vec<&str> = l.split_whitespace().collect();
            cols.get(1) == Some(&topic) && cols.get(3).is_some_and(|w| *w != "0")
        }) {
            return;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "`{topic}` never showed a writer: {}", text(&out));
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The last line of `out`'s stdout that starts with `prefix`.
fn last_line<'a>(stdout: &'a str, prefix: &str) -> &'a str {
    stdout.lines().rev().find(|l| l.starts_with(prefix)).unwrap_or_else(|| panic!("no `{prefix}` line in:\n{stdout}"))
}

#[test]
fn observers_see_what_the_simulator_published_and_change_none_of_its_sweeps() {
    let dir = scratch_dir("observe");
    let namespace = unique_namespace("observe");
    let reference = dir.join("reference.mcap");
    let attached = dir.join("attached.mcap");
    let graph_run = start(&dir, "observed", &graph(&reference, "", 150), &namespace);
    wait_for_writer(&namespace, "bodies", None);

    let ns = namespace.as_str();
    let record = dc(&["record", "-a", "--namespace", ns, "-o", attached.to_str().unwrap()]).spawn().unwrap();
    let echo = dc(&["topic", "echo", "stats/solve", "--namespace", ns, "--json"]).spawn().unwrap();
    let hz = dc(&["topic", "hz", "bodies", "--namespace", ns, "--window", "100"]).spawn().unwrap();
    let bw = dc(&["topic", "bw", "bodies", "--namespace", ns, "--window", "100"]).spawn().unwrap();
    let echo_items = dc(&["topic", "echo", "bodies", "--namespace", ns, "--count", "1", "--items"]).output().unwrap();

    // Bad input while the graph runs: an unknown topic, a namespace without a graph.
    let unknown = dc(&["topic", "echo", "no/such", "--namespace", ns]).output().unwrap();
    assert_eq!(unknown.status.code(), Some(1), "{}", text(&unknown));
    let err = String::from_utf8_lossy(&unknown.stderr);
    assert!(
        err.contains("`no/such` is not a Deep Contact topic")
            && err.contains("(alive: bodies, contacts, control, stats/solve)"),
        "{err}"
    );
    let not_written = dc(&["topic", "hz", "grid/bodies", "--namespace", ns]).output().unwrap();
    assert_eq!(not_written.status.code(), Some(1), "{}", text(&not_written));
    assert!(
        String::from_utf8_lossy(&not_written.stderr).contains("`grid/bodies` is not alive"),
        "{}",
        text(&not_written)
    );
    for args in [vec!["topic", "echo", "bodies"], vec!["topic", "list"], vec!["record", "-a"]] {
        let out = dc(&[&args[..], &["--namespace", "no-graph-here"]].concat()).output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}: {}", text(&out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("no topics alive in namespace `no-graph-here`"), "{args:?}: {}", text(&out));
    }

    // The observers end with the graph (its writers gone).
    let limit = Duration::from_secs(120);
    let graph_out = finish(graph_run, limit, "the graph");
    assert!(graph_out.status.success(), "{}", text(&graph_out));
    let (record, echo) = (finish(record, limit, "dc record -a"), finish(echo, limit, "dc topic echo"));
    let (hz, bw) = (finish(hz, limit, "dc topic hz"), finish(bw, limit, "dc topic bw"));
    for (name, out) in [("record", &record), ("echo", &echo), ("hz", &hz), ("bw", &bw)] {
        assert!(out.status.success(), "{name}: {}", text(out));
    }

    let reference_stats = frames(&reference, "stats/solve");
    assert_eq!(reference_stats.len(), 300, "the graph's recorder has every step");
    // Echo: one JSON line per frame, each equal to the published frame of its step, and none
    // missing from the first it saw to the last the simulator published.
    let lines: Vec<serde_json::Value> =
        String::from_utf8_lossy(&echo.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert!(lines.len() >= 100, "the echo started early enough to see most steps: {}", lines.len());
    let echoed: Vec<(u32, u32)> = lines
        .iter()
        .map(|v| {
            let step = &v["header"]["step"];
            let key = (step["simulation"].as_u64().unwrap() as u32, step["step"].as_u64().unwrap() as u32);
            let published: msgs::SolveStatsHeader = msgs::decode_header(&reference_stats[&key]).unwrap();
            assert_eq!(v["header"]["sweeps"], published.sweeps, "{key:?}");
            assert_eq!(v["header"]["model"], "builtin");
            assert_eq!(
                v["items"]["count"].as_u64().unwrap() as u32,
                published.sweeps.min(1000),
                "one residual a sweep"
            );
            key
        })
        .collect();
    let expected: Vec<(u32, u32)> = reference_stats.keys().copied().skip_while(|k| *k != echoed[0]).collect();
    assert_eq!(echoed, expected, "every frame from the first echoed to the end, in order");
    assert!(String::from_utf8_lossy(&echo.stderr).contains("0 dropped"), "{}", text(&echo));
    let items = String::from_utf8_lossy(&echo_items.stdout);
    assert!(items.contains("items: 34 x dc::Body") && items.matches("\n  - {id: ").count() == 34, "{items}");

    // The attached recording: intact, every frame it holds byte-identical to the published one,
    // and nothing missing from its first frame on.
    let reference_bodies = frames(&reference, "bodies");
    let attached_bodies = frames(&attached, "bodies");
    assert!(attached_bodies.len() >= 100, "{}", text(&record));
    let first = *attached_bodies.keys().next().unwrap();
    let expected: Vec<_> = reference_bodies.range(first..).collect();
    assert_eq!(attached_bodies.iter().collect::<Vec<_>>(), expected, "bodies from {first:?} on");
    assert!(String::from_utf8_lossy(&record.stdout).contains("dropped 0"), "{}", text(&record));

    // hz: the paced simulator's rate (it never runs faster than 100 steps/s); bw: its frame size.
    let stdout = String::from_utf8_lossy(&hz.stdout);
    let line = last_line(&stdout, "average rate: ");
    let rate: f64 = line.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!(rate > 5.0 && rate < 110.0, "{line}");
    let stdout = String::from_utf8_lossy(&bw.stdout);
    let line = last_line(&stdout, "average: ");
    let frame_bytes = 16 + 48 * 34; // step header + 30 balls and 4 walls
    assert!(
        line.contains(&format!("mean: {0:.2} KB  min: {0:.2} KB  max: {0:.2} KB", frame_bytes as f64 / 1e3)),
        "{line}"
    );

    // Watching changed nothing: the same graph alone gives the same sweeps, step for step.
    let alone = dir.join("alone.mcap");
    let graph_alone = start(&dir, "alone", &graph(&alone, "", 150), &unique_namespace("observe-alone"));
    let out = finish(graph_alone, limit, "the graph alone");
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(sweeps(&reference), sweeps(&alone));
}

#[test]
fn dc_play_publishes_a_recording_that_echo_decodes() {
    let dir = scratch_dir("observe-play");
    let namespace = unique_namespace("observe-play");
    let recording = deep_contact::repo_root().join("recordings/fixtures/ball-box-seed0-steps.mcap");
    let published = frames(&recording, "stats/solve");
    // Looped: however late the echo joins, it sees five frames.
    let play = dc(&["play", recording.to_str().unwrap(), "--namespace", &namespace, "--loop"]).spawn().unwrap();
    wait_for_writer(&namespace, "stats/solve", None);
    let echo =
        dc(&["topic", "echo", "stats/solve", "--namespace", &namespace, "--count", "5", "--json"]).output().unwrap();
    assert!(echo.status.success(), "{}", text(&echo));
    let lines: Vec<serde_json::Value> =
        String::from_utf8_lossy(&echo.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 5);
    for v in &lines {
        let key = (
            v["header"]["step"]["simulation"].as_u64().unwrap() as u32,
            v["header"]["step"]["step"].as_u64().unwrap() as u32,
        );
        let h: msgs::SolveStatsHeader = msgs::decode_header(&published[&key]).unwrap();
        assert_eq!(v["header"]["sweeps"], h.sweeps, "{key:?}");
    }
    let out = interrupt(play, Duration::from_secs(30), "dc play");
    assert!(out.status.success() || out.status.code() == Some(130), "{}", text(&out));
    let _ = std::fs::remove_dir_all(dir);
}

/// The launcher's zenoh router endpoint, from its log.
fn router_endpoint(launcher: &mut Child) -> (String, std::thread::JoinHandle<String>) {
    let stderr = launcher.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(at) = line.find("endpoint=") {
                let _ = tx.send(
                    line[at + "endpoint=".len()..]
                        .split_whitespace()
                        .next()
                        .unwrap_or("")
                        .trim_matches('"')
                        .to_string(),
                );
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let endpoint = rx.recv_timeout(Duration::from_secs(60)).expect("the launcher names its zenoh router");
    (endpoint, reader)
}

#[test]
fn over_zenoh_list_and_echo_see_the_graph_and_count_a_garbage_frame() {
    let dir = scratch_dir("observe-zenoh");
    let namespace = unique_namespace("observe-zenoh");
    let reference = dir.join("reference.mcap");
    let topics = "[topics]\n\"stats/solve\" = \"zenoh\"\n";
    let mut graph_run = start(&dir, "observed", &graph(&reference, topics, 250), &namespace);
    let (endpoint, log) = router_endpoint(&mut graph_run);
    wait_for_writer(&namespace, "stats/solve", Some(&endpoint));
    let ns = namespace.as_str();

    let list = dc(&["topic", "list", "--zenoh", &endpoint, "--namespace", ns]).output().unwrap();
    let listed = String::from_utf8_lossy(&list.stdout);
    let row = listed
        .lines()
        .find(|l| l.split_whitespace().nth(1) == Some("stats/solve"))
        .unwrap_or_else(|| panic!("{}", text(&list)));
    assert_eq!(
        row.split_whitespace().collect::<Vec<_>>()[2..],
        ["SolveStats", "1", "1", "reliable"],
        "the simulator writes, the recorder reads:\n{listed}"
    );
    let unknown = dc(&["topic", "echo", "bodies", "--zenoh", &endpoint, "--namespace", ns]).output().unwrap();
    assert_eq!(unknown.status.code(), Some(1), "{}", text(&unknown));
    assert!(
        String::from_utf8_lossy(&unknown.stderr).contains("`bodies` is not alive in namespace"),
        "{}",
        text(&unknown)
    );

    // A session of our own on the graph, to put a garbage payload on the topic's key.
    use runtime::zenoh::Wait;
    let session = foreign_session(&endpoint);
    let args = ["topic", "echo", "stats/solve", "--zenoh", &endpoint, "--namespace", ns, "--count", "60", "--json"];
    let mut echo = dc(&args).spawn().unwrap();
    let mut stdout = BufReader::new(echo.stdout.take().unwrap());
    let mut lines = vec![String::new()];
    stdout.read_line(&mut lines[0]).unwrap();
    let first_len = lines[0].trim_end().len();
    lines[0].truncate(first_len);
    // The echo is receiving (a frame came): the garbage now, while it still has 59 to go.
    session.put(format!("dc/{ns}/stats/solve"), b"\xffnot a frame".to_vec()).wait().unwrap();
    lines.extend(stdout.lines().map_while(Result::ok));
    let echo = finish(echo, Duration::from_secs(60), "dc topic echo over zenoh");
    assert!(echo.status.success(), "{}", text(&echo));
    assert_eq!(lines.len(), 60, "{}", text(&echo));
    let values: Vec<serde_json::Value> = lines.iter().map(|l| serde_json::from_str(l).unwrap()).collect();
    let garbage: Vec<_> = values.iter().filter(|v| v.get("undecodable").is_some()).collect();
    assert_eq!(garbage.len(), 1, "the garbage frame is printed as such: {garbage:?}");
    assert!(String::from_utf8_lossy(&echo.stderr).contains("1 undecodable"), "{}", text(&echo));

    let out = finish(graph_run, Duration::from_secs(120), "the graph");
    let log = log.join().unwrap();
    assert!(out.status.success(), "{log}");
    let published = frames(&reference, "stats/solve");
    let mut previous: Option<(u32, u32)> = None;
    for v in values.iter().filter(|v| v.get("undecodable").is_none()) {
        let key = (
            v["header"]["step"]["simulation"].as_u64().unwrap() as u32,
            v["header"]["step"]["step"].as_u64().unwrap() as u32,
        );
        let h: msgs::SolveStatsHeader = msgs::decode_header(&published[&key]).unwrap();
        assert_eq!(v["header"]["sweeps"], h.sweeps, "{key:?}");
        assert!(previous.is_none_or(|p| p < key), "in order: {previous:?} then {key:?}");
        previous = Some(key);
    }
    drop(session);
    let _ = std::fs::remove_dir_all(dir);
}

/// `dc record -a` stopped by Ctrl-C while the graph runs on: it exits cleanly with the file
/// finished (strictly readable, its frames the graph's own), and the graph goes on unharmed.
#[test]
fn an_attached_recorder_stopped_by_ctrl_c_leaves_a_finished_file() {
    let dir = scratch_dir("observe-ctrl-c");
    let namespace = unique_namespace("observe-ctrl-c");
    let (reference, attached) = (dir.join("reference.mcap"), dir.join("attached.mcap"));
    let graph_run = start(&dir, "observed", &graph(&reference, "", 100_000), &namespace);
    wait_for_writer(&namespace, "bodies", None);
    let mut record =
        dc(&["record", "-a", "--namespace", &namespace, "-o", attached.to_str().unwrap()]).spawn().unwrap();
    // Recording once it said so, then a while.
    let mut stderr = BufReader::new(record.stderr.take().unwrap());
    let mut said = String::new();
    stderr.read_line(&mut said).unwrap();
    assert!(said.starts_with("recording "), "{said}");
    std::thread::sleep(Duration::from_secs(2));
    let out = interrupt(record, Duration::from_secs(30), "dc record -a after Ctrl-C");
    assert!(out.status.success(), "{}", text(&out));
    let recorded = frames(&attached, "bodies");
    assert!(recorded.len() >= 50, "two seconds at 100 steps/s: {}", recorded.len());
    // The graph still runs (its writers are there), then stops on its own Ctrl-C.
    wait_for_writer(&namespace, "bodies", None);
    let out = interrupt(graph_run, Duration::from_secs(60), "the graph after Ctrl-C");
    assert!(out.status.code() == Some(130) || out.status.success(), "{}", text(&out));
    // Ctrl-C is how a user ends a graph: said as such, never as an error.
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("dc: error"), "{stderr}");
    let reference = frames(&reference, "bodies");
    for (key, data) in &recorded {
        assert_eq!(reference.get(key), Some(data), "{key:?}: the attached file holds what was published");
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// The forged frame of the probe: a control frame whose items claim 2^40 bytes, padded to
/// 300 kB so that zenoh delivers it in fragments.
fn forged_control_frame() -> Vec<u8> {
    let mut forged = msgs::encode(&msgs::Frame::new(msgs::Control::default(), Vec::<u8>::new())).unwrap();
    forged.truncate(forged.len() - 1); // the empty byte string's head (0x40)
    forged.push(0x5b); // a byte string with an 8-byte length
    forged.extend_from_slice(&(1u64 << 40).to_be_bytes());
    forged.resize(300_000, 0);
    forged
}

#[test]
fn a_forged_frame_from_a_foreign_session_is_counted_and_the_graph_completes() {
    // Any peer that reaches the graph's zenoh (no TLS here) can put this on `control`: the
    // metrics node and the recorder read it; before readers bounded a claimed length by the
    // bytes present, the metrics node aborted allocating 1 TB and the graph stopped.
    let dir = scratch_dir("observe-forged");
    let namespace = unique_namespace("observe-forged");
    let reference = dir.join("reference.mcap");
    let report = dir.join("report");
    let topics = "[topics]\n\"control\" = \"zenoh\"\n";
    let metrics = format!(
        "\n[[nodes]]\nname = \"metrics\"\nbinary = \"dc-metrics\"\nparams = {{ runs = 1, out = \"{}\" }}\n",
        report.display()
    );
    let text_of_graph = graph(&reference, topics, 150) + &metrics;
    let mut graph_run = start(&dir, "forged", &text_of_graph, &namespace);
    let (endpoint, log) = router_endpoint(&mut graph_run);
    wait_for_writer(&namespace, "bodies", None);

    use runtime::zenoh::Wait;
    let session = foreign_session(&endpoint);
    let forged = forged_control_frame();
    // Several, over a second: a put before the session has learned the graph's subscribers is
    // routed nowhere.
    for _ in 0..10 {
        session.put(format!("dc/{namespace}/control"), forged.clone()).wait().unwrap();
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = finish(graph_run, Duration::from_secs(120), "the graph");
    let log = log.join().unwrap();
    assert!(out.status.success(), "the graph must complete:\n{log}");
    assert!(!log.contains("memory allocation"), "{log}");
    assert!(log.contains("dropped a payload"), "the forged frames are logged and counted:\n{log}");
    assert!(report.join("report.html").is_file(), "the metrics node wrote its report:\n{log}");
    // The recorder kept every step of both simulations.
    assert_eq!(sweeps(&reference).len(), 2 * 150, "{log}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn dc_play_into_a_live_graph_is_refused_unless_it_joins_with_its_runs_marked_as_replayed() {
    // The probe: `dc play` into a running graph's namespace ended its metrics node at step 208
    // of 1,200 (the recording's RunEnd), mixed both runs in the report and the recording.
    let dir = scratch_dir("observe-play-live");
    let namespace = unique_namespace("observe-play-live");
    let reference = dir.join("reference.mcap");
    let report = dir.join("report");
    let fixture = deep_contact::repo_root().join("recordings/fixtures/ball-box-seed0-steps.mcap");
    let fixture = fixture.to_str().unwrap();
    let metrics = format!(
        "\n[[nodes]]\nname = \"metrics\"\nbinary = \"dc-metrics\"\nparams = {{ runs = 1, out = \"{}\" }}\n",
        report.display()
    );
    let graph_run = start(&dir, "observed", &(graph(&reference, "", 150) + &metrics), &namespace);
    wait_for_writer(&namespace, "bodies", None);

    let refused = dc(&["play", fixture, "--namespace", &namespace]).output().unwrap();
    assert!(!refused.status.success(), "{}", text(&refused));
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("is in use by graph `observed`") && err.contains("--into-live"), "{err}");

    // Looped for a while as recorded: frames published before the recorder's subscriber met
    // the new publisher are not delivered, later ones are.
    let joined = dc(&["play", fixture, "--namespace", &namespace, "--into-live", "--loop"]).spawn().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let joined = interrupt(joined, Duration::from_secs(30), "dc play --into-live");
    assert!(joined.status.success() || joined.status.code() == Some(130), "{}", text(&joined));
    let out = finish(graph_run, Duration::from_secs(120), "the graph");
    assert!(out.status.success(), "{}", text(&out));

    // The report is the graph's run alone: both seeds, every step.
    let rows = std::fs::read_to_string(report.join("steps.csv")).unwrap().lines().count() - 1;
    assert_eq!(rows, 2 * 150, "one row per step of the graph's own run");
    // The recorder kept the replayed frames apart: their run ids carry the mark.
    let mut reader = RecordingReader::open(&reference).unwrap();
    let (mut own, mut replayed) = (0, 0);
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        if m.channel.topic == "stats/solve" {
            let h: msgs::SolveStatsHeader = msgs::decode_header(&m.data).unwrap();
            if msgs::is_replayed(h.step.run_id) {
                replayed += 1;
            } else {
                own += 1;
            }
        }
    }
    assert_eq!(own, 2 * 150);
    assert!(replayed > 0, "the replayed statistics are recorded, marked");

    // And the other way round: a graph is refused a namespace a `dc play` holds.
    let played = unique_namespace("observe-play-held");
    let play = dc(&["play", fixture, "--namespace", &played, "--loop"]).spawn().unwrap();
    wait_for_writer(&played, "stats/solve", None);
    let file = dir.join("late.toml");
    std::fs::write(&file, graph(&dir.join("late.mcap"), "", 10)).unwrap();
    let late = Command::new(bin("dc")).arg("launch").arg(&file).args(["--namespace", &played]).output().unwrap();
    assert!(!late.status.success(), "{}", text(&late));
    assert!(String::from_utf8_lossy(&late.stderr).contains("dc play"), "{}", text(&late));
    let _ = interrupt(play, Duration::from_secs(30), "dc play");
    let _ = std::fs::remove_dir_all(dir);
}

/// `dc node list` and `dc topic info` against a running graph: its nodes by name with their
/// pids and state, and what a topic carries with its live writers and readers.
#[test]
fn node_list_and_topic_info_describe_a_running_graph() {
    let dir = scratch_dir("observe-info");
    let namespace = unique_namespace("observe-info");
    let graph_run = start(&dir, "observed", &graph(&dir.join("run.mcap"), "", 100_000), &namespace);
    wait_for_writer(&namespace, "bodies", None);

    let out = dc(&["node", "list", "--namespace", &namespace]).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    for node in ["recorder", "sim"] {
        let row = stdout.lines().find(|l| l.split_whitespace().nth(3) == Some(node));
        let cols: Vec<&str> = row.unwrap_or_else(|| panic!("no row for {node}: {stdout}")).split_whitespace().collect();
        assert_eq!((cols[0], cols[2], cols[5]), (namespace.as_str(), "observed", "running"), "{stdout}");
        let pid: i32 = cols[4].parse().unwrap();
        assert_eq!(unsafe { libc::kill(pid, 0) }, 0, "{node}'s pid {pid} is alive");
        assert!(cols[6].ends_with(&format!("dc-{}", if node == "sim" { "sim" } else { "record" })), "{stdout}");
    }

    let out = dc(&["topic", "info", "stats/solve", "--namespace", &namespace]).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("type:    dc::SolveStatsHeader header, f32 items"), "{stdout}");
    assert!(
        stdout.lines().any(|l| l.starts_with("header:") && l.contains("sweeps") && l.contains("model")),
        "{stdout}"
    );
    assert!(stdout.contains(&format!("namespace `{namespace}`: writers 1, readers 1, reliable")), "{stdout}");
    let out = dc(&["topic", "info", "contacts", "--namespace", &namespace]).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.lines().any(|l| l.starts_with("items:") && l.contains("normal_impulse")), "{stdout}");
    let out = dc(&["topic", "info", "no/such"]).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("not a Deep Contact topic"));

    let _ = interrupt(graph_run, Duration::from_secs(60), "the graph");
    let out = dc(&["node", "list", "--namespace", &namespace]).output().unwrap();
    assert!(!out.status.success(), "the graph is gone: {}", text(&out));
    let _ = std::fs::remove_dir_all(dir);
}

/// `dc topic bridge`: a topic the launch file keeps on iceoryx2 relayed to zenoh, where a foreign
/// session (as Python's would be) receives the simulator's frames under `dc/<namespace>/<topic>`.
#[test]
fn a_bridge_relays_a_shared_memory_topic_to_zenoh() {
    use runtime::zenoh::Wait;
    let dir = scratch_dir("observe-bridge");
    let namespace = unique_namespace("observe-bridge");
    let graph_run = start(&dir, "observed", &graph(&dir.join("run.mcap"), "", 100_000), &namespace);
    wait_for_writer(&namespace, "stats/solve", None);
    let mut bridge =
        dc(&["topic", "bridge", "stats/solve", "--namespace", &namespace, "--count", "400"]).spawn().unwrap();
    let mut stderr = BufReader::new(bridge.stderr.take().unwrap());
    let mut said = String::new();
    stderr.read_line(&mut said).unwrap();
    let endpoint = said
        .split_whitespace()
        .find(|w| w.starts_with("tcp/"))
        .unwrap_or_else(|| panic!("the relay names its endpoint: {said}"))
        .trim_end_matches(',')
        .to_string();
    let session = foreign_session(&endpoint);
    let subscriber = session.declare_subscriber(format!("dc/{namespace}/stats/solve")).wait().unwrap();
    let mut steps = Vec::new();
    let started = Instant::now();
    while steps.len() < 20 && started.elapsed() < Duration::from_secs(60) {
        if let Ok(Some(sample)) = subscriber.recv_timeout(Duration::from_millis(200)) {
            let frame: msgs::Frame<msgs::SolveStatsHeader, f32> = msgs::decode(&sample.payload().to_bytes()).unwrap();
            steps.push(frame.header.step.step);
        }
    }
    assert!(steps.len() >= 20, "frames over zenoh: {steps:?}: {said}");
    assert!(steps.windows(2).all(|w| w[0] < w[1] || w[1] == 0), "in order: {steps:?}");
    let _ = interrupt(bridge, Duration::from_secs(60), "dc topic bridge");
    let _ = interrupt(graph_run, Duration::from_secs(60), "the graph");
    let _ = std::fs::remove_dir_all(dir);
}

/// `dc topic pub control shutdown` from another terminal ends a running graph cleanly: the
/// simulator stops at its next step, the recorder closes its file (strictly readable), the
/// launcher exits 0.
#[test]
fn a_shutdown_published_by_hand_ends_the_graph_cleanly() {
    let dir = scratch_dir("observe-pub");
    let namespace = unique_namespace("observe-pub");
    let recording = dir.join("run.mcap");
    let graph_run = start(&dir, "observed", &graph(&recording, "", 100_000), &namespace);
    wait_for_writer(&namespace, "bodies", None);
    let out = dc(&["topic", "pub", "control", "shutdown", "--namespace", &namespace]).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("published `shutdown`"), "{}", text(&out));
    let out = finish(graph_run, Duration::from_secs(60), "the graph after a published shutdown");
    assert!(out.status.success(), "{}", text(&out));
    let steps = frames(&recording, "bodies");
    assert!(!steps.is_empty() && steps.len() < 2 * 100_000, "{} steps recorded", steps.len());
    let refused = dc(&["topic", "pub", "bodies", "shutdown", "--namespace", &namespace]).output().unwrap();
    assert!(!refused.status.success());
    let _ = std::fs::remove_dir_all(dir);
}
