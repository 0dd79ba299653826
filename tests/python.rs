//! The Python examples in `python/` against real data: a recording made by a real graph is read
//! into numpy arrays and matches what the simulator reported; a live zenoh tap of the repository's
//! own `launch/python-tap.toml` graph receives the simulator's statistics. Skipped, saying why,
//! where python3 or the PyPI packages (`python/requirements.txt`) are missing, except under
//! `DC_REQUIRE_ALL=1` (CI). (The solver probes on such a recording are experiments:
//! `experiments/tests/probes.rs`.)

use deep_contact::{bin, have_python, python, record_labelled_problems, repo_root, text};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Whether process `pid` has a listening TCP socket (its sockets in /proc/PID/fd, matched by inode
/// with the LISTEN entries of /proc/net/tcp and tcp6).
fn listens(pid: u32) -> bool {
    let Ok(fds) = std::fs::read_dir(format!("/proc/{pid}/fd")) else { return false };
    let inodes: std::collections::HashSet<String> = fds
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .filter_map(|l| Some(l.to_str()?.strip_prefix("socket:[")?.strip_suffix(']')?.to_string()))
        .collect();
    ["/proc/net/tcp", "/proc/net/tcp6"].iter().filter_map(|f| std::fs::read_to_string(f).ok()).any(|table| {
        table.lines().skip(1).any(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            f.len() > 9 && f[3] == "0A" && inodes.contains(f[9])
        })
    })
}

/// The `total_sweeps` of the `dc-sim run` summary line in a launcher's output.
fn total_sweeps(out: &Output) -> u64 {
    let all = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    let runs = msgs::control::RunSummary::find_in(all.lines()).unwrap_or_else(|e| panic!("{e}:\n{}", text(out)));
    assert_eq!(runs.len(), 1, "one run summary:\n{}", text(out));
    runs[0].total_sweeps
}

#[test]
fn python_reads_a_real_recording_into_numpy() {
    if !have_python("python reader", "numpy, mcap, cbor2") {
        return;
    }
    let (file, out) = record_labelled_problems("python-read");
    let sweeps = total_sweeps(&out);

    let read = python("python/read_recording.py", &[file.to_str().unwrap(), "--json"]);
    assert!(read.status.success(), "{}", text(&read));
    let summary: serde_json::Value = serde_json::from_slice(&read.stdout).expect("one JSON summary");
    let sims = summary.as_object().unwrap();
    assert_eq!(sims.keys().collect::<Vec<_>>(), ["3", "4"], "{summary}");
    let python_sweeps: u64 = sims.values().map(|s| s["sweeps"].as_u64().unwrap()).sum();
    assert_eq!(python_sweeps, sweeps, "Python's per-step sweeps add up to the simulator's total");
    for s in sims.values() {
        assert_eq!((s["steps"].as_u64(), s["model"].as_str()), (Some(60), Some("builtin")), "{s}");
        // 30 balls and the box's walls; the pile settles inside the box (0..15).
        assert!(s["bodies"].as_u64().unwrap() > 30, "{s}");
        let h = s["mean_height"].as_f64().unwrap();
        assert!(h > 0.0 && h < 15.0, "{s}");
        assert!(s["contacts"].as_u64().unwrap() > 0, "{s}");
    }

    // Bad input: a clear message naming the file, no traceback.
    let junk = file.with_file_name("junk.mcap");
    std::fs::write(&junk, b"\x89MCAP0\r\n this is not a recording").unwrap();
    let bad = python("python/read_recording.py", &[junk.to_str().unwrap()]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("junk.mcap") && !err.contains("Traceback"), "{err}");
}

#[test]
fn python_taps_the_live_statistics_of_the_python_tap_graph() {
    if !have_python("python live tap", "numpy, cbor2, zenoh") {
        return;
    }
    // The subscriber first (the simulator's publisher waits briefly for a match), then the
    // repository's launch file as it is.
    let tap = Command::new("python3")
        .arg(repo_root().join("python/subscribe.py"))
        .args(["--connect", "tcp/127.0.0.1:17447", "--key", "dc/python-tap/stats/solve"])
        .args(["--count", "50", "--timeout", "60", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start subscribe.py");
    // Its zenoh session is open once it listens (the subscriber is declared right after).
    let deadline = Instant::now() + Duration::from_secs(30);
    while !listens(tap.id()) {
        assert!(Instant::now() < deadline, "subscribe.py opened no zenoh session within 30 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    let launch_file = repo_root().join("launch/python-tap.toml");
    let out = Command::new(bin("dc")).arg("launch").arg(&launch_file).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let tapped = tap.wait_with_output().unwrap();
    assert!(tapped.status.success(), "{}", text(&tapped));
    let lines: Vec<serde_json::Value> =
        String::from_utf8_lossy(&tapped.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 50);
    // Consecutive steps of one simulation, as the simulator published them, with their sweeps.
    for w in lines.windows(2) {
        if w[0]["simulation"] == w[1]["simulation"] {
            assert_eq!(w[1]["step"].as_u64().unwrap(), w[0]["step"].as_u64().unwrap() + 1, "{w:?}");
        }
    }
    assert!(lines.iter().all(|l| l["model"] == "builtin"), "{lines:?}");
    assert!(lines.iter().map(|l| l["sweeps"].as_u64().unwrap()).sum::<u64>() > 0);
}

/// `dc-record --foxglove`: beside the raw recording, its Foxglove view, which the official `mcap`
/// reader (PyPI) opens with Foxglove's schemas (what Foxglove's file mode reads).
#[test]
fn a_recording_with_the_viewers_channels_opens_with_foxglove_schemas() {
    if !have_python("foxglove view", "mcap") {
        return;
    }
    let dir = deep_contact::scratch_dir("foxglove-view");
    let file = dir.join("run.mcap");
    let graph = format!(
        "[[nodes]]\nname = \"recorder\"\nbinary = \"dc-record\"\ndaemon = true\n\
         params = {{ out = \"{}\", foxglove = true }}\n\n\
         [[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\nparams = {{ model = \"builtin\", seeds = \"0..1\", steps = 30, n = 20 }}\n",
        file.display()
    );
    let (_, out) = deep_contact::launch("foxglove-view", &graph, &[]);
    assert!(out.status.success(), "{}", text(&out));
    let view = dir.join("run.foxglove.mcap");
    assert!(view.is_file(), "no view beside the recording: {}", text(&out));
    let schemas = Command::new("python3")
        .args([
            "-c",
            "import sys; from mcap.reader import make_reader\n\
             s = make_reader(open(sys.argv[1], 'rb')).get_summary()\n\
             print(' '.join(sorted({x.name for x in s.schemas.values()})))\n\
             print(' '.join(sorted({c.topic for c in s.channels.values()})))",
            view.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(schemas.status.success(), "{}", text(&schemas));
    let said = String::from_utf8_lossy(&schemas.stdout);
    assert!(
        said.contains("foxglove.SceneUpdate") && said.contains("/scene") && said.contains("/stats/solve"),
        "{said}"
    );
}
