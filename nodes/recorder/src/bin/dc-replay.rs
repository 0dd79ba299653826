//! `dc-replay`: publishes a recording's streams back onto the bus at the recorded pace (`--rate`
//! factor; `--rate 0`: as fast as the subscribers take them), optionally a selection of topics,
//! remapped, in a loop. Undecodable messages are skipped and counted.

use anyhow::Context;
use clap::Parser;
use msgs::{FrameHeader, FrameItem};
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
    /// Pace relative to the recording: 1 = as recorded, 2 = twice as fast, 0 = no pacing.
    #[arg(long, default_value_t = 1.0, value_parser = non_negative)]
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
}

fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("`{s}`: expected a rate >= 0")),
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

struct Typed<H: FrameHeader, T: FrameItem>(runtime::Publisher<H, T>);

impl<H: FrameHeader, T: FrameItem> ReplayedTopic for Typed<H, T> {
    fn publish(&mut self, data: &[u8]) -> anyhow::Result<bool> {
        // Decode first: the zenoh path would otherwise forward a bad payload untouched.
        if msgs::decode::<H, T>(data).is_err() {
            return Ok(false);
        }
        match self.0.publish_encoded(data) {
            Ok(()) => Ok(true),
            Err(runtime::Error::Codec { .. }) => Ok(false),
            Err(e) => Err(e.into()),
        }
    }
}

fn publisher(node: &runtime::Node, kind: FrameKind, topic: &str) -> anyhow::Result<Box<dyn ReplayedTopic>> {
    Ok(match kind {
        FrameKind::Bodies => Box::new(Typed(node.publisher_named::<msgs::StepHeader, msgs::Body>(topic)?)),
        FrameKind::Contacts => Box::new(Typed(node.publisher_named::<msgs::StepHeader, msgs::Contact>(topic)?)),
        FrameKind::Grid => Box::new(Typed(node.publisher_named::<msgs::GridHeader, f32>(topic)?)),
        FrameKind::SolveStats => Box::new(Typed(node.publisher_named::<msgs::SolveStatsHeader, f32>(topic)?)),
        FrameKind::Control => Box::new(Typed(node.publisher_named::<msgs::Control, u8>(topic)?)),
        FrameKind::ProblemBodies => {
            Box::new(Typed(node.publisher_named::<msgs::StepHeader, msgs::ProblemBody>(topic)?))
        }
        FrameKind::ProblemContacts => {
            Box::new(Typed(node.publisher_named::<msgs::ProblemHeader, msgs::ProblemContact>(topic)?))
        }
    })
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
    let node = runtime::Node::from_env("dc-replay")?;
    let mut pubs: HashMap<String, Box<dyn ReplayedTopic>> = HashMap::new();
    for (topic, kind) in &channels {
        if wanted(topic) {
            let out = remap.get(topic).map(String::as_str).unwrap_or(topic);
            pubs.insert(topic.clone(), publisher(&node, *kind, out).with_context(|| format!("publisher for `{out}`"))?);
            tracing::info!(topic, to = out, "replaying");
        }
    }
    if !node.ready()? {
        return Ok(());
    }

    let mut published = 0u64;
    let mut skipped = 0u64;
    let started = Instant::now();
    'outer: loop {
        for file in &files {
            let mut reader = RecordingReader::open(file)?;
            let mut clock: Option<(u64, Instant)> = None;
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
                                pubs.insert(c.topic.clone(), publisher(&node, kind, out)?);
                            }
                        }
                        continue;
                    }
                    _ => continue,
                };
                let Some(out) = pubs.get_mut(&m.channel.topic) else { continue };
                if args.rate > 0.0 {
                    let (t0, w0) = *clock.get_or_insert((m.log_time, Instant::now()));
                    let due = w0 + Duration::from_secs_f64(m.log_time.saturating_sub(t0) as f64 * 1e-9 / args.rate);
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
    }
    tracing::info!(published, skipped, seconds = format!("{:.2}", started.elapsed().as_secs_f64()), "replay done");
    println!("published {published}, skipped {skipped} undecodable");
    Ok(())
}
