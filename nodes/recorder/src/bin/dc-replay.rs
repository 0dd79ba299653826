//! `dc-replay`: publishes a recording's streams back onto the bus at the recorded pace (`--rate`
//! factor; `--rate 0`: as fast as the subscribers take them), optionally a selection of topics,
//! remapped, in a loop. Undecodable messages are skipped and counted.

use anyhow::Context;
use clap::Parser;
use msgs::{FrameHeader, FrameItem, HasStep};
use recorder::read::{Item, RecordingReader};
use recorder::FrameKind;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Parser, Debug)]
#[command(about = "Publish a recording back onto the bus")]
struct Args {
    /// The recording (.mcap), or a folder of recordings played in name order.
    #[arg(long, alias = "file")]
    input: PathBuf,
    /// Pace relative to the recording: 1 = as recorded, 2 = twice as fast, 0 = no pacing;
    /// otherwise from 0.001 to 1000000.
    #[arg(long, default_value_t = 1.0, value_parser = rate)]
    rate: f64,
    /// Recorded topics to publish, comma separated (default: all).
    #[arg(long, value_delimiter = ',')]
    topics: Vec<String>,
    /// Publish recorded topic A as topic B (`A=B`); repeatable.
    #[arg(long, value_parser = parse_remap)]
    remap: Vec<(String, String)>,
    /// Start again at the end, until stopped.
    #[arg(long = "loop")]
    repeat: bool,
    /// Started from a terminal (`dc play`): the bus namespace to publish in, so that a graph
    /// launched with `--namespace NS` (Foxglove, a trainer) reads it. A launched node takes
    /// the graph's.
    #[arg(long, value_parser = namespace)]
    namespace: Option<String>,
    /// Publish into a namespace a running graph uses (refused without it: the graph's metrics
    /// and recorder would take the recording's runs for their own). Every frame's run id is
    /// then marked as replayed (`msgs::REPLAYED_RUN`), which the metrics node leaves out of its
    /// report and the recorder keeps as a run of its own.
    #[arg(long)]
    into_live: bool,
}

fn namespace(s: &str) -> Result<String, String> {
    runtime::check_namespace(s).map(|()| s.to_string())
}

/// Slowest pace: a thousand times slower than recorded (a 100 Hz stream at one frame each 10 s);
/// slower rates turn a recording's milliseconds into hours (and overflow a wait at 1e-300).
const MIN_RATE: f64 = 1e-3;
/// Fastest pace: a recorded second in a microsecond; beyond it pacing means nothing (`--rate 0`).
const MAX_RATE: f64 = 1e6;
/// Longest recorded gap between two messages that the replay reproduces (at `--rate 1`). Nodes
/// publish every step (milliseconds apart); a longer silence is the recorder idling between runs
/// or a clock step (a log time 10^18 ns ahead would wait 31 years), not pace worth waiting for.
const MAX_GAP: Duration = Duration::from_secs(5);
/// [`MAX_GAP`] in ns, the unit of log times.
const MAX_GAP_NS: u64 = MAX_GAP.as_nanos() as u64;

/// A `--rate`: 0 (no pacing), or from [`MIN_RATE`] to [`MAX_RATE`].
fn rate(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v == 0.0 || (MIN_RATE..=MAX_RATE).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: expected 0 (no pacing) or a rate from {MIN_RATE} to {MAX_RATE}")),
    }
}

/// When each message is due, relative to the first, at a rate: the recorded gaps between
/// messages, each clamped to [`MAX_GAP`], divided by the rate. A log time earlier than one before
/// it is due at once (as before: no gap).
#[derive(Debug, Clone, Copy)]
struct Pacer {
    rate: f64,
    /// The latest log time seen, ns.
    last: Option<u64>,
    /// Recorded time since the first message, gaps clamped, ns.
    elapsed_ns: u64,
}

impl Pacer {
    fn new(rate: f64) -> Pacer {
        Pacer { rate, last: None, elapsed_ns: 0 }
    }

    /// The wall-clock offset from the first message at which the message logged at `log_time`
    /// is due, and whether its gap was clamped.
    fn due(&mut self, log_time: u64) -> (Duration, bool) {
        let gap = self.last.map_or(0, |last| log_time.saturating_sub(last));
        let clamped = gap > MAX_GAP_NS;
        self.elapsed_ns += gap.min(MAX_GAP_NS);
        self.last = Some(self.last.map_or(log_time, |last| last.max(log_time)));
        // Bounded: a file of 2^64 ns of clamped gaps at MIN_RATE is still a valid Duration.
        let offset = Duration::try_from_secs_f64(self.elapsed_ns as f64 * 1e-9 / self.rate).unwrap_or(Duration::MAX);
        (offset, clamped)
    }
}

fn parse_remap(s: &str) -> Result<(String, String), String> {
    match s.split_once('=') {
        Some((a, b)) if !a.is_empty() && !b.is_empty() => Ok((a.to_string(), b.to_string())),
        _ => Err(format!("`{s}`: expected FROM=TO")),
    }
}

/// A publisher of one topic that takes CBOR frames.
trait ReplayedTopic {
    /// Publishes an encoded frame; `Ok(false)` when the payload does not decode (skipped).
    fn publish(&mut self, data: &[u8]) -> anyhow::Result<bool>;
}

/// A topic's publisher; `mark`: every frame's run id marked as replayed (`--into-live`).
struct Typed<H: FrameHeader, T: FrameItem> {
    publisher: runtime::Publisher<H, T>,
    mark: bool,
}

impl<H: FrameHeader + HasStep, T: FrameItem> ReplayedTopic for Typed<H, T> {
    fn publish(&mut self, data: &[u8]) -> anyhow::Result<bool> {
        // Decode first: the zenoh path would otherwise forward a bad payload untouched.
        let Ok(mut frame) = msgs::decode::<H, T>(data) else { return Ok(false) };
        let sent = if self.mark {
            frame.header.step_header_mut().run_id |= msgs::REPLAYED_RUN;
            self.publisher.publish(&frame.header, &frame.items)
        } else {
            self.publisher.publish_encoded(data)
        };
        match sent {
            Ok(()) => Ok(true),
            Err(runtime::Error::Codec { .. }) => Ok(false),
            Err(e) => Err(e.into()),
        }
    }
}

fn publisher(node: &runtime::Node, kind: FrameKind, topic: &str, mark: bool) -> anyhow::Result<Box<dyn ReplayedTopic>> {
    fn typed<H: FrameHeader + HasStep, T: FrameItem>(
        node: &runtime::Node,
        topic: &str,
        mark: bool,
    ) -> anyhow::Result<Box<dyn ReplayedTopic>> {
        Ok(Box::new(Typed { publisher: node.publisher_named::<H, T>(topic)?, mark }))
    }
    msgs::with_frame_types!(kind, typed(node, topic, mark))
}

/// Takes `namespace` for the player, or (with `--into-live`) joins the graph that holds it; a
/// namespace a graph holds without `--into-live` is refused, naming the graph.
fn hold_namespace(namespace: &str, args: &Args) -> anyhow::Result<Option<runtime::lock::NamespaceLock>> {
    use runtime::lock::{LockError, NamespaceLock, PLAYER_HOST};
    if args.into_live {
        if NamespaceLock::holders(namespace).is_empty() {
            tracing::warn!(
                namespace,
                "--into-live: no graph runs in this namespace; publishing marked as replayed anyway"
            );
        }
        return Ok(None);
    }
    match NamespaceLock::acquire(namespace, PLAYER_HOST, &format!("dc play {}", args.input.display())) {
        Ok(lock) => Ok(Some(lock)),
        Err(LockError::InUse { host, holder, .. }) => anyhow::bail!(
            "namespace `{namespace}` is in use by {holder} (host `{host}`): its metrics and recorder would take the recording's runs for their own; give another --namespace, or pass --into-live to publish into it with every run marked as replayed"
        ),
        Err(e) => Err(e.into()),
    }
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> anyhow::Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    let files = recorder::recording_files(&args.input)?;
    let remap: HashMap<String, String> = args.remap.iter().cloned().collect();
    let wanted = |topic: &str| args.topics.is_empty() || args.topics.iter().any(|t| t == topic);

    // The channels of every file, so that every port exists before the graph starts.
    let mut channels: BTreeMap<String, FrameKind> = BTreeMap::new();
    for file in &files {
        let mut reader = RecordingReader::open(file)?;
        while let Some(item) = reader.next_item() {
            match item? {
                Item::Channel(c) => {
                    if let Some(kind) = c.kind {
                        channels.insert(c.topic.clone(), kind);
                    }
                }
                Item::Message(_) => break, // the recorder declares all channels up front
                _ => {}
            }
        }
    }
    let standalone = std::env::var_os("DC_BUS").is_none();
    let node = match &args.namespace {
        // From a terminal: this namespace. A launched node publishes in its graph's.
        Some(ns) if standalone => {
            let bus = runtime::BusConfig { namespace: ns.clone(), queue_depth: 16, ..Default::default() };
            runtime::Node::new("dc-replay", bus, false)
        }
        ns => {
            if let Some(ns) = ns {
                tracing::warn!(namespace = %ns, "--namespace ignored: a launched node publishes in its graph's namespace");
            }
            runtime::Node::from_env("dc-replay")?
        }
    };
    // From a terminal, `dc play` is a graph of its own: it holds its namespace, and refuses one
    // a running graph holds unless told to join it (then its runs are marked as replayed).
    let _namespace = if standalone { hold_namespace(&node.bus().namespace, &args)? } else { None };
    let mut pubs: HashMap<String, Box<dyn ReplayedTopic>> = HashMap::new();
    for (topic, kind) in &channels {
        if wanted(topic) {
            let out = remap.get(topic).map(String::as_str).unwrap_or(topic);
            pubs.insert(
                topic.clone(),
                publisher(&node, *kind, out, args.into_live).with_context(|| format!("publisher for `{out}`"))?,
            );
            tracing::info!(topic, to = out, "replaying");
        }
    }
    if args.repeat && pubs.is_empty() {
        anyhow::bail!(
            "--loop: nothing to publish in {}: no recorded channel matches --topics {:?}; refusing to loop over it",
            args.input.display(),
            args.topics
        );
    }
    if !node.ready()? {
        return Ok(());
    }

    let mut published = 0u64;
    let mut skipped = 0u64;
    let started = Instant::now();
    let mut said_clamped = false;
    'outer: loop {
        let published_before = published;
        for file in &files {
            let mut reader = RecordingReader::open(file)?;
            let mut clock: Option<(Pacer, Instant)> = None;
            while let Some(item) = reader.next_item() {
                if node.is_shutdown() {
                    break 'outer;
                }
                let m = match item? {
                    Item::Message(m) => m,
                    Item::Channel(c) => {
                        if let (Some(kind), false) = (c.kind, pubs.contains_key(&c.topic)) {
                            if wanted(&c.topic) {
                                let out = remap.get(&c.topic).map(String::as_str).unwrap_or(&c.topic);
                                tracing::warn!(topic = %c.topic, "channel declared late; its first frames may reach no subscriber");
                                pubs.insert(c.topic.clone(), publisher(&node, kind, out, args.into_live)?);
                            }
                        }
                        continue;
                    }
                    _ => continue,
                };
                let Some(out) = pubs.get_mut(&m.channel.topic) else { continue };
                if args.rate > 0.0 {
                    let (pacer, w0) = clock.get_or_insert_with(|| (Pacer::new(args.rate), Instant::now()));
                    let (offset, clamped) = pacer.due(m.log_time);
                    if clamped && !said_clamped {
                        said_clamped = true;
                        tracing::warn!(
                            file = %file.display(),
                            log_time = m.log_time,
                            "a gap between messages is longer than {MAX_GAP:?}: replayed as {MAX_GAP:?} (said once)"
                        );
                    }
                    let due = w0.checked_add(offset).unwrap_or_else(|| *w0 + MAX_GAP);
                    while let Some(wait) = due.checked_duration_since(Instant::now()) {
                        if node.is_shutdown() {
                            break 'outer;
                        }
                        std::thread::sleep(wait.min(Duration::from_millis(50)));
                    }
                }
                if out.publish(&m.data)? {
                    published += 1;
                } else {
                    skipped += 1;
                    tracing::warn!(topic = %m.channel.topic, skipped, "skipped an undecodable message");
                }
            }
        }
        if !args.repeat {
            break;
        }
        if published == published_before {
            // Another pass would publish nothing again: spinning through it forever helps no one.
            anyhow::bail!(
                "--loop: a whole pass over {} published nothing ({skipped} undecodable messages); refusing to loop over it",
                args.input.display()
            );
        }
    }
    tracing::info!(published, skipped, seconds = format!("{:.2}", started.elapsed().as_secs_f64()), "replay done");
    println!("published {published}, skipped {skipped} undecodable");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_outside_their_bounds_are_refused() {
        assert_eq!(rate("0"), Ok(0.0));
        assert_eq!(rate("0.5"), Ok(0.5));
        assert_eq!(rate("1e6"), Ok(1e6));
        for bad in ["1e-300", "0.0009", "1e7", "inf", "nan", "-1", "x"] {
            let e = rate(bad).unwrap_err();
            assert!(e.contains("from 0.001 to 1000000"), "{bad}: {e}");
        }
    }

    #[test]
    fn a_long_gap_is_clamped_and_the_pace_of_the_rest_is_kept() {
        let ms = 1_000_000u64;
        let mut p = Pacer::new(2.0);
        assert_eq!(p.due(1_000), (Duration::ZERO, false));
        assert_eq!(p.due(1_000 + 100 * ms), (Duration::from_millis(50), false));
        // 10^18 ns ahead: replayed as MAX_GAP, at the rate.
        let far = 1_000 + 100 * ms + 1_000_000_000_000_000_000;
        assert_eq!(p.due(far), (Duration::from_millis(50) + MAX_GAP / 2, true));
        assert_eq!(p.due(far + 100 * ms), (Duration::from_millis(100) + MAX_GAP / 2, false));
        // A log time going back is due at once; the pace resumes from the latest one.
        assert_eq!(p.due(5), (Duration::from_millis(100) + MAX_GAP / 2, false));
        assert_eq!(p.due(far + 200 * ms), (Duration::from_millis(150) + MAX_GAP / 2, false));
    }

    #[test]
    fn the_slowest_rate_over_the_longest_file_still_gives_a_duration() {
        let mut p = Pacer::new(MIN_RATE);
        p.due(0);
        for i in 1..100u64 {
            p.due(i * (u64::MAX / 100));
        }
        let expected = 100.0 * MAX_GAP.as_secs_f64() / MIN_RATE;
        assert!((p.due(u64::MAX).0.as_secs_f64() - expected).abs() < 1e-3, "{expected}");
    }
}
