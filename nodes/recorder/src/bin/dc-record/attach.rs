//! `dc record -a | TOPICS...`: a recorder attached to a graph that is already running, from
//! another terminal, as `ros2 bag record` is. It observes the graph (`runtime::observe`): its
//! subscribers only take frames off the bus, and a bounded queue hands them to the writer here,
//! so a slow disk drops frames (counted) instead of stalling the simulator, unless `--reliable`.
//! It stops on Ctrl-C, after `--duration`, or when the graph ends, with the file finished.

use anyhow::Result;
use msgs::ControlKind;
use recorder::{FrameKind, RecordingWriter};
use runtime::observe::{Event, ObserveOptions, Observer};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

/// What to attach to and where to write.
pub struct Attach<'a> {
    /// Every topic alive in the namespace (`-a`), or these.
    pub topics: &'a [String],
    pub namespace: Option<&'a str>,
    pub zenoh: Option<&'a str>,
    pub out: Option<&'a Path>,
    pub overwrite: bool,
    pub dir: &'a Path,
    pub reliable: bool,
    pub duration: Option<Duration>,
    pub flush_every: Duration,
    pub metadata: BTreeMap<String, String>,
}

/// Frames the hand-over queue holds before the recorder drops (a 10,000-body frame is 480 KB).
const QUEUE_FRAMES: usize = 1024;

/// Records until Ctrl-C, `--duration` or the graph's end; returns the file written.
pub fn record(a: &Attach) -> Result<std::path::PathBuf> {
    let (target, topics) = runtime::observe::find_graph(a.namespace, a.zenoh, a.topics)?;
    let namespace = target.namespace.clone();
    // A default name is taken as the graph recorder takes its own: a second recorder started in
    // the same second gets `-2`, never an error.
    let mut writer = match a.out {
        Some(p) if a.overwrite => RecordingWriter::create(p)?,
        Some(p) => RecordingWriter::create_new(p)?,
        None => {
            let stem = format!("attached-{namespace}-{}", recorder::utc_stamp(std::time::SystemTime::now()));
            RecordingWriter::create_numbered(a.dir, &stem)?
        }
    };
    let path = writer.path().to_path_buf();
    let kinds: Vec<FrameKind> =
        topics.iter().map(|t| FrameKind::of_topic(t).expect("alive topics are known ones")).collect::<Vec<_>>();
    for (t, k) in topics.iter().zip(&kinds) {
        writer.add_channel(t, *k)?;
    }
    let mut meta = a.metadata.clone();
    meta.insert("namespace".into(), namespace.clone());
    meta.insert("attached".into(), "true".into());
    meta.insert("delivery".into(), if a.reliable { "reliable" } else { "best effort" }.into());
    writer.write_metadata("dc-record", meta)?;

    let mut observer = Observer::start(ObserveOptions {
        target,
        topics: topics.clone(),
        encode: true,
        capacity: QUEUE_FRAMES,
        reliable: a.reliable,
    })?;
    eprintln!("recording {} of namespace `{namespace}` to {} (Ctrl-C stops)", topics.join(", "), path.display());
    // Log times: the wall clock when the observer took each frame.
    let (clock_at, clock_ns) = (Instant::now(), recorder::now_ns());
    let started = Instant::now();
    let mut last_flush = Instant::now();
    let (mut written, mut undecodable, mut bytes) = (0u64, 0u64, 0u64);
    loop {
        if a.duration.is_some_and(|d| started.elapsed() >= d) {
            observer.stop();
        }
        let event = match observer.events.recv_timeout(Duration::from_millis(100)) {
            Ok(e) => e,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                if last_flush.elapsed() >= a.flush_every {
                    writer.flush()?;
                    last_flush = Instant::now();
                }
                continue;
            }
            // The observer stopped and everything it took was handed out.
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
        };
        let o = match event {
            Event::Frame(o) => o,
            Event::Undecodable { .. } => {
                undecodable += 1;
                continue;
            }
        };
        let data = o.cbor.as_deref().unwrap_or_default();
        let log_time = clock_ns + o.at.saturating_duration_since(clock_at).as_nanos() as u64;
        writer.write(&topics[o.topic], kinds[o.topic], log_time, log_time, data)?;
        written += 1;
        bytes += data.len() as u64;
        let control = if kinds[o.topic] == FrameKind::Control {
            super::notes::note_control(&mut writer, data, o.step)?
        } else {
            None
        };
        // A simulation's or run's end is a flush point, as in a graph's recorder.
        let ended = matches!(control, Some(ControlKind::SimulationEnd | ControlKind::RunEnd));
        if ended || last_flush.elapsed() >= a.flush_every {
            writer.flush()?;
            last_flush = Instant::now();
        }
    }
    observer.join()?;
    let n = writer.finish()?;
    let dropped = observer.dropped();
    if observer.graph_gone() {
        eprintln!("the graph ended (no writer left on the recorded topics)");
    }
    println!("recorded {n} messages to {}", path.display());
    println!(
        "received {}, undecodable {undecodable}, dropped {dropped}, {:.1} MiB",
        written + dropped,
        bytes as f64 / (1 << 20) as f64
    );
    if dropped > 0 {
        eprintln!("{dropped} frames were dropped: the disk fell behind the graph (--reliable waits instead, holding the graph back)");
    }
    Ok(path)
}
