//! Multi-process tests with the real binaries: record a live graph, replay it into another graph,
//! kill a recorder, and the command line on bad input. Need `dc` and `dc-sim` built beside the
//! recorder's binaries (`cargo build --workspace --bins`).

mod common;

use common::*;
use recorder::read::RecordingReader;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

const DC_RECORD: &str = env!("CARGO_BIN_EXE_dc-record");
const DC_REPLAY: &str = env!("CARGO_BIN_EXE_dc-replay");

fn text(out: &Output) -> String {
    format!(
        "status: {}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Runs `dc launch` on `toml` in a namespace of its own.
fn launch(dir: &Path, name: &str, toml: &str) -> Output {
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, toml).unwrap();
    Command::new(bin("dc")).arg("launch").arg(&file).args(["--namespace", &namespace(name)]).output().expect("run dc")
}

/// Every payload of a recording, per topic, in file order.
fn payloads(file: &Path) -> BTreeMap<String, Vec<Vec<u8>>> {
    let mut out: BTreeMap<String, Vec<Vec<u8>>> = BTreeMap::new();
    let mut reader = RecordingReader::open(file).unwrap();
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        out.entry(m.channel.topic.clone()).or_default().push(m.data);
    }
    out
}

#[test]
fn replayed_recording_is_recorded_again_message_for_message() {
    let dir = scratch("replay");
    let first = dir.join("live.mcap");
    let second = dir.join("replayed.mcap");
    let t = Instant::now();
    let out = launch(
        &dir,
        "record",
        &format!(
            r#"
[graph]
name = "record"

[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0..2", steps = 30, model = "builtin", n = 40 }}
"#,
            first.display()
        ),
    );
    assert!(out.status.success(), "{}", text(&out));
    let recorded = payloads(&first);
    eprintln!("live graph recorded in {:.1} s", t.elapsed().as_secs_f64());
    let counts: BTreeMap<&str, usize> = recorded.iter().map(|(k, v)| (k.as_str(), v.len())).collect();
    // 2 simulations x 30 steps; control: run start/end + start/end of each simulation.
    assert_eq!(
        counts,
        BTreeMap::from([("bodies", 60), ("contacts", 60), ("control", 6), ("stats/solve", 60)]),
        "{}",
        text(&out)
    );
    let steps: Vec<_> = recorder::Steps::open(&first).unwrap().collect::<Result<_, _>>().unwrap();
    assert_eq!(steps.len(), 60);
    assert!(steps.iter().all(|s| s.stats.is_some() && s.bodies.items.len() >= 40));

    let t = Instant::now();
    let out = launch(
        &dir,
        "replay",
        &format!(
            r#"
[graph]
name = "replay"

[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}" }}

[[nodes]]
name = "replay"
binary = "dc-replay"
params = {{ input = "{}", rate = 0 }}
"#,
            second.display(),
            first.display()
        ),
    );
    assert!(out.status.success(), "{}", text(&out));
    eprintln!("replay graph ran in {:.1} s", t.elapsed().as_secs_f64());
    let replayed = payloads(&second);
    for (topic, frames) in &recorded {
        let again = replayed.get(topic).map(Vec::as_slice).unwrap_or_default();
        assert_eq!(again.len(), frames.len(), "topic {topic}: count\n{}", text(&out));
        assert!(again == frames.as_slice(), "topic {topic}: a payload differs");
    }
    assert_eq!(replayed.len(), recorded.len(), "extra topics: {:?}", replayed.keys());
}

/// The children of this test, by process id (never by name).
fn pid_of(child: &std::process::Child) -> libc::pid_t {
    child.id() as libc::pid_t
}

/// Starts `dc-record ARGS` on `bus` (not launched: it runs as soon as its ports exist) and waits
/// for it to say it is recording; its later log lines go to the returned channel.
fn start_recorder(bus: &str, args: &[&str]) -> (std::process::Child, std::sync::mpsc::Receiver<String>) {
    let mut rec = Command::new(DC_RECORD)
        .args(args)
        .env("DC_BUS", bus)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = rec.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufRead::lines(std::io::BufReader::new(stderr)).map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) if line.contains("recording topics=") => break,
            Ok(_) => {}
            Err(_) => panic!("dc-record did not start recording within 30 s"),
        }
    }
    (rec, rx)
}

#[test]
fn killed_recorder_loses_at_most_the_last_flush_and_recover_makes_it_indexed() {
    let dir = scratch("kill");
    let file = dir.join("killed.mcap");
    let bus = format!(r#"{{"namespace":"{}"}}"#, namespace("kill"));
    let topics = "control,bodies,contacts,stats/solve";
    let (mut rec, _log) =
        start_recorder(&bus, &["--out", file.to_str().unwrap(), "--topics", topics, "--flush-ms", "200"]);
    let mut sim = Command::new(bin("dc-sim"))
        .args(["--seeds", "0..1000", "--steps", "50", "--model", "builtin", "--n", "40"])
        .env("DC_BUS", &bus)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Let it record (several flushes: chunks written, by size or by --flush-ms, the file grows at
    // each), then, just after a flush, keep a copy of what is on disk and kill the recorder
    // without warning.
    let size = || std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
    let deadline = Instant::now() + Duration::from_secs(60);
    let (mut last, mut growths) = (size(), 0);
    let flushed = loop {
        assert!(
            Instant::now() < deadline,
            "the file grew {growths} times in 60 s, to {last} bytes: the recorder does not flush"
        );
        let now = size();
        if now != last {
            growths += 1;
            last = now;
            if growths >= 4 && now >= 200_000 {
                break std::fs::read(&file).unwrap();
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let killed_at = SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_nanos() as u64;
    unsafe { libc::kill(pid_of(&rec), libc::SIGKILL) };
    rec.wait().unwrap();
    // The simulator is blocked on the dead subscriber's full queue (back-pressure): kill it too.
    unsafe { libc::kill(pid_of(&sim), libc::SIGKILL) };
    sim.wait().unwrap();
    // Messages in the chunks that were whole on disk at the last flush before the kill (our own
    // walk of the MCAP framing, not the recorder's reader).
    let on_disk: u64 = chunks(&flushed).iter().map(|(_, messages)| messages).sum();
    assert!(on_disk > 100, "{} chunks on disk", chunks(&flushed).len());

    // The file is not a valid MCAP file as it stands ...
    let info = Command::new(DC_RECORD).arg("info").arg(&file).output().unwrap();
    assert!(!info.status.success(), "{}", text(&info));
    assert!(String::from_utf8_lossy(&info.stderr).contains("recover"), "{}", text(&info));
    // ... recover rewrites it.
    let fixed = dir.join("recovered.mcap");
    let out = Command::new(DC_RECORD).arg("recover").arg(&file).arg(&fixed).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));

    let data = std::fs::read(&fixed).unwrap();
    let summary = mcap::Summary::read(&data).unwrap().expect("an indexed file");
    let stats = summary.stats.expect("statistics");
    assert!(!summary.chunk_indexes.is_empty());
    // Everything flushed before the kill is back: at most what came after the last flush is lost.
    assert!(
        stats.message_count >= on_disk,
        "recovered {} messages, {on_disk} were flushed before the kill\n{}",
        stats.message_count,
        text(&out)
    );
    // Every recovered step is whole: steps of each simulation are contiguous from 0.
    let mut last: BTreeMap<u32, u32> = BTreeMap::new();
    let mut reader = RecordingReader::open(&fixed).unwrap();
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        if m.channel.topic == "bodies" {
            let h: msgs::StepHeader = msgs::decode_header(&m.data).unwrap();
            let expected = last.get(&h.simulation).map_or(0, |s| s + 1);
            assert_eq!(h.step, expected, "simulation {}", h.simulation);
            last.insert(h.simulation, h.step);
        }
    }
    eprintln!(
        "recovered {} messages ({on_disk} flushed at the last flush seen), {} simulations; lost the last {:.2} s",
        stats.message_count,
        last.len(),
        killed_at.saturating_sub(stats.message_end_time) as f64 * 1e-9
    );
}

#[cfg(target_os = "linux")]
#[test]
fn a_recorder_on_a_full_disk_stops_with_one_error_naming_it() {
    // /dev/full refuses every write with ENOSPC (no root, no tmpfs needed). It logged ~1,440
    // lines of `attempted another write after a write method failed` and never named the cause.
    let bus = format!(r#"{{"namespace":"{}"}}"#, namespace("full"));
    let (mut rec, log) = start_recorder(
        &bus,
        &["--out", "/dev/full", "--overwrite", "--topics", "control,bodies,contacts,stats/solve", "--flush-ms", "200"],
    );
    let drain = std::thread::spawn(move || log.iter().map(|l| l + "\n").collect::<String>());
    let mut sim = Command::new(bin("dc-sim"))
        .args(["--seeds", "0..1000", "--steps", "50", "--model", "builtin", "--n", "40"])
        .env("DC_BUS", &bus)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(status) = rec.try_wait().unwrap() {
            break Some(status);
        }
        if Instant::now() > deadline {
            unsafe { libc::kill(pid_of(&rec), libc::SIGKILL) };
            rec.wait().unwrap();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    unsafe { libc::kill(pid_of(&sim), libc::SIGKILL) };
    sim.wait().unwrap();
    let stderr = drain.join().unwrap();
    let status = status.unwrap_or_else(|| panic!("the recorder did not stop on a full disk:\n{stderr}"));
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.matches("No space left on device").count(), 1, "{stderr}");
    assert!(stderr.contains("writing /dev/full"), "{stderr}");
    assert!(!stderr.contains("attempted another write") && !stderr.contains("panicked"), "{stderr}");
}

/// `--out` at a path that holds a file (a finished recording, or a killed one waiting for
/// `recover`) is refused before anything is written: by the recorder itself, and by `dc launch`'s
/// check before any node of the graph starts. `--overwrite` is the explicit way to replace it.
#[test]
fn a_recorder_never_writes_over_an_existing_file_unless_told_to() {
    let dir = scratch("existing-out");
    let existing = dir.join("kept.mcap");
    fixture(&existing, 1, 1, 5);
    let before = std::fs::read(&existing).unwrap();

    let out = Command::new(DC_RECORD).arg("--out").arg(&existing).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    assert!(err.contains("kept.mcap already exists") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read(&existing).unwrap(), before, "the refused recorder touched the file");

    let graph = |overwrite: bool| {
        format!(
            r#"
[graph]
name = "existing"

[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}", overwrite = {overwrite} }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0..1", steps = 10, model = "builtin", n = 20 }}
"#,
            existing.display()
        )
    };
    let out = launch(&dir, "existing", &graph(false));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(err.contains("recorder") && err.contains("kept.mcap already exists"), "{}", text(&out));
    assert_eq!(std::fs::read(&existing).unwrap(), before, "the refused graph touched the file");

    let out = launch(&dir, "existing-overwrite", &graph(true));
    assert!(out.status.success(), "{}", text(&out));
    let counts: BTreeMap<String, usize> = payloads(&existing).into_iter().map(|(k, v)| (k, v.len())).collect();
    assert_eq!(counts.get("stats/solve"), Some(&10), "the overwritten file holds the new run only: {counts:?}");
}

#[test]
fn info_and_replay_refuse_bad_input_naming_the_file() {
    let dir = scratch("badcli");
    let notes = dir.join("notes.mcap");
    std::fs::write(&notes, "not a recording").unwrap();
    let good = dir.join("good.mcap");
    fixture(&good, 1, 1, 5);
    let bytes = std::fs::read(&good).unwrap();
    let truncated = dir.join("truncated.mcap");
    std::fs::write(&truncated, &bytes[..bytes.len() * 2 / 3]).unwrap();

    let future = dir.join("future.mcap");
    let mut w = recorder::RecordingWriter::create(&future).unwrap();
    let next = (msgs::WIRE_VERSION + 1).to_string();
    let meta =
        BTreeMap::from([("type".to_string(), "dc::Bodies".to_string()), ("wire_version".to_string(), next.clone())]);
    let id = w.add_raw_channel("bodies", "cbor", &meta).unwrap();
    w.write_to_channel(id, 1, 1, b"from the future").unwrap();
    w.finish().unwrap();

    let future_reason = format!("wire version {next}");
    for (file, reason) in [(&notes, "not an MCAP file"), (&truncated, "truncated"), (&future, future_reason.as_str())] {
        let info = Command::new(DC_RECORD).arg("info").arg(file).output().unwrap();
        let replay = Command::new(DC_REPLAY)
            .arg("--input")
            .arg(file)
            .env("DC_BUS", r#"{"namespace":"unused"}"#)
            .output()
            .unwrap();
        for out in [info, replay] {
            assert!(!out.status.success(), "{}", text(&out));
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(err.contains(&file.display().to_string()) && err.contains(reason), "{}", text(&out));
            assert!(!err.contains("panicked"), "{}", text(&out));
        }
    }

    let out = Command::new(DC_RECORD).arg("info").arg(&good).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("Topic: bodies") && stdout.contains("run 1 simulation 0: steps 0..=4"), "{stdout}");
    assert!(stdout.contains("zstd"), "{stdout}");
}

#[test]
fn bench_records_a_live_simulator_without_drops_and_reports_throughput() {
    // The 10,000-body benchmark at a tiny size: it completes, finds every step in the file, and
    // prints its figures (no timing is asserted). A dozen steps on purpose: such a simulator
    // publishes them in ~1 ms and is done before the recorder takes the first one; it lost them
    // all (36 drops, only control arrived) until launched nodes kept their publishers alive until
    // the graph's readers were done.
    let dir = scratch("record-bench");
    let out = Command::new(DC_RECORD)
        .args(["bench", "--n", "40", "--steps", "12", "--dir"])
        .arg(&dir)
        .output()
        .expect("run dc-record bench");
    let report = text(&out);
    assert!(out.status.success(), "{report}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| drops | 0 |"), "{report}");
    assert!(stdout.contains("bodies 0, contacts 0, stats/solve 0"), "{report}");
    for figure in ["msgs/s", "MB/s", "recorder CPU", "compression ratio"] {
        assert!(stdout.contains(figure), "no {figure}: {report}");
    }
    assert!(dir.join("bench.mcap").is_file() && dir.join("recorder-stats.json").is_file());
}
