//! dc-foxglove: serves the graph's streams to Foxglove (WebSocket protocol, subprotocol
//! `foxglove.sdk.v1`) as well-known schemas; `dc-foxglove viz IN OUT` writes the same conversion of
//! a recording as an MCAP file for Foxglove's file mode: every step, at simulation time.

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use foxglove_bridge::convert::SceneStyle;
use foxglove_bridge::timeline::{FileClock, Timeline};
use foxglove_bridge::{Bridge, BridgeConfig, Rates};
use msgs::FrameKind;
use msgs::{topics, ControlDetails, ControlKind, FrameHeader, FrameItem};
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

#[derive(Parser, Debug)]
#[command(
    name = "dc-foxglove",
    about = "Live Foxglove bridge of a Deep Contact graph; `viz` converts a recording for Foxglove's file mode",
    args_conflicts_with_subcommands = true
)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    node: NodeArgs,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Convert a recording (a `dc-record` MCAP file or a folder of them) into an MCAP file of
    /// Foxglove schemas (scene, grids, heat maps, JSON statistics): every recorded step, stamped
    /// with simulation time (step x dt from the run's parameters).
    Viz {
        input: PathBuf,
        output: PathBuf,
        #[command(flatten)]
        style: StyleArgs,
    },
}

/// Parameters of the node.
#[derive(clap::Args, Debug)]
struct NodeArgs {
    /// Address of the WebSocket server, `HOST:PORT` (port 0: any free port, logged at start).
    #[arg(long, default_value = "127.0.0.1:8765", value_parser = parse_address)]
    address: (String, u16),
    /// Bus topics to bridge, comma separated (default: every topic Foxglove can show).
    #[arg(long, value_delimiter = ',')]
    topics: Vec<String>,
    /// Messages each client may have queued before the oldest are dropped (1 to 65536).
    #[arg(long, default_value_t = 256,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_BACKLOG))]
    backlog: usize,
    /// Most messages per second per topic for the scene, grids and heat maps (0: unlimited; at
    /// most 10000).
    #[arg(long, default_value_t = 30.0, value_parser = msgs::flags::f64_in(0.0, MAX_HZ))]
    max_hz: f64,
    /// Most messages per second per topic for the JSON statistics (0: unlimited; at most 10000).
    #[arg(long, default_value_t = 100.0, value_parser = msgs::flags::f64_in(0.0, MAX_HZ))]
    plot_hz: f64,
    #[command(flatten)]
    style: StyleArgs,
}

impl NodeArgs {
    fn config(&self) -> BridgeConfig {
        BridgeConfig::live(Rates { max_hz: self.max_hz, plot_hz: self.plot_hz }, self.style.style())
    }
}

/// How the scene is drawn.
#[derive(clap::Args, Debug, Clone)]
struct StyleArgs {
    /// Contact arrow length per unit of normal impulse, metres per N·s (above 0, at most 1000).
    #[arg(long, default_value_t = 1.0, value_parser = msgs::flags::f32_above(0.0, MAX_STYLE))]
    impulse_scale: f32,
    /// Longest contact arrow, metres (above 0, at most 1000; the thesis box is 15 m wide).
    #[arg(long, default_value_t = 2.0, value_parser = msgs::flags::f32_above(0.0, MAX_STYLE))]
    max_arrow: f32,
}

/// Highest rate limit (`--max-hz`, `--plot-hz`): far above any display's frame rate.
const MAX_HZ: f64 = 10_000.0;
/// Largest `--impulse-scale` and `--max-arrow`.
const MAX_STYLE: f32 = 1000.0;
/// Most messages queued per client (`--backlog`).
const MAX_BACKLOG: u64 = 65_536;

impl StyleArgs {
    fn style(&self) -> SceneStyle {
        SceneStyle { impulse_scale: self.impulse_scale, max_arrow: self.max_arrow }
    }
}

/// `HOST:PORT`, `[V6]:PORT`.
fn parse_address(s: &str) -> Result<(String, u16), String> {
    let (host, port) = s.rsplit_once(':').ok_or_else(|| format!("`{s}`: expected HOST:PORT"))?;
    let port = port.parse::<u16>().map_err(|_| format!("`{s}`: bad port `{port}`"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        return Err(format!("`{s}`: empty host"));
    }
    Ok((host.to_string(), port))
}

/// Bus topics bridged by default.
const DEFAULT_TOPICS: &[&str] = &[
    topics::BODIES.name,
    topics::CONTACTS.name,
    topics::SOLVE_STATS.name,
    topics::METRICS_STEP.name,
    topics::GRID_BODIES.name,
    topics::GRID_CONTACTS.name,
    topics::GRID_UNET.name,
    topics::CONTROL.name,
];

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> anyhow::Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    match args.command {
        Some(Command::Viz { input, output, style }) => viz(&input, &output, style.style()),
        None => serve(args.node),
    }
}

fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}

/// What the bridge does with one frame of a topic.
type Handler<H, T> = Box<dyn FnMut(&mut Bridge, &str, &H, &[T], u64) -> Result<(), foxglove_bridge::Error>>;

/// A subscriber feeding the bridge.
trait Source {
    fn topic(&self) -> &str;
    /// Hands up to `max` waiting frames to the bridge; how many there were.
    fn drain(&mut self, bridge: &mut Bridge, max: usize) -> anyhow::Result<usize>;
    /// Waits up to `timeout` for one frame (without spinning) and hands it over.
    fn wait(&mut self, bridge: &mut Bridge, timeout: Duration) -> anyhow::Result<usize>;
    fn received(&self) -> u64;
    fn errors(&self) -> u64;
}

struct Typed<H: FrameHeader, T: FrameItem> {
    sub: runtime::Subscriber<H, T>,
    handle: Handler<H, T>,
    /// Frames the bridge refused (bad grids), logged sparingly.
    errors: u64,
}

impl<H: FrameHeader, T: FrameItem> Typed<H, T> {
    fn give(&mut self, bridge: &mut Bridge, r: runtime::Received<H, T>) {
        let topic = self.sub.topic().to_string();
        if let Err(e) = (self.handle)(bridge, &topic, r.header(), r.items(), now_ns()) {
            self.errors += 1;
            if self.errors <= 10 || self.errors.is_multiple_of(1000) {
                tracing::warn!(topic = %topic, skipped = self.errors, "{e}");
            }
        }
    }
}

impl<H: FrameHeader, T: FrameItem> Source for Typed<H, T> {
    fn topic(&self) -> &str {
        self.sub.topic()
    }
    fn drain(&mut self, bridge: &mut Bridge, max: usize) -> anyhow::Result<usize> {
        let mut n = 0;
        while n < max {
            let Some(r) = self.sub.try_recv()? else { break };
            self.give(bridge, r);
            n += 1;
        }
        Ok(n)
    }
    fn wait(&mut self, bridge: &mut Bridge, timeout: Duration) -> anyhow::Result<usize> {
        match self.sub.recv_timeout(timeout)? {
            Some(r) => {
                self.give(bridge, r);
                Ok(1)
            }
            None => Ok(0),
        }
    }
    fn received(&self) -> u64 {
        self.sub.received()
    }
    fn errors(&self) -> u64 {
        self.errors + self.sub.decode_errors()
    }
}

fn source(node: &runtime::Node, topic: &str) -> anyhow::Result<Box<dyn Source>> {
    let kind = FrameKind::of_topic(topic)
        .with_context(|| format!("unknown topic `{topic}` (known: {})", topics::names_list()))?;
    Ok(match kind {
        FrameKind::ProblemBodies | FrameKind::ProblemContacts => {
            anyhow::bail!("topic `{topic}`: the contact problem has no Foxglove view (the scene shows the contacts)")
        }
        FrameKind::Bodies => Box::new(Typed {
            sub: node.subscriber_named::<msgs::StepHeader, msgs::Body>(topic)?,
            handle: Box::new(|b, _, h, items, t| {
                b.on_bodies(h, items, t);
                Ok(())
            }),
            errors: 0,
        }),
        FrameKind::Contacts => Box::new(Typed {
            sub: node.subscriber_named::<msgs::StepHeader, msgs::Contact>(topic)?,
            handle: Box::new(|b, _, h, items, t| {
                b.on_contacts(h, items, t);
                Ok(())
            }),
            errors: 0,
        }),
        FrameKind::Grid => Box::new(Typed {
            sub: node.subscriber_named::<msgs::GridHeader, f32>(topic)?,
            handle: Box::new(|b, topic, h, items, t| b.on_grid(topic, h, items, t)),
            errors: 0,
        }),
        FrameKind::SolveStats => Box::new(Typed {
            sub: node.subscriber_named::<msgs::SolveStatsHeader, f32>(topic)?,
            handle: Box::new(|b, topic, h, items, t| {
                b.on_stats(topic, h, items, t);
                Ok(())
            }),
            errors: 0,
        }),
        FrameKind::Control => {
            let shutdown = node.shutdown_signal();
            Box::new(Typed {
                sub: node.subscriber_named::<msgs::Control, u8>(topic)?,
                handle: Box::new(move |b, _, c: &msgs::Control, details: &[u8], t| {
                    if c.kind() == Some(ControlKind::Shutdown) {
                        tracing::info!("shutdown requested by control message");
                        shutdown.set();
                    }
                    b.on_control(c, details, t);
                    Ok(())
                }),
                errors: 0,
            })
        }
    })
}

/// Frames taken from one subscriber per pass, so one busy topic cannot starve the others.
const BATCH: usize = 256;
/// Longest sleep when every queue is empty.
const IDLE_WAIT: Duration = Duration::from_millis(2);
/// How often the node logs what it forwarded.
const STATUS_EVERY: Duration = Duration::from_secs(10);

fn serve(args: NodeArgs) -> anyhow::Result<()> {
    let node = runtime::Node::from_env("dc-foxglove")?;
    let names: Vec<String> = if args.topics.is_empty() {
        DEFAULT_TOPICS.iter().map(|s| s.to_string()).collect()
    } else {
        args.topics.clone()
    };
    let mut sources = names.iter().map(|t| source(&node, t)).collect::<anyhow::Result<Vec<_>>>()?;
    // Control last in every pass: the data a control message follows is taken first.
    sources.sort_by_key(|s| s.topic() == topics::CONTROL.name);
    anyhow::ensure!(!sources.is_empty(), "no topics to bridge");

    let ctx = foxglove::Context::new();
    let mut bridge = Bridge::new(&ctx, args.config())?;
    let (host, port) = &args.address;
    // Served before the graph starts, so a client can be there from the first step.
    let server = ctx
        .websocket_server()
        .name(format!("dc-foxglove ({})", node.name()))
        .bind(host.clone(), *port)
        .message_backlog_size(args.backlog.max(1))
        .start_blocking()
        .with_context(|| format!("cannot serve Foxglove on {host}:{port}"))?;
    tracing::info!(url = %format!("ws://{host}:{}", server.port()), topics = %names.join(","), "serving Foxglove");

    if !node.ready()? {
        drop(server.stop());
        return Ok(());
    }
    let started = Instant::now();
    let mut last_status = Instant::now();
    loop {
        let stopping = node.is_shutdown();
        let mut got = 0;
        for s in sources.iter_mut() {
            got += s.drain(&mut bridge, BATCH)?;
        }
        if got == 0 {
            if stopping {
                break; // shut down and drained
            }
            sources[0].wait(&mut bridge, IDLE_WAIT)?;
        }
        if last_status.elapsed() >= STATUS_EVERY {
            last_status = Instant::now();
            let received: u64 = sources.iter().map(|s| s.received()).sum();
            let sent: u64 = bridge.counters.sent.values().sum();
            tracing::info!(clients = server.client_count(), received, sent, "bridging");
        }
    }
    let clients = server.client_count();
    // Dropping the shutdown handle aborts the client tasks at once: a graceful close would wait
    // on a client that stopped reading.
    drop(server.stop());

    let secs = started.elapsed().as_secs_f64();
    for s in &sources {
        if s.received() > 0 || s.errors() > 0 {
            tracing::info!(topic = s.topic(), received = s.received(), skipped = s.errors(), "bus topic");
        }
    }
    for (topic, n) in &bridge.counters.sent {
        tracing::info!(topic = %topic, sent = n, hz = format!("{:.1}", *n as f64 / secs.max(1e-9)), "foxglove topic");
    }
    let (scene, grids, stats) = bridge.throttled();
    tracing::info!(
        clients,
        bad_grids = bridge.counters.bad_grids,
        throttled_scene = scene,
        throttled_grids = grids,
        throttled_stats = stats,
        "foxglove bridge done"
    );
    Ok(())
}

/// Decodes one recorded frame and hands it to the bridge, stamped by `clock`; why not, when it
/// does not decode.
fn give_recorded(
    bridge: &mut Bridge,
    clock: &mut FileClock,
    kind: FrameKind,
    topic: &str,
    data: &[u8],
    log_time: u64,
) -> Result<(), String> {
    let bad = |e: msgs::CodecError| e.to_string();
    let r = match kind {
        FrameKind::Bodies => {
            let f = msgs::decode::<msgs::StepHeader, msgs::Body>(data).map_err(bad)?;
            bridge.on_bodies(&f.header, &f.items, clock.step(&f.header, log_time));
            Ok(())
        }
        FrameKind::Contacts => {
            let f = msgs::decode::<msgs::StepHeader, msgs::Contact>(data).map_err(bad)?;
            bridge.on_contacts(&f.header, &f.items, clock.step(&f.header, log_time));
            Ok(())
        }
        FrameKind::Grid => {
            let f = msgs::decode::<msgs::GridHeader, f32>(data).map_err(bad)?;
            bridge.on_grid(topic, &f.header, &f.items, clock.step(&f.header.step, log_time))
        }
        FrameKind::SolveStats => {
            let f = msgs::decode::<msgs::SolveStatsHeader, f32>(data).map_err(bad)?;
            bridge.on_stats(topic, &f.header, &f.items, clock.step(&f.header.step, log_time));
            Ok(())
        }
        FrameKind::Control => {
            let f = msgs::decode::<msgs::Control, u8>(data).map_err(bad)?;
            bridge.on_control(&f.header, &f.items, clock.control(&f.header, log_time));
            Ok(())
        }
        // No Foxglove view of the contact problem: the scene already shows the contacts.
        FrameKind::ProblemBodies | FrameKind::ProblemContacts => Ok(()),
    };
    r.map_err(|e| e.to_string())
}

/// What a first pass over a recording learns before its frames are converted.
struct Survey {
    /// The runs with a time step, laid end to end in the order their run starts were recorded
    /// (the recorder may write a run's first steps before its run start).
    timeline: Timeline,
    /// Whether there are contacts frames (a scene waits for its step's contacts only if so).
    contacts: bool,
}

/// Reads the control messages of `files` (and notes whether they hold contacts).
fn survey(files: &[PathBuf]) -> anyhow::Result<Survey> {
    let mut timeline = Timeline::default();
    let mut contacts = false;
    for file in files {
        let mut reader = recorder::RecordingReader::open(file)?;
        while let Some(m) = reader.next_message() {
            let m = m?;
            contacts |= m.channel.kind == Some(FrameKind::Contacts);
            if m.channel.kind != Some(FrameKind::Control) {
                continue;
            }
            let Ok(f) = msgs::decode::<msgs::Control, u8>(&m.data) else { continue };
            if f.header.kind() != Some(ControlKind::RunStart) {
                continue;
            }
            match f.details() {
                Ok(ControlDetails::RunStart(params)) => {
                    if !timeline.add_run(f.header.step.run_id, &params)
                        && timeline.dt_ns(f.header.step.run_id).is_none()
                    {
                        tracing::warn!(
                            run_id = f.header.step.run_id,
                            dt = params.dt,
                            "run start with an unusable time step"
                        );
                    }
                }
                Ok(_) => {}
                Err(e) => tracing::warn!(run_id = f.header.step.run_id, "run start without usable parameters: {e}"),
            }
        }
    }
    Ok(Survey { timeline, contacts })
}

/// `dc-foxglove viz IN OUT`: every frame of the recording, none throttled, at simulation time.
fn viz(input: &std::path::Path, output: &std::path::Path, style: SceneStyle) -> anyhow::Result<()> {
    let files = recorder::recording_files(input)?;
    let survey = survey(&files)?;
    let mut clock = FileClock::new(survey.timeline);
    let ctx = foxglove::Context::new();
    let mcap = ctx
        .mcap_writer()
        .create_new_buffered_file(output)
        .with_context(|| format!("cannot create {}", output.display()))?;
    let mut bridge = Bridge::new(&ctx, BridgeConfig::file(style))?;
    bridge.expect_contacts(survey.contacts);
    let (mut read, mut skipped) = (0u64, 0u64);
    for file in &files {
        let mut reader = recorder::RecordingReader::open(file)?;
        while let Some(m) = reader.next_message() {
            let m = m?;
            read += 1;
            let Some(kind) = m.channel.kind else { continue };
            if let Err(e) = give_recorded(&mut bridge, &mut clock, kind, &m.channel.topic, &m.data, m.log_time) {
                skipped += 1;
                if skipped <= 10 {
                    tracing::warn!(file = %file.display(), topic = %m.channel.topic, "skipped a message: {e}");
                }
            }
        }
    }
    bridge.finish();
    mcap.close().with_context(|| format!("cannot finish {}", output.display()))?;
    let written: u64 = bridge.counters.sent.values().sum();
    for (topic, n) in &bridge.counters.sent {
        println!("{topic}: {n}");
    }
    let (bodies_alone, contacts_alone) = bridge.unpaired();
    if bodies_alone + contacts_alone > 0 {
        println!("{bodies_alone} step(s) without contacts, {contacts_alone} contacts frame(s) without bodies");
    }
    println!(
        "times: {} frame(s) at simulation time ({} run(s) with a time step), {} at their recorded log time, {} node notice(s) at the latest time",
        clock.simulation,
        clock.timeline().runs(),
        clock.log_time,
        clock.latest
    );
    println!(
        "read {read} messages from {} file(s), wrote {written} to {} ({skipped} skipped)",
        files.len(),
        output.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(parse_address("127.0.0.1:8765").unwrap(), ("127.0.0.1".to_string(), 8765));
        assert_eq!(parse_address("[::1]:0").unwrap(), ("::1".to_string(), 0));
        assert!(parse_address("localhost").is_err());
        assert!(parse_address("h:99999").is_err());
    }

    #[test]
    fn default_topics_are_known_frame_types() {
        for t in DEFAULT_TOPICS {
            assert!(FrameKind::of_topic(t).is_some(), "{t}");
        }
    }
}
