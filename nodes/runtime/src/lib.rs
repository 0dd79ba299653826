//! What every Deep Contact node uses: a [`Node`] handle with its name, its bus configuration and a
//! shutdown signal, and typed [`Publisher`]s / [`Subscriber`]s whose transport (iceoryx2 shared
//! memory on one host, zenoh across hosts) is decided by the launch file, never by the node.
//!
//! A node binary is a few lines of wiring:
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! #[derive(clap::Parser)]
//! struct Args { #[arg(long, default_value_t = 10)] count: u32 }
//! let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) }; // only checked
//! let node = runtime::Node::from_env("dc-example")?;
//! let mut bodies = node.publisher(msgs::topics::BODIES)?;
//! if !node.ready()? { return Ok(()); } // sources start once every node's ports exist
//! bodies.publish(&msgs::StepHeader::default(), &[msgs::Body::default()])?;
//! # Ok(()) }
//! ```
//!
//! Environment (set by `dc launch`; all optional for a node started by hand):
//! - `DC_NODE_NAME`: the node's name in the graph;
//! - `DC_BUS`: JSON [`BusConfig`] (namespace, per-topic transport, zenoh endpoints);
//! - `DC_LAUNCHED=1`: the node reports readiness on stdout and waits for `start` on stdin;
//! - `DC_VALIDATE=1`: [`parse_args`] only checks the parameters (`None`: the node returns);
//! - `DC_DESCRIBE=1`: the node creates no port; [`Node::ready`] prints the topics it would publish
//!   and subscribe as JSON ([`Ports`]) and returns false (the node returns), so the launcher can
//!   route every topic.

mod config;
pub mod files;
mod iox;
pub mod lock;
pub mod observe;
mod pubsub;
pub mod shard;
mod zen;

pub use config::{
    check_namespace, BusConfig, Error, Ports, Result, ShutdownSignal, TlsConfig, Transport, ZenohConfig,
    MAX_NAMESPACE_LEN, PORTS_MARKER,
};
pub use iox::{check_node_name, live_topics, LiveTopic, MAX_NODES, MAX_PUBLISHERS, MAX_SUBSCRIBERS};
pub use pubsub::{Publisher, Received, Subscriber};
pub use zen::{live_topics_zenoh, open_router, HostSync, READERS, WRITERS};
/// The zenoh crate, for launchers holding sessions.
pub use zenoh;

use std::io::{BufRead, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

/// Line a launched node prints on stdout once its ports exist.
pub const READY_MARKER: &str = "\u{1e}dc-ready";
/// Line the launcher writes to a node's stdin once every node's ports exist.
pub const CONNECT_LINE: &str = "connect";
/// Line a launched node prints once its subscribers are attached to every publisher.
pub const CONNECTED_MARKER: &str = "\u{1e}dc-connected";
/// Line the launcher writes to a node's stdin once every node is connected.
pub const START_LINE: &str = "start";
/// Line a launched node prints when its work is done but its shared-memory publishers must stay
/// alive until the graph's readers have taken what it sent (see [`Node`]'s drop).
pub const DONE_MARKER: &str = "\u{1e}dc-done";

/// A node's handle on the graph.
pub struct Node {
    name: String,
    bus: BusConfig,
    launched: bool,
    shutdown: ShutdownSignal,
    iox: OnceLock<iox::IoxNode>,
    zenoh: OnceLock<zenoh::Session>,
    /// The node's iceoryx2 subscribers, attached to their publishers at start (see [`Node::ready`]).
    iox_subscribers: std::cell::RefCell<Vec<std::rc::Weak<dyn iox::Attach>>>,
    /// The node's iceoryx2 publishers, kept alive until the node is dropped (see `Drop`).
    iox_publishers: std::cell::RefCell<Vec<std::rc::Rc<dyn std::any::Any>>>,
    /// Under `DC_DESCRIBE=1`: the ports asked for so far (none is created).
    describe: Option<std::cell::RefCell<Ports>>,
    /// Past [`Node::ready`]: a subscriber made now attaches at once.
    running: std::cell::Cell<bool>,
    /// Publishes something over zenoh (see [`Node`]'s `Drop`).
    zenoh_publishing: std::cell::Cell<bool>,
}

/// A launched node outlives its work: iceoryx2 maps a publisher's data segment into a subscriber
/// lazily, at the first sample it takes, and the segment disappears with the publisher. A source
/// that sent a dozen frames and exited before a slower reader (the recorder) took the first one
/// lost them all. Over zenoh, a put returns once the frame is queued for each link, and a process
/// that exits at once can take the last frames to a slower link with it (a sink lost the last of
/// 60 while a tap got it). So the publishers stay alive until the launcher, which knows when the
/// graph's readers are done, closes our stdin (or a signal arrives).
impl Drop for Node {
    fn drop(&mut self) {
        // A node that never started sent nothing anybody could be reading.
        let publishes = !self.iox_publishers.borrow().is_empty() || self.zenoh_publishing.get();
        if !self.launched || !self.running.get() || !publishes || std::thread::panicking() {
            return;
        }
        if say(DONE_MARKER).is_err() {
            return;
        }
        let stdin_closed = self.shutdown.clone();
        // stdin is read on a thread so that a signal (the launcher's SIGTERM) also ends the wait.
        std::thread::spawn(move || {
            let mut line = String::new();
            while std::io::stdin().lock().read_line(&mut line).is_ok_and(|n| n > 0) {
                line.clear();
            }
            stdin_closed.set();
        });
        while !self.shutdown.is_set() {
            std::thread::sleep(Duration::from_millis(5));
        }
        self.iox_publishers.borrow_mut().clear();
    }
}

impl Node {
    /// Builds the node from its environment (see the crate docs); `default_name` is used when the
    /// node was not started by a launcher. Installs the Ctrl-C / SIGTERM handler.
    pub fn from_env(default_name: &str) -> Result<Node> {
        let name = std::env::var("DC_NODE_NAME").unwrap_or_else(|_| default_name.to_string());
        let bus = BusConfig::from_env()?;
        let launched = std::env::var("DC_LAUNCHED").is_ok_and(|v| v == "1");
        let mut node = Node::new(name, bus, launched);
        if describing() {
            node.describe = Some(Default::default());
        }
        Ok(node)
    }

    /// Builds a node with an explicit configuration (tests, in-process graphs).
    pub fn new(name: impl Into<String>, bus: BusConfig, launched: bool) -> Node {
        let shutdown = ShutdownSignal(Arc::new(AtomicBool::new(false)));
        // One handler per process; every node of the process sees the signal.
        static INSTALL: std::sync::Once = std::sync::Once::new();
        INSTALL.call_once(|| {
            match ctrlc::set_handler(|| config::SIGNALLED.store(true, Ordering::SeqCst)) {
                // The process (a launcher) handles signals itself.
                Ok(()) | Err(ctrlc::Error::MultipleHandlers) => {}
                Err(e) => tracing::warn!("could not install the Ctrl-C handler: {e}"),
            }
        });
        Node {
            name: name.into(),
            bus,
            launched,
            shutdown,
            iox: OnceLock::new(),
            zenoh: OnceLock::new(),
            iox_subscribers: Default::default(),
            iox_publishers: Default::default(),
            describe: None,
            running: Default::default(),
            zenoh_publishing: Default::default(),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn bus(&self) -> &BusConfig {
        &self.bus
    }

    /// True once Ctrl-C / SIGTERM arrived, a shutdown control message was seen, or
    /// [`Node::request_shutdown`] was called.
    pub fn is_shutdown(&self) -> bool {
        self.shutdown.is_set()
    }

    pub fn request_shutdown(&self) {
        self.shutdown.0.store(true, Ordering::SeqCst);
    }

    /// A clone of the shutdown signal, for threads of the node.
    pub fn shutdown_signal(&self) -> ShutdownSignal {
        self.shutdown.clone()
    }

    /// Applies a control message: a `Shutdown` sets the shutdown flag.
    pub fn observe_control(&self, control: &msgs::Control) {
        if control.kind() == Some(msgs::ControlKind::Shutdown) {
            tracing::info!(node = %self.name, "shutdown requested by control message");
            self.request_shutdown();
        }
    }

    /// A publisher on `topic`, over the transport the bus configuration names for it.
    pub fn publisher<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &self,
        topic: msgs::topics::Topic<H, T>,
    ) -> Result<Publisher<H, T>> {
        self.publisher_named(topic.name)
    }

    /// A publisher on a topic given by name (remapped topics); the frame types must match the
    /// topic's, which iceoryx2 checks through the type names.
    pub fn publisher_named<H: msgs::FrameHeader, T: msgs::FrameItem>(&self, topic: &str) -> Result<Publisher<H, T>> {
        if let Some(ports) = &self.describe {
            ports.borrow_mut().publishes.insert(topic.to_string());
            return Ok(Publisher::new(topic, None, None));
        }
        let transport = self.bus.transport(topic);
        let iox = if transport.uses_iceoryx2() {
            let publisher = std::rc::Rc::new(self.iox()?.publisher::<H, T>(&self.bus, topic)?);
            self.iox_publishers.borrow_mut().push(publisher.clone());
            Some(publisher)
        } else {
            None
        };
        let zen = if transport.uses_zenoh() {
            self.zenoh_publishing.set(true);
            Some(zen::ZenPublisher::new(
                self.zenoh(topic)?,
                &self.bus.key(topic),
                topic,
                self.bus.is_best_effort(topic),
                self.bus.zenoh_readers.get(topic).copied().unwrap_or(0),
            )?)
        } else {
            None
        };
        Ok(Publisher::new(topic, iox, zen))
    }

    /// Says that the node will subscribe to `topic` later than [`Node::ready`] (a port it opens
    /// only for part of its run), so that the launcher routes the topic to it. Only matters while
    /// describing; the port itself is made by [`Node::subscriber`] when needed.
    pub fn will_subscribe(&self, topic: &str) {
        if let Some(ports) = &self.describe {
            ports.borrow_mut().subscribes.insert(topic.to_string());
        }
    }

    /// A subscriber on `topic`.
    pub fn subscriber<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &self,
        topic: msgs::topics::Topic<H, T>,
    ) -> Result<Subscriber<H, T>> {
        self.subscriber_named(topic.name)
    }

    /// A subscriber on a topic given by name.
    pub fn subscriber_named<H: msgs::FrameHeader, T: msgs::FrameItem>(&self, topic: &str) -> Result<Subscriber<H, T>> {
        if let Some(ports) = &self.describe {
            ports.borrow_mut().subscribes.insert(topic.to_string());
            return Ok(Subscriber::new(topic, pubsub::SubInner::Detached, self.shutdown.clone()));
        }
        let transport = self.bus.transport(topic);
        let iox = if transport.uses_iceoryx2() {
            let sub = std::rc::Rc::new(self.iox()?.subscriber::<H, T>(&self.bus, topic)?);
            if self.running.get() {
                // Made mid-run (a simulator's grid subscriber): publishers deliver only to
                // subscribers attached to their connection, so attach before anything is asked.
                iox::Attach::attach(&*sub);
            } else {
                let weak: std::rc::Weak<dyn iox::Attach> = std::rc::Rc::downgrade(&sub) as _;
                self.iox_subscribers.borrow_mut().push(weak);
            }
            Some(sub)
        } else {
            None
        };
        let zen = if transport.uses_zenoh() {
            Some(zen::ZenSubscriber::new(
                self.zenoh(topic)?,
                &self.bus.key(topic),
                topic,
                self.bus.queue_depth.max(1) * 16,
                self.bus.is_best_effort(topic),
            )?)
        } else {
            None
        };
        let inner = match (iox, zen) {
            (Some(i), Some(z)) => pubsub::SubInner::Both(i, z),
            (Some(i), None) => pubsub::SubInner::Iox(i),
            (None, Some(z)) => pubsub::SubInner::Zenoh(z),
            (None, None) => pubsub::SubInner::Detached,
        };
        Ok(Subscriber::new(topic, inner, self.shutdown.clone()))
    }

    /// Tells the launcher that this node's ports exist and waits for the whole graph to be ready.
    /// Without a launcher it returns at once. Returns false when the graph was stopped meanwhile,
    /// and under `DC_DESCRIBE=1` once the ports are printed: the node then returns from `main`.
    ///
    /// Two phases, because an iceoryx2 publisher delivers (with back-pressure) only to subscribers
    /// that have attached to its connection, which a subscriber does when it polls: once every
    /// node's ports exist (`connect`), each node attaches its subscribers to every publisher and
    /// says so; only then do sources start (`start`). Without this a fast source overruns a
    /// subscriber that has not polled yet and iceoryx2 drops samples.
    pub fn ready(&self) -> Result<bool> {
        if let Some(ports) = &self.describe {
            let json = serde_json::to_string(&*ports.borrow()).expect("ports serialise");
            say(&format!("{PORTS_MARKER}{json}"))?;
            return Ok(false);
        }
        if !self.launched {
            self.attach_subscribers();
            self.running.set(true);
            return Ok(true);
        }
        say(READY_MARKER)?;
        if !self.wait_for_line(CONNECT_LINE)? {
            return Ok(false);
        }
        self.attach_subscribers();
        self.running.set(true);
        say(CONNECTED_MARKER)?;
        self.wait_for_line(START_LINE)
    }

    fn attach_subscribers(&self) {
        for sub in self.iox_subscribers.borrow().iter().filter_map(std::rc::Weak::upgrade) {
            sub.attach();
        }
    }

    /// Reads stdin until `expected`; false (and shutdown) when the launcher closes it.
    fn wait_for_line(&self, expected: &str) -> Result<bool> {
        let mut line = String::new();
        loop {
            line.clear();
            let n = std::io::stdin().lock().read_line(&mut line).map_err(|e| Error::Launcher(e.to_string()))?;
            if n == 0 {
                // The launcher closed our stdin: the graph is going down.
                self.request_shutdown();
                return Ok(false);
            }
            if line.trim() == expected {
                return Ok(true);
            }
        }
    }

    fn iox(&self) -> Result<&iox::IoxNode> {
        if let Some(n) = self.iox.get() {
            return Ok(n);
        }
        let node = iox::IoxNode::new(&self.name)?;
        Ok(self.iox.get_or_init(|| node))
    }

    /// The node's zenoh session (opened on first use from the bus configuration).
    pub fn zenoh_session(&self) -> Result<&zenoh::Session> {
        self.zenoh("(session)")
    }

    fn zenoh(&self, topic: &str) -> Result<&zenoh::Session> {
        if let Some(s) = self.zenoh.get() {
            return Ok(s);
        }
        let session =
            zen::open_session(&self.bus.zenoh).map_err(|what| Error::Zenoh { topic: topic.to_string(), what })?;
        Ok(self.zenoh.get_or_init(|| session))
    }
}

/// Prints a marker line for the launcher.
fn say(marker: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{marker}").map_err(|e| Error::Launcher(e.to_string()))?;
    out.flush().map_err(|e| Error::Launcher(e.to_string()))
}

/// A zenoh session configured as a node's would be from `config` (its endpoints, mode, TLS;
/// no multicast scouting), for a process that uses zenoh's API directly (the bus benchmark's raw
/// baseline).
pub fn open_zenoh_session(config: &ZenohConfig) -> std::result::Result<zenoh::Session, String> {
    zen::open_session(config)
}

/// Removes shared-memory resources left behind by iceoryx2 nodes whose processes died; returns
/// how many dead nodes were cleaned. The launcher calls this when a graph starts.
pub fn cleanup_stale_resources() -> Result<usize> {
    iox::cleanup_dead_nodes()
}

/// Sets up `tracing` to stderr: `RUST_LOG` or `info`, no colours when not on a terminal (the
/// launcher prefixes and forwards lines).
pub fn init_logging() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        // zenoh's session chatter (ids, endpoints, start-up scouting) is not the node's news.
        .unwrap_or_else(|_| {
            tracing_subscriber::EnvFilter::new("info,zenoh=warn,zenoh::net::runtime::orchestrator=error")
        });
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .try_init();
}

/// Parses a node's parameters with clap (bad ones: clap's message and exit status 2, as
/// `A::parse` does). Under `DC_VALIDATE=1` (the launcher checking a launch file) it only checks
/// them: `None` when they parse, so the node's `main` returns at once with success.
pub fn parse_args<A: clap::Parser>() -> Option<A> {
    parse_args_checked::<A, std::convert::Infallible>(|_| Ok(()))
}

/// An error and its causes on one line, `outer: cause: root`, each cause said once: a cause whose
/// text the message already carries (thiserror's `"{path}: {source}"` both shows and returns its
/// source) is not repeated, as anyhow's `Caused by:` list would.
pub fn error_text(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

/// Standard output was closed by its reader (`dc topic echo ... | head -3`); [`exit`] ends the
/// program quietly with status 0 on it, as coreutils do.
#[derive(Debug, thiserror::Error)]
#[error("standard output was closed")]
pub struct StdoutClosed;

/// Writes `text` to standard output and flushes it; a closed pipe is [`StdoutClosed`] (where
/// `println!` would panic), any other failure an error naming standard output.
pub fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(StdoutClosed.into()),
        Err(e) => Err(anyhow::Error::new(e).context("writing to standard output")),
    }
}

/// Writes a line to standard output for a program that must go on when nobody reads it (a
/// launcher forwarding its nodes' output): never panics; false when the line could not be
/// written (the reader went away).
pub fn try_print_line(text: &str) -> bool {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{text}").and_then(|()| out.flush()).is_ok()
}

/// [`try_print_line`] on standard error.
pub fn try_eprint_line(text: &str) -> bool {
    use std::io::Write;
    writeln!(std::io::stderr().lock(), "{text}").is_ok()
}

/// [`print_out`] of `text` and a line end.
pub fn print_line(text: &str) -> anyhow::Result<()> {
    print_out(&format!("{text}\n"))
}

/// A node binary's exit: `error: <error_text>` on stderr and status 1 for an error (every line of
/// a multi-line message kept, so the launcher forwards all of it), status 0 otherwise. Use as
/// `fn main() -> ExitCode { runtime::exit(run()) }`.
pub fn exit(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // Whoever read the output has stopped (`| head`): nothing is wrong, as for coreutils.
        Err(e) if e.chain().any(|c| c.is::<StdoutClosed>()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Finds a node binary: next to the running executable first (a cargo target dir), then on
/// `PATH`; a path (`scripts/node.py`) is taken as it is.
pub fn find_binary(name: &str) -> Option<std::path::PathBuf> {
    let direct = std::path::Path::new(name);
    if direct.components().count() > 1 {
        return direct.is_file().then(|| direct.to_path_buf());
    }
    let beside = std::env::current_exe().ok().and_then(|exe| exe.parent().map(|d| d.join(name)));
    if let Some(p) = beside.filter(|p| p.is_file()) {
        return Some(p);
    }
    std::env::var_os("PATH").and_then(|paths| std::env::split_paths(&paths).map(|d| d.join(name)).find(|p| p.is_file()))
}

/// The project's folder, where its shipped files lie (`models/`, `launch/`, `python/`): `DC_HOME`
/// if set, else the checkout these binaries were built from.
pub fn project_root() -> std::path::PathBuf {
    match std::env::var_os("DC_HOME") {
        Some(home) => home.into(),
        None => {
            let runtime_crate = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
            runtime_crate.parent().and_then(std::path::Path::parent).unwrap_or(runtime_crate).to_path_buf()
        }
    }
}

/// A shipped file (`models/unet-demo.dcu`) under [`project_root`]: what a default names, so that
/// the default holds from any folder.
pub fn shipped(relative: &str) -> std::path::PathBuf {
    project_root().join(relative)
}

/// Whether the launcher only asks which topics this node would use (`DC_DESCRIBE=1`): the node
/// then opens no file (a model, a recording), which may exist only on the host that runs it.
pub fn describing() -> bool {
    std::env::var("DC_DESCRIBE").is_ok_and(|v| v == "1")
}

/// [`parse_args`], then `check` on the parsed parameters (what clap cannot see: a grid too large,
/// a file that does not exist, values that only fail together), both when the launcher checks a
/// launch file (`DC_VALIDATE=1`) and before the node starts: a node whose parameters would fail
/// later never starts, and the error names the parameter (exit status 2, as clap's).
pub fn parse_args_checked<A: clap::Parser, E: std::fmt::Display>(
    check: impl FnOnce(&A) -> std::result::Result<(), E>,
) -> Option<A> {
    let validating = std::env::var("DC_VALIDATE").is_ok_and(|v| v == "1");
    let args = match A::try_parse() {
        Ok(a) => a,
        Err(e) => e.exit(),
    };
    // Describing the ports needs only the parameters' shape; the files are checked on the host
    // that runs the node (DC_VALIDATE).
    if describing() {
        return Some(args);
    }
    if let Err(e) = check(&args) {
        clap::Error::raw(clap::error::ErrorKind::ValueValidation, format!("{e:#}\n")).exit();
    }
    (!validating).then_some(args)
}

/// Sleeps up to `total`, waking early on shutdown; returns false if shut down.
pub fn sleep_unless_shutdown(node: &Node, total: Duration) -> bool {
    let deadline = std::time::Instant::now() + total;
    while std::time::Instant::now() < deadline {
        if node.is_shutdown() {
            return false;
        }
        std::thread::sleep(Duration::from_millis(10).min(total));
    }
    !node.is_shutdown()
}

/// Parses a duration parameter: a number with a unit, `1500us`, `20ms`, `0.5s`, `120s`, or a plain
/// number of milliseconds (`15`); whitespace around the number and the unit is allowed. Negative,
/// non-finite and too large values are errors; the message quotes the input.
pub fn parse_duration(s: &str) -> std::result::Result<Duration, String> {
    let t = s.trim();
    let (num, seconds_per_unit) = if let Some(v) = t.strip_suffix("ms") {
        (v, 1e-3)
    } else if let Some(v) = t.strip_suffix("us") {
        (v, 1e-6)
    } else if let Some(v) = t.strip_suffix('s') {
        (v, 1.0)
    } else {
        (t, 1e-3)
    };
    let bad = || format!("`{s}`: expected a duration like 1500us, 20ms, 0.5s, or a plain number of milliseconds");
    match num.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Duration::try_from_secs_f64(v * seconds_per_unit).map_err(|_| bad()),
        _ => Err(bad()),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn error_text_says_each_cause_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("{path}: {source}")]
        struct Shows {
            path: String,
            source: std::io::Error,
        }
        let io = std::io::Error::other("No space left on device");
        let e = anyhow::Error::new(Shows { path: "a.mcap".into(), source: io }).context("recording");
        assert_eq!(error_text(&e), "recording: a.mcap: No space left on device");
        let plain = anyhow::anyhow!("root").context("middle").context("top");
        assert_eq!(error_text(&plain), "top: middle: root");
    }

    use super::*;

    #[test]
    fn durations_parse_with_or_without_a_unit() {
        let ok = |s: &str| parse_duration(s).unwrap();
        assert_eq!(ok("20ms"), Duration::from_millis(20));
        assert_eq!(ok("0.5s"), Duration::from_millis(500));
        assert_eq!(ok("120s"), Duration::from_secs(120));
        assert_eq!(ok("1500us"), Duration::from_micros(1500));
        assert_eq!(ok("15"), Duration::from_millis(15), "a plain number is milliseconds");
        assert_eq!(ok(" 2.5 ms "), Duration::from_micros(2500));
        assert_eq!(ok("0"), Duration::ZERO);
        for bad in ["", "none", "lockstep", "soon", "ms", "-1s", "NaN", "inf", "1e300s", "5m", "1h"] {
            let err = parse_duration(bad).unwrap_err();
            assert!(err.contains(&format!("`{bad}`")), "{bad}: {err}");
        }
    }
}
