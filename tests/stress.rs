//! Graphs under load: five graphs started at once on one machine, each in its own namespace with
//! a recorder, `DC_STRESS_ROUNDS` (20) times in a row. Every graph must start and end well (no
//! port race, no shared service, no namespace clash), every recording must read back intact, and
//! every run's sweeps must be the lone run's, step for step. Every other graph sends its
//! statistics over zenoh (through the router its launcher binds), the rest over iceoryx2.

use deep_contact::*;
use recorder::read::RecordingReader;
use std::path::Path;
use std::process::Command;

const GRAPHS: usize = 5;

/// A simulator and a recorder of its statistics; `zenoh` sends them over zenoh.
fn graph(recording: &Path, zenoh: bool) -> String {
    let topics = if zenoh { "[topics]\n\"stats/solve\" = \"zenoh\"\n" } else { "" };
    format!(
        r#"
[graph]
name = "stress"
{topics}
[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "control,stats/solve", "flush-ms" = 200 }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0..2", steps = 40, model = "builtin", n = 20 }}
"#,
        recording.display()
    )
}

/// `(simulation, step, sweeps)` of every statistics frame of a recording, in order, read strictly
/// (a damaged file fails here).
fn sweeps(recording: &Path) -> Vec<(u32, u32, u32)> {
    recorder::Info::read(recording).unwrap_or_else(|e| panic!("{}: not intact: {e}", recording.display()));
    let mut reader = RecordingReader::open(recording).unwrap();
    let mut out = Vec::new();
    while let Some(m) = reader.next_message() {
        let m = m.unwrap();
        if m.channel.topic == "stats/solve" {
            let h: msgs::SolveStatsHeader = msgs::decode_header(&m.data).unwrap();
            out.push((h.step.simulation, h.step.step, h.sweeps));
        }
    }
    out.sort();
    out
}

fn start(dir: &Path, name: &str, zenoh: bool) -> std::process::Child {
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, graph(&dir.join(format!("{name}.mcap")), zenoh)).unwrap();
    Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace(name)])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run dc")
}

#[test]
fn five_graphs_at_once_twenty_times_all_start_record_intact_and_match_a_lone_run() {
    let rounds: usize = std::env::var("DC_STRESS_ROUNDS").ok().and_then(|v| v.parse().ok()).unwrap_or(20);
    let dir = scratch_dir("stress");
    let lone = start(&dir, "lone", false).wait_with_output().unwrap();
    assert!(lone.status.success(), "{}", text(&lone));
    let expected = sweeps(&dir.join("lone.mcap"));
    assert_eq!(expected.len(), 2 * 40, "two simulations of 40 steps");
    let started = std::time::Instant::now();
    let mut ok = 0;
    for round in 0..rounds {
        let graphs: Vec<(String, std::process::Child)> = (0..GRAPHS)
            .map(|g| {
                let name = format!("r{round}-g{g}");
                let child = start(&dir, &name, g % 2 == 1);
                (name, child)
            })
            .collect();
        for (name, child) in graphs {
            let out = child.wait_with_output().unwrap();
            assert!(out.status.success(), "round {round}, graph {name}: {}", text(&out));
            let recording = dir.join(format!("{name}.mcap"));
            assert_eq!(sweeps(&recording), expected, "round {round}, graph {name}: sweeps differ from the lone run");
            std::fs::remove_file(&recording).unwrap();
            ok += 1;
        }
    }
    eprintln!(
        "{ok}/{} graphs started, recorded intact and matched the lone run in {:.1} s",
        rounds * GRAPHS,
        started.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
