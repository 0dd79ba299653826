//! `dc-record bench`: a live graph, the simulator with a large scene plus the recorder, started
//! through `dc launch` exactly as a user's graph would be; then what the recorder reported and
//! what the file holds: drops, msgs/s, MB/s, the recorder's CPU time, the compression ratio.

use anyhow::{bail, Context, Result};
use recorder::bench::{missing_steps, RecorderStats};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// The simulator's per-step topics: each carries one frame per step.
const STEP_TOPICS: [&str; 3] = ["bodies", "contacts", "stats/solve"];

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Dynamic bodies of the scene.
    #[arg(long, default_value_t = 10_000)]
    n: usize,
    /// Steps to simulate.
    #[arg(long, default_value_t = 30)]
    steps: u32,
    /// Scene (dc-sim --scene).
    #[arg(long, default_value = "ball-box")]
    scene: String,
    /// Transport of the recorded topics: iceoryx2 (same host, zero copy) or zenoh.
    #[arg(long, default_value = "iceoryx2")]
    transport: String,
    /// Keep the launch file, the recording and the recorder's counts in this folder (default: a
    /// temporary folder, removed afterwards).
    #[arg(long)]
    dir: Option<PathBuf>,
}

/// `dc` beside this binary, else on `PATH`.
fn find_dc() -> Result<PathBuf> {
    let beside = std::env::current_exe().ok().and_then(|exe| exe.parent().map(|d| d.join("dc")));
    beside
        .filter(|p| p.is_file())
        .or_else(|| {
            std::env::var_os("PATH")
                .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join("dc")).find(|p| p.is_file()))
        })
        .context("no `dc` beside dc-record or on PATH (cargo build --workspace --bins)")
}

fn launch_file(args: &BenchArgs, recording: &Path, stats: &Path) -> Result<String> {
    let topics = match args.transport.as_str() {
        "iceoryx2" => String::new(),
        "zenoh" | "both" => {
            let lines: String =
                STEP_TOPICS.iter().chain(&["control"]).map(|t| format!("\"{t}\" = \"{}\"\n", args.transport)).collect();
            format!("[topics]\n{lines}\n")
        }
        other => bail!("unknown transport `{other}` (iceoryx2, zenoh, both)"),
    };
    Ok(format!(
        r#"[graph]
name = "record-bench"

{topics}[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{recording}", topics = "bodies,contacts,stats/solve,control", stats-json = "{stats}" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ scene = "{scene}", n = {n}, steps = {steps}, seeds = "0", model = "builtin" }}
"#,
        recording = recording.display(),
        stats = stats.display(),
        scene = args.scene,
        n = args.n,
        steps = args.steps,
    ))
}

pub fn run(args: &BenchArgs) -> Result<()> {
    let nanos = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let tag = format!("record-bench-{}-{nanos}", std::process::id());
    let dir = args.dir.clone().unwrap_or_else(|| std::env::temp_dir().join(&tag));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let result = run_in(args, &dir, &tag);
    if args.dir.is_none() {
        std::fs::remove_dir_all(&dir).ok();
    }
    result
}

fn run_in(args: &BenchArgs, dir: &Path, namespace: &str) -> Result<()> {
    let recording = dir.join("bench.mcap");
    let stats_file = dir.join("recorder-stats.json");
    let graph = dir.join("record-bench.toml");
    std::fs::write(&graph, launch_file(args, &recording, &stats_file)?)?;
    println!(
        "record bench: {} scene, {} bodies, {} steps, {} transport (dc launch {})",
        args.scene,
        args.n,
        args.steps,
        args.transport,
        graph.display()
    );
    let started = Instant::now();
    let out = Command::new(find_dc()?)
        .arg("launch")
        .arg(&graph)
        .args(["--namespace", namespace])
        .output()
        .context("running dc launch")?;
    let wall = started.elapsed().as_secs_f64();
    if !out.status.success() {
        let log = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = log.lines().rev().take(30).collect();
        bail!("the graph failed ({}):\n{}", out.status, tail.into_iter().rev().collect::<Vec<_>>().join("\n"));
    }
    let stats: RecorderStats = serde_json::from_str(
        &std::fs::read_to_string(&stats_file)
            .with_context(|| format!("the recorder wrote no counts to {}", stats_file.display()))?,
    )?;
    let info = recorder::Info::read(&recording)?;
    // One simulation (seed 0) publishes `steps` frames on each step topic.
    let missing = missing_steps(&recording, &STEP_TOPICS, 1, args.steps)?;
    let missing_total: u64 = missing.values().sum();
    let recorded_undecodable: u64 = info.topics.values().map(|t| t.undecodable).sum();
    let drops = missing_total + stats.undecodable + stats.write_failed + stats.received.saturating_sub(info.messages);

    let mb = stats.payload_bytes as f64 / 1e6;
    let active = stats.active_s.max(1e-9);
    let ratio = info.uncompressed_bytes as f64 / info.compressed_bytes.max(1) as f64;
    let compressions: Vec<&str> = info.compressions.iter().map(String::as_str).collect();
    println!("| measure | value |\n| --- | --- |");
    println!("| drops | {drops} |");
    println!(
        "| messages | {} received, {} in the file ({} undecodable there), {} undecodable on the bus, {} refused by the writer |",
        stats.received, info.messages, recorded_undecodable, stats.undecodable, stats.write_failed
    );
    let per_topic: Vec<String> = missing.iter().map(|(t, n)| format!("{t} {n}")).collect();
    println!("| steps missing per topic | {} |", per_topic.join(", "));
    println!("| payload | {mb:.1} MB in {:.2} s from first to last message |", stats.active_s);
    println!("| throughput | {:.0} msgs/s, {:.1} MB/s |", stats.received as f64 / active, mb / active);
    println!(
        "| recorder CPU | {:.2} s ({:.0}% of the active time; {:.0} MB per CPU-second) |",
        stats.cpu_s,
        100.0 * stats.cpu_s / active,
        mb / stats.cpu_s.max(1e-9)
    );
    println!(
        "| file | {:.1} MB on disk, chunks {:.1} MB -> {:.1} MB ({}), compression ratio {ratio:.2} |",
        info.file_size as f64 / 1e6,
        info.uncompressed_bytes as f64 / 1e6,
        info.compressed_bytes as f64 / 1e6,
        compressions.join(", ")
    );
    println!("| graph wall time | {wall:.1} s (simulator start-up and solve included) |");
    if drops > 0 {
        bail!("{drops} messages dropped");
    }
    Ok(())
}
