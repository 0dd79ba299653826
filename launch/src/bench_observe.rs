//! `dc bench observe`: what watching a running graph costs its simulator. The same graph (the
//! simulator and its own recorder of statistics) runs alone and with the terminal's observers
//! attached (`dc topic echo bodies`, `dc topic hz stats/solve`, `dc topic bw contacts`,
//! `dc record -a`); the simulator's throughput is read from its recorder's log times over the
//! window in which the observers were attached (from a fixed settle time after the graph's
//! topics appeared to the end), and the medians of `--repeat` runs are compared.

use anyhow::{bail, Context, Result};
use launch::graph::find_binary;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Options of `dc bench observe`.
#[derive(clap::Args, Debug)]
pub struct ObserveBenchArgs {
    /// Dynamic bodies (ball-box).
    #[arg(long, default_value_t = 400)]
    n: u32,
    /// Steps of the one simulation.
    #[arg(long, default_value_t = 3000)]
    steps: u32,
    /// Runs of each variant (medians are compared).
    #[arg(long, default_value_t = 3)]
    repeat: usize,
}

/// How long after the graph's topics appear the window starts: every observer has attached.
const SETTLE: Duration = Duration::from_millis(1500);

fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}

/// Steps per second of the simulator over the frames its recorder logged from `from_ns` on.
fn throughput(recording: &Path, from_ns: u64) -> Result<(f64, usize)> {
    let mut reader = recorder::RecordingReader::open(recording)?;
    let mut times = Vec::new();
    while let Some(m) = reader.next_message() {
        let m = m?;
        if m.channel.topic == "stats/solve" && m.log_time >= from_ns {
            times.push(m.log_time);
        }
    }
    if times.len() < 100 {
        bail!(
            "{}: only {} steps after the observers attached: give more --steps or --n",
            recording.display(),
            times.len()
        );
    }
    let span = (times[times.len() - 1] - times[0]) as f64 * 1e-9;
    Ok(((times.len() - 1) as f64 / span, times.len()))
}

fn wait_for_topics(namespace: &str, graph: &mut Child) -> Result<()> {
    let started = Instant::now();
    while runtime::live_topics(Some(namespace))?.iter().all(|t| t.topic != "stats/solve" || t.writers == 0) {
        if graph.try_wait()?.is_some() {
            bail!("the graph ended before its topics appeared");
        }
        if started.elapsed() > Duration::from_secs(60) {
            bail!("the graph's topics never appeared");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// One run: steps/s in the window, steps in it, frames the observers dropped.
fn run_once(dir: &Path, args: &ObserveBenchArgs, observed: bool, r: usize) -> Result<(f64, usize, u64)> {
    let dc = std::env::current_exe()?;
    let name = format!("{}-{r}", if observed { "observed" } else { "alone" });
    let recording = dir.join(format!("{name}.mcap"));
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(
        &file,
        format!(
            "[graph]\nname = \"bench-observe\"\n[[nodes]]\nname = \"recorder\"\nbinary = \"dc-record\"\ndaemon = true\n\
             params = {{ out = \"{}\", topics = \"control,stats/solve\" }}\n[[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\n\
             params = {{ seeds = \"0..1\", steps = {}, model = \"builtin\", n = {} }}\n",
            recording.display(),
            args.steps,
            args.n
        ),
    )?;
    let namespace = launch::unique_namespace("bench-observe");
    let mut graph = Command::new(&dc)
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &namespace])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()?;
    wait_for_topics(&namespace, &mut graph)?;
    let window_from = now_ns() + SETTLE.as_nanos() as u64;
    let mut observers = Vec::new();
    if observed {
        let ns = namespace.as_str();
        let attached = dir.join(format!("{name}-attached.mcap"));
        for a in [
            vec!["topic", "echo", "bodies", "--namespace", ns],
            vec!["topic", "hz", "stats/solve", "--namespace", ns],
            vec!["topic", "bw", "contacts", "--namespace", ns],
            vec!["record", "-a", "--namespace", ns, "-o", attached.to_str().context("a UTF-8 path")?],
        ] {
            let child = Command::new(&dc).args(&a).stdout(Stdio::null()).stderr(Stdio::piped()).spawn()?;
            observers.push((a.join(" "), child));
        }
    }
    let out = graph.wait_with_output()?;
    if !out.status.success() {
        bail!("the graph failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    let mut dropped = 0;
    for (what, child) in observers {
        let out = child.wait_with_output()?;
        let err = String::from_utf8_lossy(&out.stderr);
        if !out.status.success() {
            bail!("`dc {what}` failed: {err}");
        }
        // "N frames, D dropped" (topic tools) or "dropped D" (record).
        for line in err.lines().chain(String::from_utf8_lossy(&out.stdout).lines()) {
            let words: Vec<&str> = line.split_whitespace().collect();
            for w in words.windows(2) {
                if let (Ok(n), "dropped") = (w[0].trim_end_matches(',').parse::<u64>(), w[1]) {
                    dropped += n;
                }
            }
        }
    }
    let (rate, steps) = throughput(&recording, window_from)?;
    Ok((rate, steps, dropped))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn run(args: &ObserveBenchArgs) -> Result<()> {
    find_binary("dc-sim").context("dc-sim not built (cargo build --workspace --bins)")?;
    let dir: PathBuf = std::env::temp_dir().join(launch::unique_namespace("bench-observe"));
    std::fs::create_dir_all(&dir)?;
    println!(
        "simulator throughput alone and watched (echo bodies, hz stats/solve, bw contacts, record -a): \
         ball-box, {} bodies, {} steps, window from {:?} after the topics appear, {} runs each",
        args.n, args.steps, SETTLE, args.repeat
    );
    println!("{:<10} {:>10} {:>14} {:>16}", "variant", "steps/s", "window steps", "observer drops");
    let mut medians = Vec::new();
    for observed in [false, true] {
        let mut rates = Vec::new();
        for r in 0..args.repeat.max(1) {
            let (rate, steps, dropped) = run_once(&dir, args, observed, r)?;
            let label = if observed { "watched" } else { "alone" };
            println!("{label:<10} {rate:>10.1} {steps:>14} {dropped:>16}");
            rates.push(rate);
        }
        medians.push(median(rates));
    }
    println!(
        "median steps/s: alone {:.1}, watched {:.1}: watched/alone {:.3}x ({:+.1}% throughput)",
        medians[0],
        medians[1],
        medians[1] / medians[0],
        (medians[1] / medians[0] - 1.0) * 100.0
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
