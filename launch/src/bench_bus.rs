//! `dc bench bus`: one-way latency and throughput of the bus, each payload through an in-process
//! channel (the floor), the transports' own APIs (`dc-bench-bus --raw`: iceoryx2 and zenoh used
//! directly, the baseline) and our runtime's ports over each, with the ratios of ours to raw.
//! Every case is a real two-process graph (source -> sink) started by the launcher; `--repeat`
//! runs interleave the variants and the medians are reported. `--csv` writes the rows and ratios
//! (CI keeps it as an artifact: figures, not an assertion).

use anyhow::{bail, Context, Result};
use bench_bus::BenchResult;
use launch::graph::{find_binary, Graph, NodeSpec, DEFAULT_HOST};
use launch::supervisor::{self, Output};
use runtime::Transport;
use std::path::PathBuf;

/// Options of `dc bench bus`.
#[derive(clap::Args, Debug)]
pub struct BusBenchArgs {
    /// Frames in the throughput phase (100 bodies: 50 times as many), ~0.2 s of traffic each: a
    /// shorter phase is timed mostly by the scheduler.
    #[arg(long, default_value_t = 2000)]
    count: u32,
    /// Frames in the latency phase.
    #[arg(long, default_value_t = 300)]
    latency_count: u32,
    /// Runs of each case, interleaved (medians of p50, p99 and throughput are reported).
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Payloads to measure: `small` (100 bodies), `large` (10,000 bodies), `grid` (7x128x128).
    #[arg(long, value_delimiter = ',', default_value = "small,large,grid")]
    payloads: Vec<Payload>,
    /// Also write the rows and the ours/raw ratios to this CSV file.
    #[arg(long)]
    csv: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, clap::ValueEnum)]
pub enum Payload {
    Small,
    Large,
    Grid,
}

/// The ratio targets of the bus: ours against the raw transport (p50 at most, throughput at
/// least).
const TARGETS: [(&str, f64, f64); 2] = [("iceoryx2", 1.2, 0.9), ("zenoh", 1.5, 0.7)];

/// One transport variant of a case.
#[derive(Clone, Copy, PartialEq)]
enum Variant {
    InProcess,
    Raw(&'static str),
    Ours(&'static str),
}

impl Variant {
    const ALL: [Variant; 5] = [
        Variant::InProcess,
        Variant::Raw("iceoryx2"),
        Variant::Ours("iceoryx2"),
        Variant::Raw("zenoh"),
        Variant::Ours("zenoh"),
    ];

    fn label(self) -> String {
        match self {
            Variant::InProcess => "inproc".into(),
            Variant::Raw(t) => format!("{t} raw"),
            Variant::Ours(t) => t.into(),
        }
    }
}

pub fn run(args: &BusBenchArgs, interrupted: &std::sync::Arc<std::sync::atomic::AtomicBool>) -> Result<()> {
    let program = find_binary("dc-bench-bus").context("dc-bench-bus not built (cargo build --workspace)")?;
    let payloads: [(Payload, &str, Vec<String>, u32); 3] = [
        (Payload::Small, "100 bodies", vec!["--kind=bodies".into(), "--n=100".into()], 50),
        (Payload::Large, "10,000 bodies", vec!["--kind=bodies".into(), "--n=10000".into()], 1),
        (Payload::Grid, "grid 7x128x128", vec!["--kind=grid".into()], 1),
    ];
    let repeat = args.repeat.max(1);
    println!(
        "one-way latency (p50, p99 of {} paced frames) and throughput ({} frames back to back, 100 bodies {}); median of {repeat} runs",
        args.latency_count,
        args.count,
        args.count * 50
    );
    println!(
        "{:<16} {:<14} {:>10} {:>10} {:>12} {:>10}",
        "payload", "transport", "p50 us", "p99 us", "frames/s", "MB/s"
    );
    let mut csv = String::from("payload,transport,p50_us,p99_us,frames_per_s,mb_per_s,p50_vs_raw,throughput_vs_raw\n");
    for (_, label, kind_args, more) in payloads.iter().filter(|p| args.payloads.contains(&p.0)) {
        let common = [format!("--count={}", args.count * more), format!("--latency-count={}", args.latency_count)];
        let mut runs: Vec<Vec<BenchResult>> = vec![Vec::new(); Variant::ALL.len()];
        for _ in 0..repeat {
            for (i, variant) in Variant::ALL.into_iter().enumerate() {
                let mut case = kind_args.clone();
                case.extend(common.iter().cloned());
                case.push(format!("--label={}", variant.label()));
                runs[i].push(one_case(&program, variant, &case, interrupted)?);
            }
        }
        let medians: Vec<BenchResult> = runs.iter().map(|r| median(r)).collect();
        let of = |v: Variant| &medians[Variant::ALL.iter().position(|x| *x == v).expect("a variant")];
        for (variant, m) in Variant::ALL.into_iter().zip(&medians) {
            println!(
                "{:<16} {:<14} {:>10.1} {:>10.1} {:>12.0} {:>10.1}",
                label,
                variant.label(),
                m.p50_us,
                m.p99_us,
                m.frames_per_s,
                m.mb_per_s
            );
            let raw = match variant {
                Variant::Ours(t) => Some(of(Variant::Raw(t))),
                _ => None,
            };
            let (p50_ratio, fps_ratio) = raw.map_or((String::new(), String::new()), |r| {
                (format!("{:.3}", m.p50_us / r.p50_us), format!("{:.3}", m.frames_per_s / r.frames_per_s))
            });
            csv.push_str(&format!(
                "{},{},{:.1},{:.1},{:.1},{:.1},{p50_ratio},{fps_ratio}\n",
                label.replace(',', ""),
                variant.label(),
                m.p50_us,
                m.p99_us,
                m.frames_per_s,
                m.mb_per_s
            ));
        }
        let ratios: Vec<String> = TARGETS
            .iter()
            .map(|(t, p50_max, fps_min)| {
                let (ours, raw) = (of(Variant::Ours(t)), of(Variant::Raw(t)));
                format!(
                    "{t} p50 {:.2}x (target <= {p50_max}), throughput {:.2}x (>= {fps_min})",
                    ours.p50_us / raw.p50_us,
                    ours.frames_per_s / raw.frames_per_s
                )
            })
            .collect();
        println!("{:<16} ours / raw: {}", "", ratios.join("; "));
    }
    if let Some(path) = &args.csv {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        std::fs::write(path, csv).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Medians of each figure over runs (each figure on its own).
fn median(runs: &[BenchResult]) -> BenchResult {
    let of = |f: fn(&BenchResult) -> f64| {
        let mut v: Vec<f64> = runs.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    BenchResult {
        p50_us: of(|r| r.p50_us),
        p99_us: of(|r| r.p99_us),
        frames_per_s: of(|r| r.frames_per_s),
        mb_per_s: of(|r| r.mb_per_s),
        ..runs[0].clone()
    }
}

fn one_case(
    program: &std::path::Path,
    variant: Variant,
    args: &[String],
    interrupted: &std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> Result<BenchResult> {
    let line = match variant {
        Variant::InProcess => {
            let out = std::process::Command::new(program).arg("--role=inproc").args(args).output()?;
            if !out.status.success() {
                bail!("in-process bench failed: {}", String::from_utf8_lossy(&out.stderr));
            }
            String::from_utf8_lossy(&out.stdout).lines().last().unwrap_or_default().to_string()
        }
        Variant::Raw(t) | Variant::Ours(t) => {
            let mut args = args.to_vec();
            if matches!(variant, Variant::Raw(_)) {
                args.push("--raw".into());
            }
            let graph = bench_graph(&args, t == "zenoh")?;
            let report = supervisor::run(&graph, DEFAULT_HOST, Output::Capture, interrupted)?;
            report.stdout.get("sink").and_then(|l| l.last().cloned()).context("sink printed no result")?
        }
    };
    serde_json::from_str(&line).with_context(|| format!("bad result line `{line}` ({})", variant.label()))
}

/// A two-node graph (source -> sink) over one transport, in its own namespace.
pub fn bench_graph(args: &[String], zenoh: bool) -> Result<Graph> {
    let node = |role: &str| {
        let args = std::iter::once(format!("--role={role}")).chain(args.iter().cloned()).collect();
        NodeSpec::new(role, "dc-bench-bus", false, args)
            .with_env("RUST_LOG", "warn,zenoh::net::runtime::orchestrator=error")
    };
    let mut graph =
        Graph::single_host("bench-bus", &launch::unique_namespace("bench"), vec![node("sink"), node("source")])?;
    graph.check_params()?;
    if zenoh {
        for t in [msgs::topics::BENCH_BODIES.name, msgs::topics::BENCH_GRID.name] {
            graph.topics.insert(t.into(), Transport::Zenoh);
        }
    }
    Ok(graph)
}
