//! Observers of a running graph (`dc topic echo | hz | bw`, `dc record -a`): a process that joins
//! a graph's topics from outside it, after the graph started, without the launcher.
//!
//! An observer must never slow the graph. Its subscribers live on a thread of their own that
//! only takes frames off the bus and hands them over a bounded queue; whatever the observer does
//! with them (print, encode, write to disk) happens elsewhere. When that work falls behind the
//! queue fills and frames are dropped and counted, unless the observer asked to be reliable
//! (then a full queue waits, and so, once the observer's bus queue is full too, does the graph).
//! Over zenoh the observer's subscribers are best effort (a ring that loses its oldest frame) for
//! the same reason.

use crate::config::{BusConfig, Result, ShutdownSignal, Transport, ZenohConfig};
use crate::Node;
use msgs::topics::FrameKind;
use msgs::{FrameHeader, FrameItem, HasStep, StepHeader};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Where the graph to observe is.
#[derive(Debug, Clone, Default)]
pub struct Target {
    /// The graph's bus namespace; `NS@host` for one host of a multi-host graph.
    pub namespace: String,
    /// Over zenoh, through this endpoint of the graph (a node's or its router's,
    /// `tcp/127.0.0.1:7447`); `None`: this host's iceoryx2 topics.
    pub zenoh: Option<String>,
}

impl Target {
    /// The bus configuration of an observer of this target.
    pub fn bus(&self, topics: &[String], reliable: bool) -> BusConfig {
        let (namespace, host) = match self.namespace.split_once('@') {
            Some((ns, host)) => (ns.to_string(), host.to_string()),
            None => (self.namespace.clone(), String::new()),
        };
        let mut bus = BusConfig { namespace, host, observe: true, queue_depth: 16, ..Default::default() };
        if let Some(endpoint) = &self.zenoh {
            bus.default_transport = Transport::Zenoh;
            bus.zenoh = ZenohConfig { connect: vec![endpoint.clone()], ..Default::default() };
            if !reliable {
                bus.best_effort = topics.iter().cloned().collect();
            }
        }
        bus
    }
}

/// How long a listing over zenoh waits for the graph's liveliness tokens.
const ZENOH_LIST_WAIT: Duration = Duration::from_secs(2);

/// The topics alive on this host's iceoryx2 bus, or over zenoh through `zenoh` (an endpoint of
/// the graph); every namespace, or one.
pub fn live_topics_at(zenoh: Option<&str>, namespace: Option<&str>) -> anyhow::Result<Vec<crate::iox::LiveTopic>> {
    match zenoh {
        Some(endpoint) => crate::live_topics_zenoh(endpoint, namespace, ZENOH_LIST_WAIT).map_err(anyhow::Error::msg),
        None => Ok(crate::iox::live_topics(namespace)?),
    }
}

/// Where [`live_topics_at`] looks, for messages: `on this host`, `over zenoh through E`.
pub fn place_text(zenoh: Option<&str>) -> String {
    match zenoh {
        Some(e) => format!("over zenoh through {e}"),
        None => "on this host".to_string(),
    }
}

/// The graph an observer of `topics` joins: `namespace`, or the only one alive; and the topics
/// to take there: `topics`, each alive there, or (none given) every topic alive there. An error
/// says what is alive instead: no graph, several graphs, a topic not alive or not a topic.
pub fn find_graph(
    namespace: Option<&str>,
    zenoh: Option<&str>,
    topics: &[String],
) -> anyhow::Result<(Target, Vec<String>)> {
    use anyhow::bail;
    let place = place_text(zenoh);
    let all = live_topics_at(zenoh, None)?;
    let namespace = match namespace {
        Some(ns) => ns.to_string(),
        None => {
            let mut names: Vec<&str> = all.iter().map(|t| t.namespace.as_str()).collect();
            names.dedup();
            match names.as_slice() {
                [] => bail!("no Deep Contact topics alive {place}: no graph is running there"),
                [one] => one.to_string(),
                many => bail!("several graphs are running {place}: say which with --namespace ({})", many.join(", ")),
            }
        }
    };
    let alive: Vec<String> = all.iter().filter(|t| t.namespace == namespace).map(|t| t.topic.clone()).collect();
    if alive.is_empty() {
        bail!("no topics alive in namespace `{namespace}` {place}: is its graph running?");
    }
    if let Some(topic) = topics.iter().find(|t| !alive.contains(t)) {
        let what = if msgs::topics::info(topic).is_some() { "is not alive" } else { "is not a Deep Contact topic" };
        bail!("topic `{topic}` {what} in namespace `{namespace}` (alive: {})", alive.join(", "));
    }
    let topics = if topics.is_empty() { alive } else { topics.to_vec() };
    Ok((Target { namespace, zenoh: zenoh.map(str::to_string) }, topics))
}

/// What an observer is asked to take.
#[derive(Debug, Clone)]
pub struct ObserveOptions {
    pub target: Target,
    pub topics: Vec<String>,
    /// Hand each frame over CBOR-encoded (echo, record); without it only its step, arrival time
    /// and size travel (hz, bw).
    pub encode: bool,
    /// Frames the hand-over queue holds.
    pub capacity: usize,
    /// A full queue waits instead of dropping.
    pub reliable: bool,
}

/// One frame taken off the bus.
#[derive(Debug, Clone)]
pub struct Observed {
    /// Index of its topic in [`ObserveOptions::topics`].
    pub topic: usize,
    /// When the observer took it.
    pub at: Instant,
    pub step: StepHeader,
    /// Header and items as they are in memory (what crossed shared memory), bytes.
    pub size: usize,
    /// The frame as CBOR (with [`ObserveOptions::encode`]).
    pub cbor: Option<Vec<u8>>,
}

/// What the observer thread hands over.
#[derive(Debug, Clone)]
pub enum Event {
    Frame(Observed),
    /// A payload of this topic (index) that did not decode: taken, counted, skipped.
    Undecodable {
        topic: usize,
        at: Instant,
    },
}

/// Per topic counts, shared with the observer thread.
#[derive(Debug, Default)]
pub struct TopicCounts {
    pub received: AtomicU64,
    /// Frames the hand-over queue had no room for.
    pub dropped: AtomicU64,
    pub undecodable: AtomicU64,
}

/// A running observer: its events, counts and thread.
pub struct Observer {
    pub events: Receiver<Event>,
    pub counts: Arc<Vec<TopicCounts>>,
    shutdown: ShutdownSignal,
    /// Set when the observed topics had writers and have none left (the graph ended).
    graph_gone: Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<anyhow::Result<()>>>,
}

impl Observer {
    /// Opens the topics (on the observer thread) and starts taking frames; an error opening any
    /// of them (the graph is not there, the topic does not exist) is returned here.
    pub fn start(options: ObserveOptions) -> anyhow::Result<Observer> {
        let shutdown = ShutdownSignal::default();
        let counts: Arc<Vec<TopicCounts>> = Arc::new(options.topics.iter().map(|_| TopicCounts::default()).collect());
        let (events_tx, events) = std::sync::mpsc::sync_channel(options.capacity.max(1));
        let (opened_tx, opened) = std::sync::mpsc::channel();
        let graph_gone = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let thread = {
            let (shutdown, counts, gone) = (shutdown.clone(), counts.clone(), graph_gone.clone());
            std::thread::Builder::new()
                .name("observer".into())
                .spawn(move || run(options, shutdown, counts, gone, events_tx, opened_tx))?
        };
        let mut observer = Observer { events, counts, shutdown, graph_gone, thread: Some(thread) };
        match opened.recv() {
            Ok(()) => Ok(observer),
            // The thread ended before opening everything: its error says why.
            Err(_) => Err(observer.join().err().unwrap_or_else(|| anyhow::anyhow!("the observer thread ended"))),
        }
    }

    /// Set by Ctrl-C / SIGTERM (or [`Observer::stop`]).
    pub fn is_stopped(&self) -> bool {
        self.shutdown.is_set()
    }

    /// The observed topics had writers and have none left: the graph ended (this host's
    /// iceoryx2 topics only; over zenoh an observer runs until stopped).
    pub fn graph_gone(&self) -> bool {
        self.graph_gone.load(Ordering::Relaxed)
    }

    pub fn stop(&self) {
        self.shutdown.set();
    }

    /// Stops the thread and returns its result.
    pub fn join(&mut self) -> anyhow::Result<()> {
        self.shutdown.set();
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| anyhow::anyhow!("the observer thread panicked"))?,
            None => Ok(()),
        }
    }

    pub fn dropped(&self) -> u64 {
        self.counts.iter().map(|c| c.dropped.load(Ordering::Relaxed)).sum()
    }
}

impl Drop for Observer {
    fn drop(&mut self) {
        self.shutdown.set();
    }
}

/// One topic's subscriber, whatever its frame type.
trait Tap {
    /// Takes up to `max` waiting frames; returns how many payloads it took (decoded or not).
    fn poll(&mut self, max: usize, now: Instant, out: &mut Vec<Event>) -> Result<usize>;
    /// Sleeps until a frame may be waiting (one topic only) or `timeout`.
    fn wait(&mut self, timeout: Duration) -> Result<Option<Event>>;
}

struct Typed<H: FrameHeader, T: FrameItem> {
    index: usize,
    sub: crate::Subscriber<H, T>,
    undecodable: u64,
    encode: bool,
}

impl<H: FrameHeader + HasStep, T: FrameItem> Typed<H, T> {
    fn event(&mut self, r: &crate::Received<H, T>, at: Instant) -> Result<Event> {
        let (header, items) = (r.header(), r.items());
        let cbor = if self.encode {
            let mut bytes = Vec::with_capacity(64 + std::mem::size_of_val(items));
            msgs::encode_into(header, items, &mut bytes)
                .map_err(|source| crate::Error::Codec { topic: self.sub.topic().to_string(), source })?;
            Some(bytes)
        } else {
            None
        };
        let size = std::mem::size_of::<H>() + std::mem::size_of_val(items);
        Ok(Event::Frame(Observed { topic: self.index, at, step: header.step_header(), size, cbor }))
    }

    /// An undecodable payload the subscriber counted since last asked, as an event.
    fn undecodable(&mut self, at: Instant, out: &mut Vec<Event>) -> usize {
        let now = self.sub.decode_errors();
        let new = (now - self.undecodable) as usize;
        self.undecodable = now;
        out.extend((0..new).map(|_| Event::Undecodable { topic: self.index, at }));
        new
    }
}

impl<H: FrameHeader + HasStep, T: FrameItem> Tap for Typed<H, T> {
    fn poll(&mut self, max: usize, now: Instant, out: &mut Vec<Event>) -> Result<usize> {
        let mut taken = 0;
        for _ in 0..max {
            let Some(r) = self.sub.try_recv()? else { break };
            // Each frame's own arrival, not the batch's: `dc topic hz` measures periods.
            out.push(self.event(&r, Instant::now())?);
            taken += 1;
        }
        Ok(taken + self.undecodable(now, out))
    }

    fn wait(&mut self, timeout: Duration) -> Result<Option<Event>> {
        match self.sub.recv_timeout(timeout)? {
            Some(r) => Ok(Some(self.event(&r, Instant::now())?)),
            None => Ok(None),
        }
    }
}

fn tap(node: &Node, index: usize, topic: &str, encode: bool) -> anyhow::Result<Box<dyn Tap>> {
    use anyhow::Context;
    let kind = FrameKind::of_topic(topic)
        .with_context(|| format!("unknown topic `{topic}` (known: {})", msgs::topics::names_list()))?;
    fn typed<H: FrameHeader + HasStep, T: FrameItem>(
        node: &Node,
        index: usize,
        topic: &str,
        encode: bool,
    ) -> Result<Box<dyn Tap>> {
        Ok(Box::new(Typed { index, sub: node.subscriber_named::<H, T>(topic)?, undecodable: 0, encode }))
    }
    Ok(msgs::with_frame_types!(kind, typed(node, index, topic, encode))?)
}

/// Watches the writers of the observed iceoryx2 topics: once some were seen, none left for a
/// while means the graph ended.
struct WriterWatch {
    namespace: Option<String>,
    topics: Vec<String>,
    last_check: Instant,
    seen: bool,
    none_since: Option<Instant>,
}

/// How often the writers are counted, and how long none may be left before the graph counts as
/// gone (a restarted node comes back within it).
const WRITER_CHECK: Duration = Duration::from_millis(500);
const WRITERS_GONE_AFTER: Duration = Duration::from_secs(2);

impl WriterWatch {
    fn new(options: &ObserveOptions) -> WriterWatch {
        WriterWatch {
            // Over zenoh writers are not counted here.
            namespace: options.target.zenoh.is_none().then(|| options.target.namespace.clone()),
            topics: options.topics.clone(),
            last_check: Instant::now(),
            seen: false,
            none_since: None,
        }
    }

    fn all_gone(&mut self, node: &Node) -> bool {
        let Some(ns) = &self.namespace else { return false };
        if self.last_check.elapsed() < WRITER_CHECK {
            return false;
        }
        self.last_check = Instant::now();
        // Through the observer's own iceoryx2 node: no node made and removed every check.
        let Ok(live) = node.iox().and_then(|iox| crate::iox::live_topics_on(iox, Some(ns))) else { return false };
        let writers: usize =
            live.iter().filter(|t| &t.namespace == ns && self.topics.contains(&t.topic)).map(|t| t.writers).sum();
        if writers > 0 {
            self.seen = true;
            self.none_since = None;
            return false;
        }
        let since = *self.none_since.get_or_insert_with(Instant::now);
        self.seen && since.elapsed() >= WRITERS_GONE_AFTER
    }
}

/// How long a many-topic observer naps when nothing was waiting (a single topic sleeps on its
/// event instead).
const IDLE_NAP: Duration = Duration::from_micros(500);

fn run(
    options: ObserveOptions,
    shutdown: ShutdownSignal,
    counts: Arc<Vec<TopicCounts>>,
    graph_gone: Arc<std::sync::atomic::AtomicBool>,
    events: SyncSender<Event>,
    opened: std::sync::mpsc::Sender<()>,
) -> anyhow::Result<()> {
    let bus = options.target.bus(&options.topics, options.reliable);
    let node = Node::new(format!("dc-observe-{}", std::process::id()), bus, false);
    let mut taps = options
        .topics
        .iter()
        .enumerate()
        .map(|(i, t)| tap(&node, i, t, options.encode))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if !node.ready()? {
        return Ok(());
    }
    let _ = opened.send(());
    let mut batch = Vec::new();
    let mut writers = WriterWatch::new(&options);
    let hand_over = |event: Event| -> bool {
        let topic = match &event {
            Event::Frame(o) => {
                counts[o.topic].received.fetch_add(1, Ordering::Relaxed);
                o.topic
            }
            Event::Undecodable { topic, .. } => {
                counts[*topic].undecodable.fetch_add(1, Ordering::Relaxed);
                *topic
            }
        };
        if options.reliable {
            return events.send(event).is_ok();
        }
        match events.try_send(event) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                counts[topic].dropped.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        }
    };
    while !shutdown.is_set() && !node.is_shutdown() {
        if writers.all_gone(&node) {
            tracing::debug!("the observed topics have no writers left: the graph ended");
            graph_gone.store(true, Ordering::Relaxed);
            shutdown.set();
            break;
        }
        if let [only] = taps.as_mut_slice() {
            batch.clear();
            batch.extend(only.wait(Duration::from_millis(50))?);
            // Whatever else is waiting, and the undecodable payloads counted meanwhile.
            only.poll(256, Instant::now(), &mut batch)?;
            for e in batch.drain(..) {
                if !hand_over(e) {
                    return Ok(());
                }
            }
            continue;
        }
        let now = Instant::now();
        let mut taken = 0;
        for tap in taps.iter_mut() {
            batch.clear();
            taken += tap.poll(64, now, &mut batch)?;
            for e in batch.drain(..) {
                if !hand_over(e) {
                    return Ok(());
                }
            }
        }
        if taken == 0 {
            std::thread::sleep(IDLE_NAP);
        }
    }
    Ok(())
}
