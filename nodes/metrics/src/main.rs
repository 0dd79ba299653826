//! dc-metrics: collects `SolveStats` and control messages, publishes a small per-step summary for
//! live plots, and writes the report folder when the expected runs have ended (or on shutdown, then
//! saying what is missing).

use anyhow::{Context, Result};
use clap::Parser;
use metrics::merge::RecordsFile;
use metrics::{report, Aggregate, Completeness, StepRecord};
use msgs::topics;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(name = "dc-metrics", about = "Aggregates solver statistics and writes the evaluation report")]
struct Args {
    /// Report folder (default: reports/metrics-<unix seconds>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the report and exit once this many runs have ended (0: run until stopped).
    #[arg(long, default_value_t = 0)]
    runs: usize,
    /// Title of the report.
    #[arg(long, default_value = "Warm-start evaluation")]
    title: String,
    /// A step is settled once every body stays slower than this (m/s) for the rest of its
    /// simulation (above 0, at most 1000).
    #[arg(long, default_value_t = 0.1, value_parser = msgs::flags::f32_above(0.0, 1000.0))]
    settle_speed: f32,
    /// First steps of the step-range phases after the first, comma-separated and increasing
    /// (`100,150`: steps 0-99, 100-149, 150-end; the last is the late phase of the accuracy table;
    /// empty: one phase). Default: 2/5 and 3/5 of the simulations' steps (100,150 at 250).
    #[arg(long, value_parser = parse_phases)]
    phases: Option<Phases>,
    /// Build the report from an earlier report's `steps.csv` instead of listening on the bus (its
    /// tables and plots as this version makes them; the convergence plot needs the per-sweep
    /// residuals, which the file does not keep).
    #[arg(long, value_name = "STEPS_CSV")]
    from_steps: Option<PathBuf>,
    /// Also keep every step received, with its per-sweep residuals, in OUT/records.cbor: what
    /// `--merge` needs of a shard (`dc eval --shard` asks for it).
    #[arg(long)]
    records: bool,
    /// Build one report from the folders of a sharded run (`dc eval --shard I/N`; what `dc report
    /// merge` runs): every shard present once, finished, of one run's settings and build, else
    /// refused before anything is written. Needs --out.
    #[arg(long, value_name = "SHARD_DIR", num_args = 1.., conflicts_with_all = ["from_steps", "records"])]
    merge: Vec<PathBuf>,
}

#[derive(Debug, Clone)]
struct Phases(Vec<u32>);

fn parse_phases(s: &str) -> Result<Phases, String> {
    metrics::phases::parse_boundaries(s).map(Phases)
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    if let Some(steps) = &args.from_steps {
        return report_from_steps(&args, steps);
    }
    if !args.merge.is_empty() {
        return report_from_shards(&args);
    }
    let node = runtime::Node::from_env("dc-metrics")?;
    let mut stats = node.subscriber(topics::SOLVE_STATS)?;
    let mut control = node.subscriber(topics::CONTROL)?;
    let mut live = node.publisher(topics::METRICS_STEP)?;
    if !node.ready()? {
        return Ok(());
    }
    let out = args.out.clone().unwrap_or_else(default_out);

    let mut aggregate = Aggregate::new();
    aggregate.settle_speed = args.settle_speed;
    aggregate.phase_boundaries = args.phases.as_ref().map(|p| p.0.clone());
    let mut completeness = Completeness::default();
    // Per model: cumulative sweeps, for the live summary.
    let mut cumulative: BTreeMap<String, u64> = BTreeMap::new();
    let mut dropped = 0u64;
    // Frames of a recording played into this graph (`dc play --into-live`): not our runs.
    let mut replayed = 0u64;
    let mut handle_stats = |r: &runtime::Received<msgs::SolveStatsHeader, f32>,
                            aggregate: &mut Aggregate,
                            completeness: &mut Completeness|
     -> Result<()> {
        if msgs::is_replayed(r.header().step.run_id) {
            replayed += 1;
            return Ok(());
        }
        if let Some(why) = completeness.implausible(r.header()) {
            // Logged once in full, then counted: a flood of bad frames must not flood the log.
            if dropped == 0 {
                tracing::error!(topic = topics::SOLVE_STATS.name, "dropped an impossible statistics frame: {why}");
            }
            dropped += 1;
            return Ok(());
        }
        let record = StepRecord::from_msg(r.header(), r.items());
        completeness.step(record.run_id, record.simulation, record.step, &record.model);
        let total = cumulative.entry(record.model.clone()).or_default();
        *total += record.sweeps as u64;
        // Live: the step's header and [cumulative sweeps of its model, sweeps of this step].
        live.publish(r.header(), &[*total as f32, record.sweeps as f32])?;
        aggregate.add(record);
        Ok(())
    };

    let mut replayed_control = 0u64;
    loop {
        while let Some(c) = control.try_recv()? {
            if msgs::is_replayed(c.header().step.run_id) {
                replayed_control += 1;
                continue;
            }
            completeness.control(c.header(), c.items());
            node.observe_control(c.header());
        }
        if args.runs > 0 && completeness.runs_ended() >= args.runs {
            break;
        }
        if node.is_shutdown() {
            tracing::warn!("stopped before every run ended: the report will say what is missing");
            break;
        }
        if let Some(r) = stats.recv_timeout(Duration::from_millis(20))? {
            handle_stats(&r, &mut aggregate, &mut completeness)?;
        }
    }
    // Statistics published before a run's end are already queued: take them all.
    while let Some(r) = stats.try_recv()? {
        handle_stats(&r, &mut aggregate, &mut completeness)?;
    }
    while let Some(c) = control.try_recv()? {
        if !msgs::is_replayed(c.header().step.run_id) {
            completeness.control(c.header(), c.items());
        }
    }
    if replayed + replayed_control > 0 {
        tracing::info!(
            statistics = replayed,
            control = replayed_control,
            "left out frames of replayed runs (dc play --into-live)"
        );
    }

    let mut missing = completeness.missing();
    if dropped > 0 {
        tracing::warn!(topic = topics::SOLVE_STATS.name, dropped, "impossible statistics frames were dropped");
        missing.push(format!("{}: {dropped} impossible frames dropped (see the log)", topics::SOLVE_STATS.name));
    }
    for m in &missing {
        tracing::warn!("missing: {m}");
    }
    // The solver the runs announced belongs in the title: reports under different solvers
    // (`dc-sim --relaxation`, `--compliance`) must not be read as one.
    let solvers = completeness.solvers();
    write_and_print(&aggregate, &out, &metrics::merge::titled(&args.title, &solvers), &missing)?;
    if args.records {
        let path = RecordsFile::of(&aggregate, &args.title, &solvers, &missing).write(&out)?;
        tracing::info!(file = %path.display(), "kept every step for a merge");
    }
    if stats.decode_errors() > 0 {
        tracing::warn!(errors = stats.decode_errors(), "undecodable statistics payloads were skipped");
    }
    Ok(())
}

fn default_out() -> PathBuf {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    PathBuf::from(format!("reports/metrics-{secs}"))
}

/// Writes the report and prints its tables.
fn write_and_print(aggregate: &Aggregate, out: &std::path::Path, title: &str, missing: &[String]) -> Result<()> {
    let written = report::write(aggregate, out, title, missing)?;
    println!("{}", report::summary_markdown(&written.summaries));
    if !aggregate.is_empty() {
        println!("{}", report::phases_markdown(&written.phases));
        println!("{}", report::accuracy_markdown(&written.accuracy));
    }
    println!("report: {}", written.dir.join("report.html").display());
    Ok(())
}

/// `--from-steps`: the report of an earlier run's steps, without the bus.
fn report_from_steps(args: &Args, steps: &std::path::Path) -> Result<()> {
    let aggregate = report::aggregate_steps(steps, args.settle_speed, args.phases.as_ref().map(|p| p.0.as_slice()))?;
    let out = args.out.clone().unwrap_or_else(default_out);
    let missing = [
        format!("{}: per-sweep residuals are not kept in steps.csv, so the convergence plot is empty", steps.display()),
        "the solver settings the runs announced are not kept in steps.csv either: the title is --title's".to_string(),
    ];
    write_and_print(&aggregate, &out, &args.title, &missing)
}

/// `--merge`: the report of a sharded run, from its shards' folders.
fn report_from_shards(args: &Args) -> Result<()> {
    let out = args.out.clone().context("--merge needs --out DIR (where the merged report goes)")?;
    let merged = metrics::merge::merge(&args.merge)?;
    let canonical = |p: &std::path::Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    if let Some(dir) = args.merge.iter().find(|d| canonical(d) == canonical(&out)) {
        anyhow::bail!(
            "--out {} is one of the shard folders ({}): the merge would overwrite a shard's report",
            out.display(),
            dir.display()
        );
    }
    let text = serde_json::to_string_pretty(&merged.summary())?;
    let mut aggregate = merged.aggregate;
    aggregate.settle_speed = args.settle_speed;
    aggregate.phase_boundaries = args.phases.as_ref().map(|p| p.0.clone());
    write_and_print(&aggregate, &out, &merged.title, &[])?;
    let path = out.join("merged.json");
    std::fs::write(&path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    println!("merged {} shards: {}", merged.shards.len(), path.display());
    Ok(())
}
