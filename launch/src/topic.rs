//! `dc topic list | echo | hz | bw`: a running graph seen from another terminal. The observers
//! join the graph's topics from outside (see `runtime::observe`): best effort, so a slow
//! terminal never holds the simulator back; what they drop is counted and said.

use anyhow::{bail, Result};
use msgs::topics::FrameKind;
use runtime::observe::{Event, ObserveOptions, Observer};
use runtime::LiveTopic;
use serde::Serialize;
use serde_json::Value;
use std::io::Write;
use std::time::{Duration, Instant};

/// Where to look: `--namespace`, `--zenoh`.
#[derive(clap::Args, Debug, Clone)]
pub struct Where {
    /// The graph's bus namespace (`NS@host` for one host of a multi-host graph); default: the
    /// only one alive.
    #[arg(long)]
    pub namespace: Option<String>,
    /// Look over zenoh through this endpoint of the graph (a node's listening endpoint or the
    /// graph's router, as `dc launch --dry-run` prints them: `tcp/127.0.0.1:7447`) instead of
    /// this host's shared memory.
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh: Option<String>,
}

/// The topics alive where `place` says, every namespace or one.
fn live(place: &Where, namespace: Option<&str>) -> Result<Vec<LiveTopic>> {
    runtime::observe::live_topics_at(place.zenoh.as_deref(), namespace)
}

fn where_text(place: &Where) -> String {
    runtime::observe::place_text(place.zenoh.as_deref())
}

/// `dc topic list`: one line per live topic; none alive is an error (exit 1) saying where it
/// looked, so a script can tell a graph that is not running from one without topics.
pub fn list(place: &Where) -> Result<()> {
    let topics = live(place, place.namespace.as_deref())?;
    if topics.is_empty() {
        match &place.namespace {
            Some(ns) => bail!(
                "no topics alive in namespace `{ns}` {}: is its graph running? (`dc topic list` shows every namespace)",
                where_text(place)
            ),
            None => bail!("no Deep Contact topics alive {}: no graph is running there", where_text(place)),
        }
    }
    let width = |f: fn(&LiveTopic) -> usize, title: &str| topics.iter().map(f).max().unwrap_or(0).max(title.len());
    let (wn, wt) = (width(|t| t.namespace.len(), "namespace"), width(|t| t.topic.len(), "topic"));
    runtime::print_line(&format!(
        "{:wn$}  {:wt$}  {:15}  {:>7}  {:>7}  delivery",
        "namespace", "topic", "kind", "writers", "readers"
    ))?;
    for t in &topics {
        let kind = msgs::topics::info(&t.topic).map(|i| format!("{:?}", i.kind)).unwrap_or_default();
        let delivery = if t.best_effort { "best effort" } else { "reliable" };
        runtime::print_line(&format!(
            "{:wn$}  {:wt$}  {kind:15}  {:>7}  {:>7}  {delivery}",
            t.namespace, t.topic, t.writers, t.readers
        ))?;
    }
    Ok(())
}

/// Options of `dc topic info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    pub topic: String,
    #[command(flatten)]
    pub place: Where,
}

/// `dc topic info`: what a topic carries (its frame's header and item types with their fields,
/// who publishes it) and, where it is alive, its writers, readers and delivery per namespace.
/// A name that is no topic of the table is an error listing the topics.
pub fn info(args: &InfoArgs) -> Result<()> {
    let Some(row) = msgs::topics::info(&args.topic) else {
        bail!("`{}` is not a Deep Contact topic (topics: {})", args.topic, msgs::topics::names_list());
    };
    let (header_type, item_type) = row.kind.parts();
    let (header_fields, item_fields) = fields_of(row.kind);
    let mut lines = vec![
        format!("topic:   {}", row.name),
        format!("about:   {}", row.about),
        format!("type:    {header_type} header, {item_type} items"),
        format!("header:  {}", header_fields.join(", ")),
    ];
    if !item_fields.is_empty() {
        lines.push(format!("items:   {}", item_fields.join(", ")));
    }
    let live: Vec<LiveTopic> =
        live(&args.place, args.place.namespace.as_deref())?.into_iter().filter(|t| t.topic == row.name).collect();
    if live.is_empty() {
        lines.push(format!("alive:   nowhere {}", where_text(&args.place)));
    }
    for t in &live {
        let delivery = if t.best_effort { "best effort" } else { "reliable" };
        lines.push(format!(
            "alive:   namespace `{}`: writers {}, readers {}, {delivery}",
            t.namespace, t.writers, t.readers
        ));
    }
    runtime::print_line(&lines.join("\n"))
}

/// The field names of a frame kind's header and items (empty for items that are plain numbers).
fn fields_of(kind: FrameKind) -> (Vec<String>, Vec<String>) {
    use msgs::*;
    fn names<T: Serialize + Default>() -> Vec<String> {
        match ciborium::Value::serialized(&T::default()) {
            Ok(ciborium::Value::Map(fields)) => fields.iter().map(|(k, _)| inline_cbor(k)).collect(),
            _ => Vec::new(),
        }
    }
    match kind {
        FrameKind::Bodies => (names::<StepHeader>(), names::<Body>()),
        FrameKind::Contacts => (names::<StepHeader>(), names::<Contact>()),
        FrameKind::ProblemBodies => (names::<StepHeader>(), names::<ProblemBody>()),
        FrameKind::ProblemContacts => (names::<ProblemHeader>(), names::<ProblemContact>()),
        FrameKind::Grid => (names::<GridHeader>(), Vec::new()),
        FrameKind::SolveStats => (names::<SolveStatsHeader>(), Vec::new()),
        FrameKind::Control => (names::<Control>(), Vec::new()),
    }
}

/// Options of `dc topic pub`.
#[derive(clap::Args, Debug)]
pub struct PubArgs {
    /// The topic: `control`, the one a person publishes to by hand.
    pub topic: String,
    /// What to say: `shutdown`, every node of the graph finishes cleanly (its simulators at the
    /// next step, its recorders with their files closed), as on Ctrl-C of its launcher.
    pub message: String,
    /// The graph's bus namespace (default: the only one alive on this host).
    #[arg(long)]
    pub namespace: Option<String>,
}

/// `dc topic pub control shutdown`: publishes one control frame into a running graph on this
/// host's shared memory.
pub fn publish(args: &PubArgs) -> Result<()> {
    if args.topic != msgs::topics::CONTROL.name {
        bail!("`dc topic pub` publishes on `control` only (the other topics are the nodes' own data)");
    }
    let kind = match args.message.as_str() {
        "shutdown" => msgs::ControlKind::Shutdown,
        other => bail!("control message `{other}`: the one a person sends is `shutdown`"),
    };
    let (target, _) = runtime::observe::find_graph(args.namespace.as_deref(), None, std::slice::from_ref(&args.topic))?;
    let (namespace, host) = match target.namespace.split_once('@') {
        Some((ns, host)) => (ns.to_string(), host.to_string()),
        None => (target.namespace.clone(), String::new()),
    };
    let bus = runtime::BusConfig { namespace, host, queue_depth: 16, ..Default::default() };
    let node = runtime::Node::new("dc-topic-pub", bus, false);
    let mut control = node.publisher(msgs::topics::CONTROL)?;
    node.ready()?;
    let frame = msgs::Control { step: msgs::StepHeader::default(), kind: kind as u32, count: 0 };
    control.publish(&frame, &[])?;
    // The frame lives in this process's shared memory: stay until the graph's readers took it.
    std::thread::sleep(Duration::from_millis(500));
    runtime::print_line(&format!("published `{}` on control of namespace `{}`", args.message, target.namespace))
}

/// Options of `dc topic bridge`.
#[derive(clap::Args, Debug)]
pub struct BridgeArgs {
    /// The topics to relay, comma-separated (default: every topic alive in the namespace).
    #[arg(value_delimiter = ',')]
    pub topics: Vec<String>,
    /// The graph's bus namespace (default: the only one alive on this host).
    #[arg(long)]
    pub namespace: Option<String>,
    /// The zenoh endpoint the relay listens on (port 0: a free one; the endpoint is printed).
    #[arg(long, default_value = "tcp/127.0.0.1:0")]
    pub listen: String,
    /// Stop after relaying this many frames.
    #[arg(long)]
    pub count: Option<u64>,
}

/// `dc topic bridge`: relays topics of a graph on this host's shared memory to zenoh, keys
/// `dc/<namespace>/<topic>`, so any zenoh client (Python, another machine) can tap a topic the
/// launch file keeps on iceoryx2, without editing it. Best effort like every observer: a slow
/// relay drops (counted) and never holds the graph back.
pub fn bridge(args: &BridgeArgs) -> Result<()> {
    use runtime::zenoh::Wait;
    let (target, topics) = runtime::observe::find_graph(args.namespace.as_deref(), None, &args.topics)?;
    let namespace = target.namespace.clone();
    let options = ObserveOptions { target, topics: topics.clone(), encode: true, capacity: 256, reliable: false };
    let mut observer = Observer::start(options)?;
    let (session, endpoint) = relay_session(&args.listen)?;
    let bus = runtime::BusConfig { namespace: namespace.clone(), ..Default::default() };
    let publishers = topics
        .iter()
        .map(|t| {
            session.declare_publisher(bus.key(t)).wait().map_err(|e| anyhow::anyhow!("zenoh publisher for `{t}`: {e}"))
        })
        .collect::<Result<Vec<_>>>()?;
    eprintln!(
        "relaying {} of namespace `{namespace}` to zenoh at {endpoint} (keys {}); Ctrl-C stops",
        topics.join(", "),
        bus.key("<topic>")
    );
    let mut relayed = vec![0u64; topics.len()];
    while args.count.is_none_or(|n| relayed.iter().sum::<u64>() < n) {
        let Some(event) = next_event(&observer) else { break };
        if let Some(Event::Frame(o)) = event {
            if let Some(cbor) = o.cbor {
                publishers[o.topic].put(cbor).wait().map_err(|e| anyhow::anyhow!("zenoh put: {e}"))?;
                relayed[o.topic] += 1;
            }
        }
    }
    observer.join()?;
    for (i, topic) in topics.iter().enumerate() {
        tally(&observer, i, topic, relayed[i]);
    }
    Ok(())
}

/// The relay's zenoh session listening on `listen`; port 0 takes a port free now, and another
/// should a process take it before zenoh binds it. Returns the endpoint it listens on.
fn relay_session(listen: &str) -> Result<(runtime::zenoh::Session, String)> {
    let open = |endpoint: &str| {
        let config = runtime::ZenohConfig { listen: vec![endpoint.to_string()], ..Default::default() };
        runtime::open_zenoh_session(&config).map_err(|e| anyhow::anyhow!("zenoh on {endpoint}: {e}"))
    };
    let Some(address) = listen.strip_prefix("tcp/").and_then(|a| a.strip_suffix(":0")) else {
        return Ok((open(listen)?, listen.to_string()));
    };
    let mut tries = 0;
    loop {
        let endpoint = format!("tcp/{address}:{}", launch::plan::free_port(address));
        match open(&endpoint) {
            Ok(session) => return Ok((session, endpoint)),
            Err(e) if tries >= 4 => return Err(e),
            Err(_) => tries += 1,
        }
    }
}

fn observe(place: &Where, topic: &str, encode: bool) -> Result<Observer> {
    let options = ObserveOptions {
        target: runtime::observe::find_graph(place.namespace.as_deref(), place.zenoh.as_deref(), &[topic.to_string()])?
            .0,
        topics: vec![topic.to_string()],
        encode,
        capacity: 256,
        reliable: false,
    };
    Observer::start(options)
}

/// The next event: `Some(None)` when none came for a while, `None` once the observer stopped
/// (Ctrl-C, the graph ended) and everything it took was handed out.
fn next_event(observer: &Observer) -> Option<Option<Event>> {
    use std::sync::mpsc::RecvTimeoutError;
    match observer.events.recv_timeout(Duration::from_millis(100)) {
        Ok(e) => Some(Some(e)),
        Err(RecvTimeoutError::Timeout) if !observer.is_stopped() => Some(None),
        Err(RecvTimeoutError::Timeout) => match observer.events.try_recv() {
            Ok(e) => Some(Some(e)),
            Err(_) => None,
        },
        Err(RecvTimeoutError::Disconnected) => None,
    }
}

/// Says on stderr how many frames were used (`used`: printed or counted; the observer may have
/// taken a few more before it stopped, which are not said), dropped (fell behind) and could not
/// be decoded.
fn tally(observer: &Observer, index: usize, topic: &str, used: u64) {
    let c = &observer.counts[index];
    let load = |a: &std::sync::atomic::AtomicU64| a.load(std::sync::atomic::Ordering::Relaxed);
    if observer.graph_gone() {
        eprintln!("{topic}: the graph ended (no writer left)");
    }
    eprintln!(
        "{topic}: {used} frames, {} dropped (this terminal fell behind), {} undecodable",
        load(&c.dropped),
        load(&c.undecodable)
    );
}

/// Options of `dc topic echo`.
#[derive(clap::Args, Debug)]
pub struct EchoArgs {
    pub topic: String,
    #[command(flatten)]
    pub place: Where,
    /// Stop after this many frames.
    #[arg(long)]
    pub count: Option<u64>,
    /// One JSON object per frame and line.
    #[arg(long)]
    pub json: bool,
    /// Print every item, not only their count and summary.
    #[arg(long)]
    pub items: bool,
}

/// `dc topic echo`: each frame decoded (header fields by name, items summarised or listed); an
/// undecodable frame is printed as such and counted.
pub fn echo(args: &EchoArgs) -> Result<()> {
    let kind = FrameKind::of_topic(&args.topic);
    let mut observer = observe(&args.place, &args.topic, true)?;
    let mut out = std::io::stdout().lock();
    let mut printed = 0u64;
    while args.count.is_none_or(|n| printed < n) {
        let Some(event) = next_event(&observer) else { break };
        let Some(event) = event else { continue };
        let text = match (&event, kind) {
            (Event::Frame(o), Some(kind)) => {
                let cbor = o.cbor.as_deref().unwrap_or_default();
                match decode(kind, cbor, args.items) {
                    Ok(frame) if args.json => frame.json(&args.topic),
                    Ok(frame) => frame.text(&args.topic),
                    Err(e) => undecodable_text(&args.topic, args.json, &e.to_string()),
                }
            }
            _ => undecodable_text(&args.topic, args.json, "the payload did not decode"),
        };
        printed += 1;
        if writeln!(out, "{text}").and_then(|_| out.flush()).is_err() {
            break; // `| head`: the reader is gone.
        }
    }
    observer.join()?;
    tally(&observer, 0, &args.topic, printed);
    Ok(())
}

fn undecodable_text(topic: &str, json: bool, why: &str) -> String {
    if json {
        serde_json::json!({ "topic": topic, "undecodable": why }).to_string()
    } else {
        format!("--- {topic}: undecodable frame: {why}")
    }
}

/// A frame decoded for people: its header as JSON, what its items are, and the items if asked.
struct Decoded {
    header: Value,
    /// The header's fields in declaration order, each on one line (JSON objects lose it).
    header_lines: Vec<String>,
    item_type: &'static str,
    count: usize,
    /// A line about the items (f32: min, max, mean; control: its details).
    summary: Option<Value>,
    /// With `--items`: each item as JSON, and as a line in field order.
    items: Vec<Value>,
    item_lines: Vec<String>,
}

impl Decoded {
    fn text(&self, topic: &str) -> String {
        let mut lines = vec![format!("--- {topic}")];
        lines.extend(self.header_lines.iter().cloned());
        lines.push(format!("items: {} x {}", self.count, self.item_type));
        if let Some(Value::Object(fields)) = &self.summary {
            lines.extend(fields.iter().map(|(k, v)| format!("  {k}: {}", inline(v))));
        }
        lines.extend(self.item_lines.iter().map(|item| format!("  - {item}")));
        lines.push(String::new());
        lines.join("\n")
    }

    fn json(&self, topic: &str) -> String {
        let mut v = serde_json::json!({
            "topic": topic,
            "header": self.header,
            "items": { "count": self.count, "type": self.item_type },
        });
        if let Some(summary) = &self.summary {
            v["items"]["summary"] = summary.clone();
        }
        if !self.items.is_empty() {
            v["items"]["values"] = Value::Array(self.items.clone());
        }
        v.to_string()
    }
}

/// `field: value` per field of `header`, in declaration order, values as [`inline_cbor`].
fn header_lines<H: Serialize>(header: &H) -> Vec<String> {
    match ciborium::Value::serialized(header) {
        Ok(ciborium::Value::Map(fields)) => {
            fields.iter().map(|(k, v)| format!("{}: {}", inline_cbor(k), inline_cbor(v))).collect()
        }
        Ok(other) => vec![inline_cbor(&other)],
        Err(e) => vec![format!("(header: {e})")],
    }
}

/// `value` on one line in field order (see [`inline_cbor`]).
fn inline_serialized<T: Serialize>(value: &T) -> String {
    match ciborium::Value::serialized(value) {
        Ok(v) => inline_cbor(&v),
        Err(e) => format!("({e})"),
    }
}

/// A CBOR value on one line, YAML-like, maps in their order.
fn inline_cbor(v: &ciborium::Value) -> String {
    use ciborium::Value as C;
    match v {
        C::Map(m) => format!(
            "{{{}}}",
            m.iter().map(|(k, v)| format!("{}: {}", inline_cbor(k), inline_cbor(v))).collect::<Vec<_>>().join(", ")
        ),
        C::Array(a) => format!("[{}]", a.iter().map(inline_cbor).collect::<Vec<_>>().join(", ")),
        C::Text(s) => s.clone(),
        C::Integer(i) => i128::from(*i).to_string(),
        C::Float(f) => (*f as f32).to_string(),
        C::Bool(b) => b.to_string(),
        C::Null => "null".to_string(),
        C::Bytes(b) => format!("<{} bytes>", b.len()),
        other => format!("{other:?}"),
    }
}

/// A value on one line, YAML-like: `{run_id: 3, step: 7}`, `[1, 2, 3]`, strings bare.
fn inline(v: &Value) -> String {
    match v {
        Value::Object(m) => {
            format!("{{{}}}", m.iter().map(|(k, v)| format!("{k}: {}", inline(v))).collect::<Vec<_>>().join(", "))
        }
        Value::Array(a) => format!("[{}]", a.iter().map(inline).collect::<Vec<_>>().join(", ")),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Decodes a CBOR frame of `kind` with the decoders the nodes use.
fn decode(kind: FrameKind, cbor: &[u8], items: bool) -> Result<Decoded> {
    use msgs::*;
    let (_, item_type) = kind.parts();
    Ok(match kind {
        FrameKind::Bodies => structs::<StepHeader, Body>(cbor, item_type, items)?,
        FrameKind::Contacts => structs::<StepHeader, Contact>(cbor, item_type, items)?,
        FrameKind::ProblemBodies => structs::<StepHeader, ProblemBody>(cbor, item_type, items)?,
        FrameKind::ProblemContacts => structs::<ProblemHeader, ProblemContact>(cbor, item_type, items)?,
        FrameKind::Grid => numbers::<GridHeader>(cbor, item_type, items)?,
        FrameKind::SolveStats => numbers::<SolveStatsHeader>(cbor, item_type, items)?,
        FrameKind::Control => {
            let frame = decode::<Control, u8>(cbor)?;
            let details = match frame.details() {
                Ok(d) => serde_json::to_value(d)?,
                Err(e) => Value::String(format!("undecodable details: {e}")),
            };
            let mut header = serde_json::to_value(frame.header)?;
            if let (Value::Object(m), Some(k)) = (&mut header, frame.header.kind()) {
                m.insert("kind".into(), Value::String(format!("{k:?}")));
            }
            let mut lines = header_lines(&frame.header);
            if let Some(k) = frame.header.kind() {
                lines.push(format!("kind name: {k:?}"));
            }
            Decoded {
                header,
                header_lines: lines,
                item_type: "details (CBOR bytes)",
                count: frame.items.len(),
                summary: Some(serde_json::json!({ "details": details })),
                items: Vec::new(),
                item_lines: Vec::new(),
            }
        }
    })
}

fn structs<H: msgs::FrameHeader, T: msgs::FrameItem + Serialize>(
    cbor: &[u8],
    item_type: &'static str,
    items: bool,
) -> Result<Decoded> {
    let frame = msgs::decode::<H, T>(cbor)?;
    let values =
        if items { frame.items.iter().map(serde_json::to_value).collect::<Result<_, _>>()? } else { Vec::new() };
    let item_lines = if items { frame.items.iter().map(inline_serialized).collect() } else { Vec::new() };
    Ok(Decoded {
        item_lines,
        header: serde_json::to_value(frame.header)?,
        header_lines: header_lines(&frame.header),
        item_type,
        count: frame.items.len(),
        summary: None,
        items: values,
    })
}

fn numbers<H: msgs::FrameHeader>(cbor: &[u8], item_type: &'static str, items: bool) -> Result<Decoded> {
    let frame = msgs::decode::<H, f32>(cbor)?;
    let v = &frame.items;
    let summary = (!v.is_empty()).then(|| {
        let (min, max) = v.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &x| (lo.min(x), hi.max(x)));
        let mean = v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64;
        serde_json::json!({ "min": min, "max": max, "mean": mean, "first": v[0], "last": v[v.len() - 1] })
    });
    Ok(Decoded {
        header: serde_json::to_value(frame.header)?,
        header_lines: header_lines(&frame.header),
        item_type,
        count: v.len(),
        summary,
        item_lines: if items { v.iter().map(f32::to_string).collect() } else { Vec::new() },
        items: if items { v.iter().map(|&x| Value::from(x)).collect() } else { Vec::new() },
    })
}

/// Options of `dc topic hz` and `dc topic bw`.
#[derive(clap::Args, Debug)]
pub struct RateArgs {
    pub topic: String,
    #[command(flatten)]
    pub place: Where,
    /// Frames the statistics are taken over (the latest ones).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(2..))]
    pub window: u64,
    /// Stop after this many frames (the last line then covers them).
    #[arg(long)]
    pub count: Option<u64>,
}

/// The latest frames' arrival times and sizes.
#[derive(Debug, Default)]
pub struct Window {
    capacity: usize,
    frames: std::collections::VecDeque<(Instant, usize)>,
}

/// Rate and bandwidth of a [`Window`].
#[derive(Debug, Clone, PartialEq)]
pub struct WindowStats {
    pub frames: usize,
    /// Mean, min, max and standard deviation of the periods between frames, seconds.
    pub period_mean: f64,
    pub period_min: f64,
    pub period_max: f64,
    pub period_std: f64,
    /// Bytes per second over the window, and the mean, min and max frame size.
    pub bytes_per_s: f64,
    pub size_mean: f64,
    pub size_min: usize,
    pub size_max: usize,
}

impl Window {
    pub fn new(capacity: usize) -> Window {
        Window { capacity: capacity.max(2), frames: Default::default() }
    }

    pub fn push(&mut self, at: Instant, size: usize) {
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back((at, size));
    }

    /// `None` until two frames were seen.
    pub fn stats(&self) -> Option<WindowStats> {
        let (first, last) = (self.frames.front()?.0, self.frames.back()?.0);
        if self.frames.len() < 2 {
            return None;
        }
        let periods: Vec<f64> =
            self.frames.iter().zip(self.frames.iter().skip(1)).map(|(a, b)| (b.0 - a.0).as_secs_f64()).collect();
        let n = periods.len() as f64;
        let mean = periods.iter().sum::<f64>() / n;
        let var = periods.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / n;
        let sizes = self.frames.iter().map(|f| f.1);
        let span = (last - first).as_secs_f64();
        // Bytes that arrived after the first frame, over the time they took.
        let bytes_after_first: usize = self.frames.iter().skip(1).map(|f| f.1).sum();
        Some(WindowStats {
            frames: self.frames.len(),
            period_mean: mean,
            period_min: periods.iter().cloned().fold(f64::INFINITY, f64::min),
            period_max: periods.iter().cloned().fold(0.0, f64::max),
            period_std: var.sqrt(),
            bytes_per_s: if span > 0.0 { bytes_after_first as f64 / span } else { 0.0 },
            size_mean: sizes.clone().sum::<usize>() as f64 / self.frames.len() as f64,
            size_min: sizes.clone().min().unwrap_or(0),
            size_max: sizes.max().unwrap_or(0),
        })
    }
}

/// Which figure `rate` prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Figure {
    Hz,
    Bw,
}

fn bytes_text(b: f64) -> String {
    match b {
        b if b >= 1e6 => format!("{:.2} MB", b / 1e6),
        b if b >= 1e3 => format!("{:.2} KB", b / 1e3),
        b => format!("{b:.0} B"),
    }
}

pub fn stats_line(figure: Figure, s: &WindowStats) -> String {
    match figure {
        Figure::Hz => format!(
            "average rate: {:.3} Hz  min: {:.6}s  max: {:.6}s  std dev: {:.6}s  window: {}",
            if s.period_mean > 0.0 { 1.0 / s.period_mean } else { 0.0 },
            s.period_min,
            s.period_max,
            s.period_std,
            s.frames
        ),
        Figure::Bw => format!(
            "average: {}/s  mean: {}  min: {}  max: {}  window: {}",
            bytes_text(s.bytes_per_s),
            bytes_text(s.size_mean),
            bytes_text(s.size_min as f64),
            bytes_text(s.size_max as f64),
            s.frames
        ),
    }
}

/// `dc topic hz | bw`: every second, the rate (period mean, min, max, std) or bandwidth over the
/// latest `--window` frames, as their ROS 2 namesakes print them.
pub fn rate(args: &RateArgs, figure: Figure) -> Result<()> {
    let mut observer = observe(&args.place, &args.topic, false)?;
    let mut window = Window::new(args.window as usize);
    let (mut seen, mut last_print) = (0u64, Instant::now());
    let mut printed_since = false;
    while args.count.is_none_or(|n| seen < n) {
        let Some(event) = next_event(&observer) else { break };
        if let Some(Event::Frame(o)) = event {
            window.push(o.at, o.size);
            seen += 1;
            printed_since = false;
        }
        if last_print.elapsed() >= Duration::from_secs(1) {
            last_print = Instant::now();
            match window.stats() {
                Some(s) if !printed_since => runtime::print_line(&stats_line(figure, &s))?,
                _ => runtime::print_line("no new frames")?,
            }
            printed_since = true;
        }
    }
    if !printed_since {
        if let Some(s) = window.stats() {
            runtime::print_line(&stats_line(figure, &s))?;
        }
    }
    observer.join()?;
    tally(&observer, 0, &args.topic, seen);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_statistics_are_those_of_the_latest_frames() {
        let t0 = Instant::now();
        let mut w = Window::new(3);
        assert!(w.stats().is_none());
        w.push(t0, 100);
        assert!(w.stats().is_none(), "one frame has no period");
        for (ms, size) in [(10, 100), (30, 300), (40, 200)] {
            w.push(t0 + Duration::from_millis(ms), size);
        }
        // The first frame left the window: periods 20 ms and 10 ms.
        let s = w.stats().unwrap();
        assert_eq!(s.frames, 3);
        assert!((s.period_mean - 0.015).abs() < 1e-9);
        assert!((s.period_min - 0.010).abs() < 1e-9 && (s.period_max - 0.020).abs() < 1e-9);
        assert!((s.period_std - 0.005).abs() < 1e-9);
        assert!((s.bytes_per_s - 500.0 / 0.030).abs() < 1e-6);
        assert_eq!((s.size_min, s.size_max), (100, 300));
        assert!(stats_line(Figure::Hz, &s).starts_with("average rate: 66.667 Hz"));
        assert!(stats_line(Figure::Bw, &s).starts_with("average: 16.67 KB/s"));
    }

    #[test]
    fn frames_decode_for_people_and_garbage_is_an_error() {
        let header = msgs::StepHeader { run_id: 7, simulation: 2, step: 5 };
        let body = msgs::Body { id: 3, mass: 1.5, ..Default::default() };
        let cbor = msgs::encode(&msgs::Frame::new(header, vec![body; 4])).unwrap();
        let d = decode(FrameKind::Bodies, &cbor, true).unwrap();
        let text = d.text("bodies");
        assert!(text.contains("run_id: 7") && text.contains("step: 5"), "{text}");
        assert!(text.contains("items: 4 x dc::Body"), "{text}");
        assert_eq!(text.matches("  - {id: 3, shape: 0").count(), 4, "{text}");
        let json: Value = serde_json::from_str(&d.json("bodies")).unwrap();
        assert_eq!(json["header"]["simulation"], 2);
        assert_eq!(json["items"]["count"], 4);
        let stats = msgs::SolveStatsHeader { sweeps: 12, ..Default::default() };
        let cbor = msgs::encode(&msgs::Frame::new(stats, vec![0.5f32, 0.25, 0.125])).unwrap();
        let text = decode(FrameKind::SolveStats, &cbor, false).unwrap().text("stats/solve");
        assert!(text.contains("sweeps: 12") && text.contains("max: 0.5") && text.contains("last: 0.125"), "{text}");
        assert!(decode(FrameKind::Bodies, b"\xff\x00garbage", false).is_err());
    }
}
