//! `dc-record`: records every topic of a graph (or `--topics a,b`) into one MCAP file per run;
//! `dc-record info FILE` and `dc-record recover IN OUT` inspect and repair recordings.

use anyhow::Context;
use clap::{Parser, Subcommand};
use msgs::HasStep;
use msgs::{ControlKind, FrameHeader, FrameItem};
use recorder::read::ReadOptions;
use recorder::{now_ns, utc_stamp, FrameKind, RecordingWriter};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

// In a folder of its own: a file directly in src/bin would be taken for a binary.
#[path = "dc-record/attach.rs"]
mod attach;
#[path = "dc-record/bench.rs"]
mod bench;
#[path = "dc-record/notes.rs"]
mod notes;

#[derive(Parser, Debug)]
#[command(
    about = "Record a Deep Contact graph to MCAP; inspect and repair recordings",
    long_about = "Record a Deep Contact graph to MCAP; inspect and repair recordings.\n\n\
        In a launch file, dc-record is a node of the graph (--topics, --out or --dir). From a \
        terminal, `dc record -a` or `dc record TOPIC...` attaches to a graph that is already \
        running and records until Ctrl-C, --duration or the graph's end."
)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// Attach to a running graph and record these topics (`dc record bodies stats/solve`).
    #[arg(value_name = "TOPICS", conflicts_with = "all")]
    attach_topics: Vec<String>,
    /// Attach to a running graph and record every topic alive in its namespace.
    #[arg(short = 'a', long)]
    all: bool,
    /// Attaching: the graph's namespace (default: the only one running on this host).
    #[arg(long)]
    namespace: Option<String>,
    /// Attaching: reach the graph over zenoh through this endpoint (`tcp/127.0.0.1:7447`).
    #[arg(long, value_name = "ENDPOINT")]
    zenoh: Option<String>,
    /// Attaching: never drop a frame; a recorder that falls behind then holds the graph back.
    #[arg(long)]
    reliable: bool,
    /// Attaching: stop after this long (`30s`); default: Ctrl-C or the graph's end.
    #[arg(long, value_parser = runtime::parse_duration)]
    duration: Option<Duration>,
    /// As a graph's node: topics to record, comma separated (default: every known topic).
    #[arg(long, value_delimiter = ',')]
    topics: Vec<String>,
    /// Write everything to this one file instead of one file per run under `--dir`. A file already
    /// there is refused (before the graph starts) unless `--overwrite`.
    #[arg(short = 'o', long)]
    out: Option<PathBuf>,
    /// Let `--out` truncate a file already at its path.
    #[arg(long, requires = "out")]
    overwrite: bool,
    /// Folder of the per-run files `run-<run id>-<UTC time>.mcap`.
    #[arg(long, default_value = "recordings")]
    dir: PathBuf,
    /// Longest time between chunk flushes, in milliseconds (a kill loses at most this much).
    #[arg(long, default_value_t = 1000)]
    flush_ms: u64,
    /// At the end, write the counts (received, dropped, bytes, active time, CPU time) as JSON here.
    #[arg(long)]
    stats_json: Option<PathBuf>,
    /// Also write each recording as Foxglove sees it (scene, grids, heat maps, statistics in
    /// Foxglove's schemas), `NAME.foxglove.mcap` beside `NAME.mcap`, once it is finished: the
    /// conversion of `dc-foxglove viz`, run by it.
    #[arg(long)]
    foxglove: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Topics, types, counts, time range, simulations and steps, size and compression of a
    /// recording; exits 1 on damage, recordings concatenated in one file or a summary section
    /// that does not match the data.
    Info { file: PathBuf },
    /// Rewrite a recording whose writer was killed (or that is damaged, or several concatenated)
    /// into a valid indexed file; OUTPUT is replaced only when complete, and never the input.
    Recover { input: PathBuf, output: PathBuf },
    /// Record a live simulator (dc-sim + dc-record through `dc launch`, 10,000 bodies by default)
    /// and print drops, msgs/s, MB/s, the recorder's CPU time and the compression ratio.
    Bench(bench::BenchArgs),
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> anyhow::Result<()> {
    // An existing `--out` is refused when the parameters are checked, so `dc launch` refuses the
    // graph before any node starts; creating the file refuses it again (a file made meanwhile).
    let Some(args) = runtime::parse_args_checked::<Args, recorder::Error>(|a| match &a.out {
        Some(path) if a.command.is_none() && !a.overwrite && std::fs::symlink_metadata(path).is_ok() => {
            Err(recorder::Error::Exists { path: path.clone() })
        }
        _ => Ok(()),
    }) else {
        return Ok(());
    };
    runtime::init_logging();
    match &args.command {
        Some(Command::Info { file }) => {
            // Lenient: everything intact is counted and the damage listed; damage, recordings
            // concatenated and a bad summary section still fail.
            let info = recorder::Info::read_with(file, ReadOptions { lenient: true, ..Default::default() })?;
            show(&info)?;
            match info.problem() {
                Some(e) => Err(e.into()),
                None => Ok(()),
            }
        }
        Some(Command::Recover { input, output }) => {
            // Bytes read, with the time left, on a terminal only (hidden otherwise).
            let bar = indicatif::ProgressBar::new(0);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "recover [{bar:30}] {bytes}/{total_bytes} ({elapsed}, ~{eta} left)",
                )
                .expect("valid template")
                .progress_chars("=> "),
            );
            let r = recorder::recover::recover_with_progress(input, output, &mut |read, size| {
                bar.set_length(size);
                bar.set_position(read);
            });
            bar.finish_and_clear();
            let r = r?;
            if r.input_was_sound() {
                tracing::info!("input was intact");
            }
            show(format_args!(
                "recovered {} messages on {} channels, {} metadata records into {}\n",
                r.messages,
                r.channels,
                r.metadata,
                output.display()
            ))?;
            // Per topic kept and skipped, each damaged region skipped (the reader logged it), the
            // recordings found after the first and what was wrong with the input's summary.
            show(&r)
        }
        Some(Command::Bench(bench_args)) => bench::run(bench_args),
        None if args.all || !args.attach_topics.is_empty() => {
            let path = attach::record(&attach::Attach {
                topics: &args.attach_topics,
                namespace: args.namespace.as_deref(),
                zenoh: args.zenoh.as_deref(),
                out: args.out.as_deref(),
                overwrite: args.overwrite,
                dir: &args.dir,
                reliable: args.reliable,
                duration: args.duration,
                flush_every: Duration::from_millis(args.flush_ms.max(1)),
                metadata: recorder_metadata("dc-record"),
            })?;
            if args.foxglove {
                foxglove_view(&path)?;
            }
            Ok(())
        }
        None if !in_a_graph() => anyhow::bail!(
            "say what to record from the running graph: `dc record -a` (every topic) or `dc record TOPIC...`; \
             `dc record info FILE` and `dc record recover IN OUT` inspect and repair recordings (`dc record --help`)"
        ),
        None => record(&args),
    }
}

/// A subscriber of one topic that hands out its frames as CBOR.
trait RecordedTopic {
    fn topic(&self) -> &str;
    fn kind(&self) -> FrameKind;
    /// Takes up to `max` waiting frames: `(step, encoded frame)` each.
    fn poll(&mut self, max: usize, out: &mut Vec<(msgs::StepHeader, Vec<u8>)>) -> anyhow::Result<()>;
    fn received(&self) -> u64;
    fn decode_errors(&self) -> u64;
}

struct Typed<H: FrameHeader, T: FrameItem> {
    kind: FrameKind,
    sub: runtime::Subscriber<H, T>,
}

impl<H: FrameHeader + HasStep, T: FrameItem> RecordedTopic for Typed<H, T> {
    fn topic(&self) -> &str {
        self.sub.topic()
    }
    fn kind(&self) -> FrameKind {
        self.kind
    }
    fn poll(&mut self, max: usize, out: &mut Vec<(msgs::StepHeader, Vec<u8>)>) -> anyhow::Result<()> {
        for _ in 0..max {
            let Some(r) = self.sub.try_recv()? else { break };
            let mut bytes = Vec::with_capacity(64 + std::mem::size_of_val(r.items()));
            msgs::encode_into(r.header(), r.items(), &mut bytes)?;
            out.push((r.header().step_header(), bytes));
        }
        Ok(())
    }
    fn received(&self) -> u64 {
        self.sub.received()
    }
    fn decode_errors(&self) -> u64 {
        self.sub.decode_errors()
    }
}

fn subscribe(node: &runtime::Node, topic: &str) -> anyhow::Result<Box<dyn RecordedTopic>> {
    let kind = FrameKind::of_topic(topic)
        .with_context(|| format!("unknown topic `{topic}` (known: {})", msgs::topics::names_list()))?;
    fn typed<H: FrameHeader + HasStep, T: FrameItem>(
        node: &runtime::Node,
        topic: &str,
        kind: FrameKind,
    ) -> anyhow::Result<Box<dyn RecordedTopic>> {
        Ok(Box::new(Typed { kind, sub: node.subscriber_named::<H, T>(topic)? }))
    }
    msgs::with_frame_types!(kind, typed(node, topic, kind))
}

/// One open recording file.
struct Open {
    writer: RecordingWriter,
    last_flush: Instant,
}

/// The recorder's files: one per run id (or one for all with `--out`).
struct Files<'a> {
    args: &'a Args,
    node_metadata: BTreeMap<String, String>,
    topics: Vec<(String, FrameKind)>,
    open: BTreeMap<u64, Open>,
    /// Runs whose end was announced, closed after a grace period for frames still in other queues.
    ending: BTreeMap<u64, Instant>,
    finished: Vec<(PathBuf, u64)>,
}

/// After a shutdown, how long topics over zenoh must stay quiet before the recorder ends, and
/// the longest it waits for that.
const ZENOH_DRAIN_QUIET: Duration = Duration::from_millis(500);
const ZENOH_DRAIN_MAX: Duration = Duration::from_secs(5);

/// How long a run's file stays open after its `RunEnd` for frames still queued on other topics.
const RUN_END_GRACE: Duration = Duration::from_secs(1);

impl Files<'_> {
    /// The file of `run_id`, opened on its first message.
    fn file(&mut self, run_id: u64) -> anyhow::Result<&mut Open> {
        let key = if self.args.out.is_some() { 0 } else { run_id };
        if !self.open.contains_key(&key) {
            let mut writer = match &self.args.out {
                Some(p) if self.args.overwrite => RecordingWriter::create(p)?,
                Some(p) => RecordingWriter::create_new(p)?,
                None => self.new_run_file(run_id)?,
            };
            let path = writer.path().to_path_buf();
            for (topic, kind) in &self.topics {
                writer.add_channel(topic, *kind)?;
            }
            let mut meta = self.node_metadata.clone();
            meta.insert("run_id".into(), run_id.to_string());
            writer.write_metadata("dc-record", meta)?;
            tracing::info!(path = %path.display(), run_id, "recording");
            self.open.insert(key, Open { writer, last_flush: Instant::now() });
        }
        Ok(self.open.get_mut(&key).expect("inserted above"))
    }

    /// A new file for `run_id` under `--dir`: `run-<id>-<UTC time>.mcap`, or with `-2`, `-3`, ...
    /// appended when another recorder (of this graph or another) took that name first.
    fn new_run_file(&self, run_id: u64) -> anyhow::Result<RecordingWriter> {
        let stem = format!("run-{run_id}-{}", utc_stamp(SystemTime::now()));
        Ok(RecordingWriter::create_numbered(&self.args.dir, &stem)?)
    }

    fn finish(&mut self, run_id: u64) -> anyhow::Result<()> {
        let key = if self.args.out.is_some() { 0 } else { run_id };
        if self.args.out.is_some() {
            // One file for all runs: a run end is only a flush point.
            if let Some(open) = self.open.get_mut(&key) {
                open.writer.flush()?;
                open.last_flush = Instant::now();
            }
            return Ok(());
        }
        if let Some(open) = self.open.remove(&key) {
            let path = open.writer.path().to_path_buf();
            let n = open.writer.finish()?;
            tracing::info!(path = %path.display(), messages = n, "recording finished");
            self.finished.push((path, n));
        }
        Ok(())
    }

    fn flush_due(&mut self, every: Duration) -> anyhow::Result<()> {
        for open in self.open.values_mut() {
            if open.last_flush.elapsed() >= every {
                open.writer.flush()?;
                open.last_flush = Instant::now();
            }
        }
        Ok(())
    }

    fn finish_all(&mut self) -> anyhow::Result<()> {
        for (_, open) in std::mem::take(&mut self.open) {
            let path = open.writer.path().to_path_buf();
            let n = open.writer.finish()?;
            tracing::info!(path = %path.display(), messages = n, "recording finished");
            self.finished.push((path, n));
        }
        Ok(())
    }
}

fn record(args: &Args) -> anyhow::Result<()> {
    let node = runtime::Node::from_env("dc-record")?;
    let names: Vec<String> =
        if args.topics.is_empty() { msgs::topics::names().map(str::to_string).collect() } else { args.topics.clone() };
    let mut subs = names.iter().map(|t| subscribe(&node, t)).collect::<anyhow::Result<Vec<_>>>()?;
    // Control last in every pass: the data a control message follows is taken first.
    subs.sort_by_key(|s| s.kind() == FrameKind::Control);

    let mut node_metadata = recorder_metadata(node.name());
    node_metadata.insert("namespace".to_string(), node.bus().namespace.clone());
    let mut files = Files {
        args,
        node_metadata,
        topics: subs.iter().map(|s| (s.topic().to_string(), s.kind())).collect(),
        open: BTreeMap::new(),
        ending: BTreeMap::new(),
        finished: Vec::new(),
    };

    if !node.ready()? {
        return Ok(());
    }
    tracing::info!(topics = %names.join(","), "recording");
    let flush_every = Duration::from_millis(args.flush_ms.max(1));
    let mut batch = Vec::new();
    // A refused write stops the recorder (below), so a run that ends well dropped nothing.
    let write_failed = 0u64;
    let started = Instant::now();
    let mut bytes = 0u64;
    let mut first_frame: Option<Instant> = None;
    let mut last_frame = started;
    let over_zenoh = names.iter().any(|t| node.bus().transport(t).uses_zenoh());
    let mut stopped_at: Option<Instant> = None;
    loop {
        let stopping = node.is_shutdown();
        let mut got = 0;
        for sub in subs.iter_mut() {
            batch.clear();
            sub.poll(64, &mut batch)?;
            got += batch.len();
            if !batch.is_empty() {
                last_frame = Instant::now();
                first_frame.get_or_insert(last_frame);
            }
            let log_time = now_ns();
            for (step, data) in batch.drain(..) {
                bytes += data.len() as u64;
                if sub.kind() == FrameKind::Control && is_graph_notice(&data) {
                    // A launcher's notice (node down / up) belongs to every run in progress.
                    for open in files.open.values_mut() {
                        open.writer.write(sub.topic(), sub.kind(), log_time, log_time, &data)?;
                    }
                    continue;
                }
                let open = files.file(step.run_id)?;
                // A refused write (a full disk ...) stops the recorder with that one error: the
                // writer keeps its file as it was after the last flush (`recover` rescues it),
                // the other open files are finished as the recorder's values drop.
                open.writer.write(sub.topic(), sub.kind(), log_time, log_time, &data)?;
                if sub.kind() == FrameKind::Control {
                    let c: msgs::Control = msgs::decode_header(&data)?;
                    node.observe_control(&c);
                    match c.kind() {
                        Some(ControlKind::SimulationEnd) => {
                            open.writer.flush()?;
                            open.last_flush = Instant::now();
                        }
                        Some(ControlKind::RunStart) => {
                            notes::note_control(&mut open.writer, &data, step)?;
                        }
                        Some(ControlKind::RunEnd) => {
                            open.writer.flush()?;
                            open.last_flush = Instant::now();
                            files.ending.insert(step.run_id, Instant::now());
                        }
                        _ => {}
                    }
                }
            }
        }
        files.flush_due(flush_every)?;
        let ended: Vec<u64> =
            files.ending.iter().filter(|(_, t)| t.elapsed() >= RUN_END_GRACE).map(|(r, _)| *r).collect();
        for run in ended {
            files.ending.remove(&run);
            files.finish(run)?;
        }
        if got == 0 {
            if stopping {
                // Shut down and drained. Frames over zenoh may still be on their way (the graph
                // stops a recorder when its writers end, and their last frames cross sockets and
                // perhaps a router): wait until the topics have been quiet a while.
                let stopped = *stopped_at.get_or_insert_with(Instant::now);
                let quiet = last_frame.elapsed().min(stopped.elapsed());
                if !over_zenoh || quiet >= ZENOH_DRAIN_QUIET || stopped.elapsed() >= ZENOH_DRAIN_MAX {
                    break;
                }
            }
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    files.finish_all()?;
    let elapsed = started.elapsed().as_secs_f64();
    let mut received = 0;
    let mut undecodable = 0;
    for s in &subs {
        received += s.received();
        undecodable += s.decode_errors();
        if s.received() > 0 || s.decode_errors() > 0 {
            tracing::info!(topic = s.topic(), received = s.received(), undecodable = s.decode_errors(), "topic");
        }
    }
    tracing::info!(
        received,
        undecodable,
        dropped = write_failed,
        mib = format!("{:.1}", bytes as f64 / (1 << 20) as f64),
        mib_per_s = format!("{:.1}", bytes as f64 / (1 << 20) as f64 / elapsed.max(1e-9)),
        files = files.finished.len(),
        "recorder done"
    );
    for (path, n) in &files.finished {
        println!("recorded {n} messages to {}", path.display());
    }
    if args.foxglove {
        for (path, _) in &files.finished {
            foxglove_view(path)?;
        }
    }
    println!("received {received}, undecodable {undecodable}, dropped {write_failed}");
    if let Some(path) = &args.stats_json {
        let stats = recorder::bench::RecorderStats {
            received,
            undecodable,
            write_failed,
            payload_bytes: bytes,
            active_s: first_frame.map_or(0.0, |first| (last_frame - first).as_secs_f64()),
            wall_s: elapsed,
            cpu_s: recorder::bench::process_cpu_seconds(),
        };
        recorder::write::replace_file(path, serde_json::to_string_pretty(&stats)?.as_bytes())?;
    }
    Ok(())
}

/// Writes the Foxglove view of a finished recording, `NAME.foxglove.mcap` beside it, with
/// `dc-foxglove viz` (found beside this binary, then on PATH), and says where and how long it took.
fn foxglove_view(recording: &std::path::Path) -> anyhow::Result<()> {
    let view = recording.with_extension("foxglove.mcap");
    let program = runtime::find_binary("dc-foxglove")
        .context("the Foxglove view needs dc-foxglove beside dc-record or on PATH (cargo build --workspace --bins)")?;
    let started = Instant::now();
    let out =
        std::process::Command::new(&program).arg("viz").arg(recording).arg(&view).output().with_context(|| {
            format!("running {} for the Foxglove view of {}", program.display(), recording.display())
        })?;
    if !out.status.success() {
        anyhow::bail!(
            "the Foxglove view of {} failed: {}",
            recording.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    println!("Foxglove view: {} ({:.1} s)", view.display(), started.elapsed().as_secs_f64());
    Ok(())
}

/// Prints `text` on stdout; a closed stdout (`dc-record info FILE | head`) ends the output quietly.
fn show(text: impl std::fmt::Display) -> anyhow::Result<()> {
    use std::io::Write;
    match write!(std::io::stdout().lock(), "{text}") {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e).context("writing to stdout"),
        _ => Ok(()),
    }
}

/// What every recording says about its recorder: node name, arguments, wire version, recorder
/// version, start time, git revision.
fn recorder_metadata(node: &str) -> BTreeMap<String, String> {
    let mut meta = BTreeMap::from([
        ("node".to_string(), node.to_string()),
        ("args".to_string(), std::env::args().skip(1).collect::<Vec<_>>().join(" ")),
        ("wire_version".to_string(), msgs::WIRE_VERSION.to_string()),
        ("recorder".to_string(), concat!("dc-record ", env!("CARGO_PKG_VERSION")).to_string()),
        ("started".to_string(), utc_stamp(SystemTime::now())),
    ]);
    if let Some(rev) = git_revision() {
        meta.insert("git_revision".into(), rev);
    }
    meta
}

/// Started as a graph's node (by a launcher, or by hand with a bus configuration in `DC_BUS`)
/// or asked for its ports, rather than from a terminal.
fn in_a_graph() -> bool {
    std::env::var_os("DC_BUS").is_some()
        || ["DC_LAUNCHED", "DC_DESCRIBE"].iter().any(|v| std::env::var(v).is_ok_and(|v| v == "1"))
}

/// A control message about the graph rather than a run (run id 0: node down / up).
fn is_graph_notice(data: &[u8]) -> bool {
    msgs::decode_header::<msgs::Control>(data)
        .is_ok_and(|c| matches!(c.kind(), Some(ControlKind::NodeDown | ControlKind::NodeUp)))
}

/// `git rev-parse HEAD` of the working directory, best effort.
fn git_revision() -> Option<String> {
    let out = std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}
