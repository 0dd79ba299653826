//! Starts one host's part of a graph as child processes, forwards their logs prefixed with the node
//! name, releases them together once every node's ports exist (on every host of the graph),
//! restarts nodes whose policy says so and tells the graph (control: node down / up), and stops
//! the whole graph on Ctrl-C or when a node fails.
//!
//! [`run_with`] is a loop over the phases of one `Supervisor`: take the nodes' events, move the
//! start-up barrier, watch the other hosts, announce restarted nodes, handle exits, and once the
//! workers are done `shutdown` (producers before their consumers); a failure, a timeout or
//! Ctrl-C ends the run with `abort` (every node at once) instead. What each phase decides is a
//! pure function (`barrier_step`, `hosts_gate`, `HostWatch::update`, `failure_action`,
//! `workers_finished`, `next_wave`) tested without processes; the methods around them do the
//! process and bus work, and `stop_nodes` is the one place a node is signalled.

use crate::graph::{Graph, NodeSpec, OnFailure};
use crate::plan::{self, Plan};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStderr, ChildStdin, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long nodes get to finish after SIGTERM before SIGKILL.
const STOP_GRACE: Duration = Duration::from_secs(5);
/// How often stopping nodes are looked at during [`STOP_GRACE`].
const STOP_POLL: Duration = Duration::from_millis(10);
/// How long one round of the run loop waits for the nodes' first event.
const EVENT_WAIT: Duration = Duration::from_millis(20);
/// How long the nodes' last output lines may take to arrive once they are stopped.
const LAST_LINES_WAIT: Duration = Duration::from_secs(2);
/// The state a launcher declares to the other hosts' launchers once its nodes are connected.
const CONNECTED: &str = "connected";
/// The state a launcher declares while it has workers not all done.
const WORKING: &str = "working";
/// How many of a node's last stderr lines the launcher keeps, to quote its error when it fails.
const STDERR_TAIL: usize = 40;
/// How long a failed node's stderr may take to drain before its error is quoted.
const STDERR_DRAIN: Duration = Duration::from_secs(1);

/// Knobs of a run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// How long a launcher waits for the other hosts' launchers to have their nodes connected.
    pub hosts_timeout: Duration,
    /// How long this host's nodes may take to be ready (a model to load, a Python process to
    /// import its packages) before the launcher gives up; it says whom it waits for long before.
    pub ready_timeout: Duration,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions { hosts_timeout: Duration::from_secs(120), ready_timeout: Duration::from_secs(120) }
    }
}

/// After this long without every node ready, the launcher says whom it waits for (and again
/// each time as long again has passed).
const READY_NOTICE: Duration = Duration::from_secs(5);

/// How a graph run ended.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// `said`: the node's own error (its last `error:` lines), empty if it said none.
    #[error("node `{node}` exited with {status}{said}")]
    NodeFailed { node: String, status: String, said: String },
    #[error("node `{node}` exited with {status} after {restarts} restarts (its bound): stopping the graph{said}")]
    RestartsExhausted { node: String, status: String, restarts: u32, said: String },
    #[error("node `{node}` could not start: {what}")]
    Spawn { node: String, what: String },
    #[error("interrupted")]
    Interrupted,
    #[error("no node of the graph is placed on host `{0}`")]
    NoNodes(String),
    #[error(transparent)]
    Graph(#[from] crate::graph::GraphError),
    #[error("launcher bus: {0}")]
    Bus(String),
    #[error("node {nodes} not ready within {secs} s of its start (a node is ready once its ports exist; `--ready-timeout` sets the limit)")]
    NotReady { nodes: String, secs: f64 },
    #[error("host {missing} did not get its nodes connected within {secs} s (is `dc launch --host` running there, and can this host reach it?)")]
    HostsMissing { missing: String, secs: f64 },
    /// Another graph runs on this namespace and host: its nodes would read and write ours.
    #[error("namespace `{namespace}` is in use on host `{host}` by {holder}; stop it, or give this one another namespace (`--namespace`)")]
    NamespaceInUse { namespace: String, host: String, holder: String },
    #[error("namespace lock {path}: {what}")]
    NamespaceLock { path: String, what: String },
}

impl From<runtime::lock::LockError> for RunError {
    fn from(e: runtime::lock::LockError) -> RunError {
        match e {
            runtime::lock::LockError::InUse { namespace, host, holder } => {
                RunError::NamespaceInUse { namespace, host, holder }
            }
            runtime::lock::LockError::Io { path, what } => RunError::NamespaceLock { path, what },
        }
    }
}

/// Where captured node output goes.
#[derive(Clone)]
pub enum Output {
    /// Print `[node] line` on our stdout / stderr.
    Forward,
    /// Keep every stdout line per node instead of printing it (for `dc bench`, whose output is
    /// a table: the start notices are not printed either); stderr is still forwarded.
    Capture,
    /// Hand every line to a watcher (a progress display) instead of printing it; only
    /// warnings, errors and lines that are not log records are printed (`[node] line` on
    /// stderr), and the launcher's own start notices are not.
    Watch(LineWatcher),
}

/// Sees each output line of each node: `(node, is stderr, line)`.
pub type LineWatcher = std::sync::Arc<dyn Fn(&str, bool, &str) + Send + Sync>;

/// Whether a node's stderr line is a routine log record (`... INFO ...`, `DEBUG`, `TRACE`)
/// rather than a warning, an error or a message of its own.
fn routine_log_line(line: &str) -> bool {
    let mut words = line.split_whitespace();
    let (Some(first), Some(level)) = (words.next(), words.next()) else { return false };
    // tracing's format: an RFC 3339 time, then the level.
    first.len() >= 20 && first.as_bytes()[4] == b'-' && matches!(level, "INFO" | "DEBUG" | "TRACE")
}

enum Event {
    Ready(usize),
    Connected(usize),
    /// The node finished its work and keeps its publishers alive until released.
    Done(usize),
    Line(usize, String),
    /// A stderr line (already printed), and the end of the node's stderr.
    ErrLine(usize, String),
    ErrClosed(usize),
}

/// Where a node is in its start-up handshake.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Phase {
    Starting,
    Ready,
    Connected,
    Started,
}

struct Running {
    spec: NodeSpec,
    child: Child,
    stdin: Option<ChildStdin>,
    exited: Option<ExitStatus>,
    /// Said it is done (see [`runtime::DONE_MARKER`]); exits once its stdin closes.
    done: bool,
    phase: Phase,
    restarts: u32,
    /// Its last stderr lines, and whether its stderr is still open.
    stderr_tail: std::collections::VecDeque<String>,
    stderr_open: bool,
}

/// What a failed node said about its failure, from its last stderr lines: from the last line
/// that starts an error (`error: ...` of `runtime::exit`, a tracing `ERROR`, a panic) to the end,
/// as `": line; line"` for the launcher's message (empty when it said nothing of the kind).
fn error_said<'a>(tail: impl DoubleEndedIterator<Item = &'a String> + ExactSizeIterator) -> String {
    let lines: Vec<&String> = tail.collect();
    let starts = |l: &str| l.starts_with("error:") || l.contains(" ERROR ") || l.contains("panicked at");
    match lines.iter().rposition(|l| starts(l)) {
        Some(at) => {
            let said: Vec<&str> = lines[at..].iter().map(|l| l.trim()).filter(|l| !l.is_empty()).collect();
            format!(": {}", said.join("; "))
        }
        None => String::new(),
    }
}

impl Running {
    fn finished(&self) -> bool {
        self.done || self.exited.is_some()
    }

    /// Keeps a stderr line among the last [`STDERR_TAIL`].
    fn keep_stderr_line(&mut self, line: String) {
        if self.stderr_tail.len() == STDERR_TAIL {
            self.stderr_tail.pop_front();
        }
        self.stderr_tail.push_back(line);
    }
}

/// What a finished run leaves: per node, its captured stdout lines (with [`Output::Capture`]) and
/// how often it was restarted.
#[derive(Debug, Default)]
pub struct RunReport {
    pub stdout: BTreeMap<String, Vec<String>>,
    pub restarts: BTreeMap<String, u32>,
}

/// The launcher's own place on the bus: it publishes node down / up notices on `control` and,
/// on a graph of several hosts, meets the other launchers (liveliness tokens).
struct LauncherBus {
    // Field order is drop order: ports before the node, the router last.
    control: runtime::Publisher<msgs::Control, u8>,
    sync: Option<runtime::HostSync>,
    /// [`graph_identity`] and when this launcher started (ns since the epoch), as declared.
    identity: u64,
    started: u128,
    _node: runtime::Node,
    _router: Option<runtime::zenoh::Session>,
}

impl LauncherBus {
    fn open(graph: &Graph, plan: &Plan, host: &str) -> Result<LauncherBus, RunError> {
        let bus_err = |e: String| RunError::Bus(e);
        // The router first: every node of the graph connects to it.
        let router = match &plan.router {
            Some((endpoint, router_host)) if router_host == host => {
                tracing::info!(endpoint, "zenoh router for the graph");
                Some(runtime::open_router(endpoint, plan.tls_of(host).as_ref()).map_err(bus_err)?)
            }
            _ => None,
        };
        let name = plan::launcher_name(host);
        let node = runtime::Node::new(name.clone(), plan.bus(&name, host), false);
        let control = node.publisher(msgs::topics::CONTROL).map_err(|e| bus_err(e.to_string()))?;
        let started = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let identity = graph_identity(graph);
        let sync = if plan.multi_host {
            let session = node.zenoh_session().map_err(|e| bus_err(e.to_string()))?;
            let mut sync =
                runtime::HostSync::new(session, &format!("dc/{}/_launch", graph.namespace)).map_err(bus_err)?;
            sync.declare(host, &format!("{GRAPH_STATE}-{identity:016x}-{started}")).map_err(bus_err)?;
            Some(sync)
        } else {
            None
        };
        Ok(LauncherBus { control, sync, identity, started, _node: node, _router: router })
    }

    /// Tells the graph that a node went down (`up == false`) or came back.
    fn notice(&mut self, up: bool, notice: msgs::NodeNotice) {
        let msg = msgs::ControlMsg::node_notice(up, &notice);
        if let Err(e) = self.control.publish_frame(&msg) {
            let kind = if up { msgs::ControlKind::NodeUp } else { msgs::ControlKind::NodeDown };
            tracing::warn!("could not publish the {kind:?} notice of `{}`: {e}", notice.node);
        }
    }
}

/// The notice about `node` of `host`, with the topics it publishes.
fn notice_of(plan: &Plan, node: &str, host: &str, status: &str) -> msgs::NodeNotice {
    msgs::NodeNotice {
        node: node.to_string(),
        host: host.to_string(),
        publishes: published(plan, node),
        status: status.to_string(),
    }
}

/// Where this host's start-up barrier stands. Two barriers: every node's ports exist (ready) ->
/// `connect`; every node attached its subscribers (connected) -> `start`. With several hosts,
/// `start` waits for every host's nodes to be connected, so no source publishes into a graph half
/// there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Waiting for every node to be ready.
    Spawned,
    /// Told `connect`; waiting for every node (and host) to be connected.
    Connecting,
    /// Told `start`.
    Started,
}

struct BarrierState {
    stage: Stage,
    /// When the nodes were spawned (the other hosts get [`RunOptions::hosts_timeout`] from then).
    since: Instant,
    /// How many "waiting for node ..." notices were said.
    ready_notices: u32,
}

impl BarrierState {
    /// `connect` was said (restarted nodes are told it too).
    fn connecting(&self) -> bool {
        self.stage != Stage::Spawned
    }

    fn started(&self) -> bool {
        self.stage == Stage::Started
    }
}

/// What the barrier does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BarrierStep {
    /// Nothing yet (or nothing left: started).
    Hold,
    /// Every node is ready (or finished): say `connect`.
    Connect,
    /// Every node here is connected (or finished): say `start` once every host is.
    LocalConnected,
}

/// The barrier's next step from its stage and each node's `(phase, finished)`: a finished node
/// counts as past every barrier.
fn barrier_step(stage: Stage, nodes: impl IntoIterator<Item = (Phase, bool)>) -> BarrierStep {
    let (needed, step) = match stage {
        Stage::Spawned => (Phase::Ready, BarrierStep::Connect),
        Stage::Connecting => (Phase::Connected, BarrierStep::LocalConnected),
        Stage::Started => return BarrierStep::Hold,
    };
    if nodes.into_iter().all(|(phase, finished)| phase >= needed || finished) {
        step
    } else {
        BarrierStep::Hold
    }
}

/// Whether `start` may go once this host's nodes are connected, with several hosts.
#[derive(Debug, Clone, PartialEq, Eq)]
enum HostsGate {
    /// Every host with nodes has them connected.
    Open,
    Wait,
    /// These hosts did not get their nodes connected in time.
    TimedOut(Vec<String>),
}

/// The gate from the hosts with nodes, those whose launchers say `connected`, and how long we
/// have waited.
fn hosts_gate(with_nodes: &[String], connected: &BTreeSet<String>, waited: Duration, timeout: Duration) -> HostsGate {
    let missing: Vec<String> = with_nodes.iter().filter(|h| !connected.contains(*h)).cloned().collect();
    if missing.is_empty() {
        HostsGate::Open
    } else if waited > timeout {
        HostsGate::TimedOut(missing)
    } else {
        HostsGate::Wait
    }
}

/// The state naming a multi-host launcher's graph and when it started: `graph-<identity>-<start>`
/// (identity: [`graph_identity`]; start: nanoseconds since the epoch).
const GRAPH_STATE: &str = "graph";

/// What tells two graphs apart across hosts: the graph's name, hosts and nodes (name, binary,
/// host, arguments), hashed. Every host's launcher of one graph computes the same value from its
/// copy of the file; a different graph on the same namespace does not.
pub fn graph_identity(graph: &Graph) -> u64 {
    let mut text = format!("{}\n", graph.name);
    for (name, h) in &graph.hosts {
        text.push_str(&format!("host {name} {} {} {}\n", h.address, h.zenoh_port, h.router));
    }
    for n in &graph.nodes {
        text.push_str(&format!("node {} {} {} {}\n", n.name, n.binary, n.host, n.args.join(" ")));
    }
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Among the launchers alive on the namespace, one that was there first and is another graph's,
/// or another launcher of this graph for this very host: `(its host, what it is)`. The newcomer
/// refuses; the graph that was there first goes on.
fn earlier_claim(
    alive: &BTreeSet<(String, String)>,
    host: &str,
    identity: u64,
    started: u128,
) -> Option<(String, String)> {
    alive.iter().find_map(|(h, state)| {
        let rest = state.strip_prefix(GRAPH_STATE)?.strip_prefix('-')?;
        let (id, start) = rest.split_once('-')?;
        let (id, start) = (u64::from_str_radix(id, 16).ok()?, start.parse::<u128>().ok()?);
        if start >= started {
            return None;
        }
        if id != identity {
            Some((h.clone(), format!("another graph, identity {id:016x}, on host `{h}`")))
        } else if h == host {
            Some((h.clone(), format!("this graph's launcher for host `{h}`, started earlier")))
        } else {
            None
        }
    })
}

/// The hosts whose launchers hold `state` among the alive `(host, state)` tokens.
fn hosts_in(alive: &BTreeSet<(String, String)>, state: &str) -> BTreeSet<String> {
    alive.iter().filter(|(_, s)| s == state).map(|(h, _)| h.clone()).collect()
}

/// Another host's launcher vanished, or came back.
#[derive(Debug, Clone, PartialEq, Eq)]
enum HostChange {
    Gone(String),
    Back(String),
}

/// The other hosts as this launcher has seen them since `start`.
#[derive(Debug, Default)]
struct HostWatch {
    /// Hosts with nodes, this one included.
    with_nodes: Vec<String>,
    /// Other hosts seen running.
    seen: BTreeSet<String>,
    /// Other hosts that went away.
    gone: BTreeSet<String>,
    /// This host declared `working` (it has workers, not all done).
    working_declared: bool,
}

impl HostWatch {
    /// Compares the other hosts with nodes (not `me`) with those whose launchers are `connected`
    /// now: a seen host no longer there is gone, a gone host there again is back (a host seen
    /// for the first time is just seen).
    fn update(&mut self, me: &str, connected: &BTreeSet<String>) -> Vec<HostChange> {
        let mut changes = Vec::new();
        for h in self.with_nodes.iter().filter(|h| h.as_str() != me) {
            match (self.seen.contains(h), connected.contains(h)) {
                (true, false) => {
                    self.seen.remove(h);
                    self.gone.insert(h.clone());
                    changes.push(HostChange::Gone(h.clone()));
                }
                (false, true) => {
                    if self.gone.remove(h) {
                        changes.push(HostChange::Back(h.clone()));
                    }
                    self.seen.insert(h.clone());
                }
                _ => {}
            }
        }
        changes
    }
}

/// What happens to a node that exited with a failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FailureAction {
    /// Start it again: restart number `attempt` of at most `max`.
    Restart { attempt: u32, max: u32 },
    /// Its restarts are used up: stop the graph.
    Exhausted { restarts: u32 },
    /// Its policy is to stop the graph.
    StopGraph,
}

/// The action for a failed node from its policy and how often it was restarted.
fn failure_action(policy: OnFailure, restarts: u32) -> FailureAction {
    match policy {
        OnFailure::Restart { max } if restarts < max => FailureAction::Restart { attempt: restarts + 1, max },
        OnFailure::Restart { .. } => FailureAction::Exhausted { restarts },
        OnFailure::StopGraph => FailureAction::StopGraph,
    }
}

/// Started, and every worker (non-daemon) of `(daemon, finished)` finished.
fn workers_finished(started: bool, nodes: impl IntoIterator<Item = (bool, bool)>) -> bool {
    started && nodes.into_iter().filter(|(daemon, _)| !daemon).all(|(_, finished)| finished)
}

/// A node that fails while being stopped (an exit code, not our signal) is still a failure.
fn failed_on_stop(status: ExitStatus) -> bool {
    !status.success() && status.code().is_some()
}

/// Runs the nodes of `graph` placed on `host` until they are all done (daemons are stopped when
/// the others are, on every host), a node fails past its policy, or `interrupt` fires.
pub fn run(
    graph: &Graph,
    host: &str,
    output: Output,
    interrupt: &std::sync::atomic::AtomicBool,
) -> Result<RunReport, RunError> {
    run_with(graph, host, output, interrupt, &RunOptions::default())
}

/// [`run`] with options.
pub fn run_with(
    graph: &Graph,
    host: &str,
    output: Output,
    interrupt: &std::sync::atomic::AtomicBool,
    options: &RunOptions,
) -> Result<RunReport, RunError> {
    let mut sup = Supervisor::new(graph, host, output, options)?;
    sup.spawn_all()?;
    loop {
        sup.pump_events();
        sup.list_nodes();
        sup.watch_ready()?;
        sup.advance_barrier()?;
        sup.watch_hosts();
        sup.announce_restarted();
        if interrupt.load(std::sync::atomic::Ordering::SeqCst) {
            return Err(sup.interrupted());
        }
        sup.handle_exits()?;
        if sup.workers_done() && sup.other_hosts_done() {
            return sup.shutdown();
        }
    }
}

/// One host's run of a graph.
struct Supervisor<'a> {
    // Field order is drop order: the nodes' pipes close before the bus goes.
    nodes: Vec<Running>,
    report: RunReport,
    rx: mpsc::Receiver<Event>,
    tx: mpsc::Sender<Event>,
    bus: LauncherBus,
    plan: Plan,
    graph: &'a Graph,
    host: &'a str,
    output: Output,
    options: &'a RunOptions,
    /// Width of the node-name column of forwarded lines.
    width: usize,
    barrier: BarrierState,
    hosts: HostWatch,
    /// What `dc node list` was last told: each node's pid, exit status and whether it is done.
    listed: Vec<(u32, Option<ExitStatus>, bool)>,
    /// Last: released after every node is stopped and the bus closed.
    namespace_lock: runtime::lock::NamespaceLock,
}

impl<'a> Supervisor<'a> {
    /// Routes the graph and joins the bus; cleans up what dead iceoryx2 nodes left first.
    fn new(graph: &'a Graph, host: &'a str, output: Output, options: &'a RunOptions) -> Result<Self, RunError> {
        let width = match graph.nodes_on(host).map(|s| s.name.len()).max() {
            Some(w) => w,
            None => return Err(RunError::NoNodes(host.to_string())),
        };
        let lock = runtime::lock::NamespaceLock::acquire(&graph.namespace, host, &format!("graph `{}`", graph.name))?;
        match runtime::cleanup_stale_resources() {
            Ok(0) => {}
            Ok(n) => tracing::info!("cleaned shared-memory resources of {n} dead iceoryx2 nodes"),
            Err(e) => tracing::warn!("stale resource cleanup failed: {e}"),
        }
        let ports = plan::describe_ports(graph)?;
        let mut plan = Plan::new(graph, &ports);
        plan.check_port_limits(graph)?;
        let mut attempt = 1;
        let bus = loop {
            match LauncherBus::open(graph, &plan, host) {
                // A port picked for the router was taken before the router bound it: another.
                Err(RunError::Bus(e)) if attempt < 20 && e.contains("open router") && plan.choose_router_port() => {
                    tracing::warn!(attempt, "zenoh router port taken ({e}): trying another");
                    attempt += 1;
                }
                other => break other?,
            }
        };
        let (tx, rx) = mpsc::channel::<Event>();
        let with_nodes = graph.hosts.keys().filter(|h| graph.nodes_on(h).next().is_some()).cloned().collect();
        Ok(Supervisor {
            namespace_lock: lock,
            listed: Vec::new(),
            nodes: Vec::new(),
            report: RunReport::default(),
            rx,
            tx,
            bus,
            plan,
            graph,
            host,
            output,
            options,
            width,
            barrier: BarrierState { stage: Stage::Spawned, since: Instant::now(), ready_notices: 0 },
            hosts: HostWatch { with_nodes, ..Default::default() },
        })
    }

    /// Starts every node of this host; if one cannot start, stops those started.
    fn spawn_all(&mut self) -> Result<(), RunError> {
        let graph = self.graph;
        for (i, spec) in graph.nodes_on(self.host).enumerate() {
            match self.spawn(i, spec) {
                Ok((child, stdin)) => self.nodes.push(Running {
                    spec: spec.clone(),
                    child,
                    stdin,
                    exited: None,
                    done: false,
                    phase: Phase::Starting,
                    restarts: 0,
                    stderr_tail: Default::default(),
                    stderr_open: true,
                }),
                Err(e) => return Err(self.abort(e)),
            }
        }
        self.barrier.since = Instant::now();
        Ok(())
    }

    /// Starts node `i` with its bus configuration, and threads that turn its stdout into events
    /// and forward its stderr.
    fn spawn(&self, i: usize, spec: &NodeSpec) -> Result<(Child, Option<ChildStdin>), RunError> {
        let bus_json = serde_json::to_string(&self.plan.bus(&spec.name, self.host)).expect("bus config serialises");
        let mut cmd = Command::new(&spec.program);
        if let Some(dir) = &spec.workdir {
            cmd.current_dir(dir);
        }
        cmd.args(&spec.args)
            .envs(&spec.env)
            .env("DC_NODE_NAME", &spec.name)
            .env("DC_BUS", bus_json)
            .env("DC_LAUNCHED", "1")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        die_with_parent(&mut cmd);
        let mut child = cmd.spawn().map_err(|e| RunError::Spawn { node: spec.name.clone(), what: e.to_string() })?;
        let watcher = match &self.output {
            Output::Watch(w) => Some((spec.name.clone(), w.clone())),
            Output::Forward => {
                tell!("[dc] node `{}` started (pid {})", spec.name, child.id());
                None
            }
            Output::Capture => None,
        };
        let prefix = format!("[{:width$}]", spec.name, width = self.width);
        let forward = matches!(self.output, Output::Forward);
        let stdout = child.stdout.take().expect("piped");
        let (p, tx, w) = (prefix.clone(), self.tx.clone(), watcher.clone());
        std::thread::spawn(move || read_stdout(i, stdout, forward.then_some(p), w, tx));
        let stderr = child.stderr.take().expect("piped");
        let tx = self.tx.clone();
        std::thread::spawn(move || read_stderr(i, stderr, prefix, watcher, tx));
        let stdin = child.stdin.take();
        Ok((child, stdin))
    }

    /// Takes the nodes' events (handshake markers, captured lines), waiting briefly for the first.
    fn pump_events(&mut self) {
        let mut first = self.rx.recv_timeout(EVENT_WAIT).ok();
        while let Some(ev) = first.take().or_else(|| self.rx.try_recv().ok()) {
            match ev {
                Event::Ready(i) => self.nodes[i].phase = self.nodes[i].phase.max(Phase::Ready),
                Event::Connected(i) => self.nodes[i].phase = self.nodes[i].phase.max(Phase::Connected),
                Event::Done(i) => self.nodes[i].done = true,
                Event::Line(i, line) => self.capture(i, line),
                Event::ErrLine(i, line) => {
                    if let Some(n) = self.nodes.get_mut(i) {
                        n.keep_stderr_line(line);
                    }
                }
                Event::ErrClosed(i) => {
                    if let Some(n) = self.nodes.get_mut(i) {
                        n.stderr_open = false;
                    }
                }
            }
        }
    }

    /// Keeps a stdout line of node `i` with [`Output::Capture`].
    fn capture(&mut self, i: usize, line: String) {
        if matches!(self.output, Output::Capture) {
            self.report.stdout.entry(self.nodes[i].spec.name.clone()).or_default().push(line);
        }
    }

    fn phases(&self) -> impl Iterator<Item = (Phase, bool)> + '_ {
        self.nodes.iter().map(|n| (n.phase, n.finished()))
    }

    /// Tells `dc node list` this host's nodes (beside the namespace lock) when one started,
    /// finished or was restarted since it was last told.
    fn list_nodes(&mut self) {
        // Compared on every pass of the supervisor's loop: plain values, no text.
        let unchanged = self.listed.len() == self.nodes.len()
            && self.nodes.iter().zip(&self.listed).all(|(n, l)| *l == (n.child.id(), n.exited, n.done));
        if unchanged {
            return;
        }
        self.listed = self.nodes.iter().map(|n| (n.child.id(), n.exited, n.done)).collect();
        let state = |n: &Running| match (n.exited, n.done) {
            (Some(status), _) => status.to_string(),
            (None, true) => "done".to_string(),
            (None, false) => "running".to_string(),
        };
        let nodes = self
            .nodes
            .iter()
            .map(|n| runtime::lock::NodeEntry {
                name: n.spec.name.clone(),
                program: n.spec.program.display().to_string(),
                pid: n.child.id(),
                state: state(n),
                restarts: n.restarts,
            })
            .collect();
        let list = runtime::lock::GraphNodes {
            namespace: self.graph.namespace.clone(),
            host: self.host.to_string(),
            graph: self.graph.name.clone(),
            launcher_pid: std::process::id(),
            nodes,
        };
        if let Err(e) = self.namespace_lock.list_nodes(&list) {
            tracing::debug!("cannot list the nodes for `dc node list`: {e}");
        }
    }

    /// While the nodes are not all ready: says whom the graph waits for every [`READY_NOTICE`],
    /// and past [`RunOptions::ready_timeout`] stops the nodes and fails naming them.
    fn watch_ready(&mut self) -> Result<(), RunError> {
        if self.barrier.stage != Stage::Spawned {
            return Ok(());
        }
        let waited = self.barrier.since.elapsed();
        let notices = (waited.as_secs_f64() / READY_NOTICE.as_secs_f64()) as u32;
        if notices <= self.barrier.ready_notices && waited < self.options.ready_timeout {
            return Ok(());
        }
        self.barrier.ready_notices = notices;
        let waiting: Vec<String> = self
            .nodes
            .iter()
            .filter(|n| n.phase < Phase::Ready && !n.finished())
            .map(|n| format!("`{}`", n.spec.name))
            .collect();
        if waiting.is_empty() {
            return Ok(());
        }
        let nodes = waiting.join(", ");
        if waited >= self.options.ready_timeout {
            let secs = self.options.ready_timeout.as_secs_f64();
            return Err(self.abort(RunError::NotReady { nodes, secs }));
        }
        tell!(
            "[dc] waiting for node {nodes} to be ready ({:.0} s of at most {:.0} s)",
            waited.as_secs_f64(),
            self.options.ready_timeout.as_secs_f64()
        );
        Ok(())
    }

    /// Says `connect` once every node is ready, then `start` once every node (on every host) is
    /// connected; both may happen in one call.
    fn advance_barrier(&mut self) -> Result<(), RunError> {
        if barrier_step(self.barrier.stage, self.phases()) == BarrierStep::Connect {
            self.barrier.stage = Stage::Connecting;
            tell_all(&mut self.nodes, runtime::CONNECT_LINE);
        }
        if barrier_step(self.barrier.stage, self.phases()) == BarrierStep::LocalConnected && self.hosts_connected()? {
            self.barrier.stage = Stage::Started;
            tell_all(&mut self.nodes, runtime::START_LINE);
            for n in self.nodes.iter_mut() {
                n.phase = n.phase.max(Phase::Started);
            }
            tracing::debug!("all {} nodes connected: started", self.nodes.len());
        }
        Ok(())
    }

    /// With several hosts: says this host's nodes are connected and tells whether every host's
    /// are; past the timeout, stops the nodes and fails. With one host: yes.
    fn hosts_connected(&mut self) -> Result<bool, RunError> {
        let Some(sync) = &mut self.bus.sync else { return Ok(true) };
        // `working` before `connected`: a host that sees us connected has seen that we have
        // workers too (one session delivers in order), so it cannot mistake us for done and stop
        // its daemons under our feet.
        if !self.hosts.working_declared && self.nodes.iter().any(|n| !n.spec.daemon) {
            sync.declare(self.host, WORKING).map_err(RunError::Bus)?;
            self.hosts.working_declared = true;
        }
        // Another graph on this namespace reached over zenoh (another machine: the lock file
        // only sees this one), or a second launcher for this host: refused before our nodes
        // talk to theirs.
        let (identity, started) = (self.bus.identity, self.bus.started);
        if let Some((host, holder)) = earlier_claim(sync.alive(), self.host, identity, started) {
            let namespace = self.graph.namespace.clone();
            return Err(self.abort(RunError::NamespaceInUse { namespace, host, holder }));
        }
        sync.declare(self.host, CONNECTED).map_err(RunError::Bus)?;
        let connected = hosts_in(sync.alive(), CONNECTED);
        match hosts_gate(&self.hosts.with_nodes, &connected, self.barrier.since.elapsed(), self.options.hosts_timeout) {
            HostsGate::Open => Ok(true),
            HostsGate::Wait => Ok(false),
            HostsGate::TimedOut(missing) => {
                let missing = missing.iter().map(|h| format!("`{h}`")).collect::<Vec<_>>().join(", ");
                Err(self.abort(RunError::HostsMissing { missing, secs: self.options.hosts_timeout.as_secs_f64() }))
            }
        }
    }

    /// Another host whose launcher vanished (its liveliness went: killed, or unreachable past
    /// zenoh's lease) takes its nodes with it: tell ours, so that a simulator stops waiting for
    /// grids that cannot come. Back when its launcher is.
    fn watch_hosts(&mut self) {
        if !self.barrier.started() {
            return;
        }
        let Some(sync) = &mut self.bus.sync else { return };
        let connected = hosts_in(sync.alive(), CONNECTED);
        let changes = self.hosts.update(self.host, &connected);
        for change in &changes {
            match change {
                HostChange::Gone(h) => tell!("[dc] host `{h}` is gone: its nodes count as down"),
                HostChange::Back(h) => tell!("[dc] host `{h}` is back"),
            }
        }
        let graph = self.graph;
        for change in changes {
            let (up, h, status) = match &change {
                HostChange::Gone(h) => (false, h, "host gone"),
                HostChange::Back(h) => (true, h, "host back"),
            };
            for node in graph.nodes_on(h) {
                self.bus.notice(up, notice_of(&self.plan, &node.name, h, status));
            }
        }
    }

    /// A restarted node was told to connect and start at spawn; once connected it is back.
    fn announce_restarted(&mut self) {
        for n in self.nodes.iter_mut().filter(|n| n.restarts > 0 && n.exited.is_none() && n.phase == Phase::Connected) {
            n.phase = Phase::Started;
            tell!("[dc] node `{}` is back (restart {})", n.spec.name, n.restarts);
            self.bus.notice(true, notice_of(&self.plan, &n.spec.name, self.host, "running"));
        }
    }

    /// Notes the nodes that exited; a failed one is restarted or stops the graph (an error).
    fn handle_exits(&mut self) -> Result<(), RunError> {
        for i in 0..self.nodes.len() {
            let n = &mut self.nodes[i];
            if n.exited.is_some() {
                continue;
            }
            let Ok(Some(status)) = n.child.try_wait() else { continue };
            n.exited = Some(status);
            if !status.success() {
                self.node_failed(i, status)?;
            }
        }
        Ok(())
    }

    /// Node `i` exited with the failure `status`: restarts it, or ends the run as its policy says.
    fn node_failed(&mut self, i: usize, status: ExitStatus) -> Result<(), RunError> {
        let name = self.nodes[i].spec.name.clone();
        let described = describe(status);
        let said = self.last_words(i);
        // Its shared-memory ports must go at once: publishers would wait on its full queues.
        if let Err(e) = runtime::cleanup_stale_resources() {
            tracing::warn!("cleaning the dead node's resources: {e}");
        }
        let down = notice_of(&self.plan, &name, self.host, &described);
        let e = match failure_action(self.nodes[i].spec.on_failure, self.nodes[i].restarts) {
            FailureAction::Restart { attempt, max } => {
                self.nodes[i].restarts = attempt;
                tell!("[dc] node `{name}` exited with {described}: restarting it ({attempt} of at most {max})");
                self.bus.notice(false, down);
                self.restart(i)?;
                self.report.restarts.insert(name, attempt);
                return Ok(());
            }
            FailureAction::Exhausted { restarts } => {
                tell!("[dc] node `{name}` exited with {described} after {restarts} restarts: stopping the graph");
                self.bus.notice(false, down);
                RunError::RestartsExhausted { node: name, status: described, restarts, said }
            }
            FailureAction::StopGraph => {
                tell!("[dc] node `{name}` exited with {described}: stopping the graph");
                RunError::NodeFailed { node: name, status: described, said }
            }
        };
        let e = self.abort(e);
        // What the other nodes said on their way out comes before the error.
        self.take_last_lines();
        Err(e)
    }

    /// What failed node `i` said about its failure ([`error_said`]): its last words are still
    /// in the pipe, so they get [`STDERR_DRAIN`] to arrive. Its kept lines are cleared after.
    fn last_words(&mut self, i: usize) -> String {
        let since = Instant::now();
        while self.nodes[i].stderr_open && since.elapsed() < STDERR_DRAIN {
            self.pump_events();
        }
        let said = error_said(self.nodes[i].stderr_tail.iter());
        self.nodes[i].stderr_tail.clear();
        said
    }

    /// Starts node `i` again and tells it the barrier lines already said: it reads them once its
    /// ports exist, the rest of the graph is running.
    fn restart(&mut self, i: usize) -> Result<(), RunError> {
        let spec = self.nodes[i].spec.clone();
        let (child, stdin) = match self.spawn(i, &spec) {
            Ok(c) => c,
            Err(e) => return Err(self.abort(e)),
        };
        let n = &mut self.nodes[i];
        (n.child, n.stdin, n.exited, n.done, n.phase) = (child, stdin, None, false, Phase::Starting);
        n.stderr_open = true;
        if self.barrier.connecting() {
            tell(n, runtime::CONNECT_LINE);
        }
        if self.barrier.started() {
            tell(n, runtime::START_LINE);
        }
        Ok(())
    }

    fn workers_done(&self) -> bool {
        workers_finished(self.barrier.started(), self.nodes.iter().map(|n| (n.spec.daemon, n.finished())))
    }

    /// On a graph of several hosts, this host's workers are done: say so and tell whether every
    /// other host's are too (a host that disappeared loses its token and counts as done).
    fn other_hosts_done(&mut self) -> bool {
        let Some(sync) = &mut self.bus.sync else { return true };
        if self.hosts.working_declared {
            sync.withdraw(self.host, WORKING);
            self.hosts.working_declared = false;
        }
        !sync.alive().iter().any(|(_, state)| state == WORKING)
    }

    /// The end of a run whose workers are done: the nodes at work (daemons) stop in waves,
    /// producers first, so they drain what the finished workers sent (whose publishers are still
    /// alive); then the lingering workers. A node that fails while being stopped is still a
    /// failure worth reporting.
    fn shutdown(mut self) -> Result<RunReport, RunError> {
        stop_in_waves(&mut self.nodes, &self.plan);
        stop_nodes(&mut self.nodes, |_| true);
        self.take_last_lines();
        if let Some(n) = self.nodes.iter().find(|n| n.exited.is_some_and(failed_on_stop)) {
            let status = describe(n.exited.unwrap());
            let said = error_said(n.stderr_tail.iter());
            return Err(RunError::NodeFailed { node: n.spec.name.clone(), status, said });
        }
        Ok(std::mem::take(&mut self.report))
    }

    fn interrupted(&mut self) -> RunError {
        tell!("[dc] interrupted: stopping the graph");
        self.abort(RunError::Interrupted)
    }

    /// The end of a run on `e`: stops every node at once and passes `e` on.
    fn abort(&mut self, e: RunError) -> RunError {
        stop_nodes(&mut self.nodes, |_| true);
        e
    }

    /// Takes the stdout lines still on their way from stopped nodes (for [`Output::Capture`]),
    /// for at most [`LAST_LINES_WAIT`].
    fn take_last_lines(&mut self) {
        // Reader threads finish once the children's pipes close; with the supervisor's own
        // sender gone, the channel then disconnects and the wait ends at once (no node is
        // spawned after this).
        drop(std::mem::replace(&mut self.tx, mpsc::channel().0));
        let deadline = Instant::now() + LAST_LINES_WAIT;
        while let Ok(ev) = self.rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            if let Event::Line(i, line) = ev {
                self.capture(i, line);
            }
        }
    }
}

/// The topics `node` publishes, for the down / up notices.
fn published(plan: &Plan, node: &str) -> Vec<String> {
    plan.members
        .iter()
        .find(|m| m.name == node)
        .map(|m| m.ports.publishes.iter().cloned().collect())
        .unwrap_or_default()
}

fn tell(n: &mut Running, line: &str) {
    if let Some(stdin) = &mut n.stdin {
        let _ = writeln!(stdin, "{line}").and_then(|_| stdin.flush());
    }
}

/// Writes a line to every running node's stdin.
fn tell_all(nodes: &mut [Running], line: &str) {
    for n in nodes.iter_mut().filter(|n| n.exited.is_none()) {
        tell(n, line);
    }
}

fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit status {c}"),
        (None, Some(s)) => format!("signal {s}"),
        _ => status.to_string(),
    }
}

/// Stops the nodes still at work, one [`next_wave`] at a time: each wave exits before the next is
/// asked to, so what a producer makes of its last inputs (an SPH node's last grids) still reaches
/// a reader that records it.
fn stop_in_waves(nodes: &mut [Running], plan: &Plan) {
    let ports = |name: &str| plan.members.iter().find(|m| m.name == name).map(|m| &m.ports);
    loop {
        let at_work: Vec<String> =
            nodes.iter().filter(|n| n.exited.is_none() && !n.done).map(|n| n.spec.name.clone()).collect();
        if at_work.is_empty() {
            return;
        }
        let wave = next_wave(at_work, ports);
        stop_nodes(nodes, |n| wave.contains(&n.spec.name));
    }
}

/// The nodes of `at_work` to stop first: those none of whose input topics another of them writes
/// (the launchers' control notices aside); all of them when they read each other.
fn next_wave<'p>(at_work: Vec<String>, ports: impl Fn(&str) -> Option<&'p runtime::Ports>) -> Vec<String> {
    let fed_by_others = |name: &str| {
        ports(name).is_some_and(|p| {
            p.subscribes
                .iter()
                .filter(|t| t.as_str() != msgs::topics::CONTROL.name)
                .any(|t| at_work.iter().any(|o| o != name && ports(o).is_some_and(|q| q.publishes.contains(t))))
        })
    };
    let wave: Vec<String> = at_work.iter().filter(|n| !fed_by_others(n)).cloned().collect();
    if wave.is_empty() {
        at_work
    } else {
        wave
    }
}

/// Stops the running nodes `which` selects: stdin closed (a node waiting for `start`, or lingering
/// after its work, sees EOF and leaves), SIGTERM to those not done, SIGKILL after [`STOP_GRACE`].
fn stop_nodes(nodes: &mut [Running], which: impl Fn(&Running) -> bool) {
    for n in nodes.iter_mut().filter(|n| which(n)) {
        n.stdin.take();
        if n.exited.is_none() && !n.done {
            unsafe { libc::kill(n.child.id() as i32, libc::SIGTERM) };
        }
    }
    let deadline = Instant::now() + STOP_GRACE;
    loop {
        let mut alive = false;
        for n in nodes.iter_mut().filter(|n| n.exited.is_none() && which(n)) {
            match n.child.try_wait() {
                Ok(Some(s)) => n.exited = Some(s),
                _ => alive = true,
            }
        }
        if !alive {
            return;
        }
        if Instant::now() >= deadline {
            for n in nodes.iter_mut().filter(|n| n.exited.is_none() && which(n)) {
                tell!("[dc] node `{}` ignored SIGTERM for {STOP_GRACE:?}: killing it", n.spec.name);
                let _ = n.child.kill();
                n.exited = n.child.wait().ok();
            }
            return;
        }
        std::thread::sleep(STOP_POLL);
    }
}

/// Turns node `i`'s stdout into events: its handshake markers, and every other line (printed
/// after `prefix` when there is one).
fn read_stdout(
    i: usize,
    stdout: ChildStdout,
    prefix: Option<String>,
    watcher: Option<(String, LineWatcher)>,
    tx: mpsc::Sender<Event>,
) {
    let mut printing = true;
    for line in BufReader::new(stdout).lines().map_while(Result::ok) {
        let event = match line.as_str() {
            runtime::READY_MARKER => Event::Ready(i),
            runtime::CONNECTED_MARKER => Event::Connected(i),
            runtime::DONE_MARKER => Event::Done(i),
            _ => {
                // A closed stdout (`dc launch g.toml | head -3`) stops the printing, never the
                // graph: the lines still go to the watcher and the events.
                if let Some(p) = &prefix {
                    if printing && !runtime::try_print_line(&format!("{p} {line}")) {
                        printing = false;
                        tell!("[dc] standard output closed: node output is no longer printed");
                    }
                }
                if let Some((node, watch)) = &watcher {
                    watch(node, false, &line);
                }
                Event::Line(i, line)
            }
        };
        let _ = tx.send(event);
    }
}

/// Prints node `i`'s stderr lines after `prefix` and passes them on, then says it closed.
fn read_stderr(
    i: usize,
    stderr: ChildStderr,
    prefix: String,
    watcher: Option<(String, LineWatcher)>,
    tx: mpsc::Sender<Event>,
) {
    for line in BufReader::new(stderr).lines().map_while(Result::ok) {
        match &watcher {
            Some((node, watch)) => {
                watch(node, true, &line);
                if !routine_log_line(&line) {
                    tell!("{prefix} {line}");
                }
            }
            None => tell!("{prefix} {line}"),
        }
        let _ = tx.send(Event::ErrLine(i, line));
    }
    let _ = tx.send(Event::ErrClosed(i));
}

/// Children get SIGKILL when the launcher dies, so a killed `dc` leaves no orphans.
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
            Ok(())
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::process::ExitStatusExt;

    #[test]
    fn a_failed_nodes_error_is_quoted_from_its_last_error_line() {
        let tail = |lines: &[&str]| lines.iter().map(|l| l.to_string()).collect::<Vec<_>>();
        let t = tail(&["INFO ready", "error: a.mcap: No space left on device", "  while writing chunk 3"]);
        assert_eq!(error_said(t.iter()), ": error: a.mcap: No space left on device; while writing chunk 3");
        // The last error counts (an earlier one was recovered from).
        let t = tail(&["error: first", "INFO retried", "2026-12-01T00:00:00Z ERROR lost frames", ""]);
        assert_eq!(error_said(t.iter()), ": 2026-12-01T00:00:00Z ERROR lost frames");
        let t = tail(&["thread 'main' panicked at src/main.rs:3:5:", "attempt to divide by zero"]);
        assert!(error_said(t.iter()).ends_with("attempt to divide by zero"));
        assert_eq!(error_said(tail(&["INFO bye"]).iter()), "");
    }

    fn set(hosts: &[&str]) -> BTreeSet<String> {
        hosts.iter().map(|h| h.to_string()).collect()
    }

    fn strings(hosts: &[&str]) -> Vec<String> {
        hosts.iter().map(|h| h.to_string()).collect()
    }

    #[test]
    fn connect_waits_for_every_node_to_be_ready_or_finished() {
        use Phase::*;
        assert_eq!(barrier_step(Stage::Spawned, [(Ready, false), (Starting, false)]), BarrierStep::Hold);
        // A node that finished (or died) before its ports existed does not hold the others back.
        assert_eq!(barrier_step(Stage::Spawned, [(Ready, false), (Starting, true)]), BarrierStep::Connect);
        assert_eq!(barrier_step(Stage::Spawned, [(Connected, false), (Ready, false)]), BarrierStep::Connect);
        // Connected nodes alone do not start the graph before `connect` was said.
        assert_eq!(barrier_step(Stage::Spawned, [(Connected, false)]), BarrierStep::Connect);
    }

    #[test]
    fn start_waits_for_every_node_to_be_connected_or_finished() {
        use Phase::*;
        assert_eq!(barrier_step(Stage::Connecting, [(Connected, false), (Ready, false)]), BarrierStep::Hold);
        assert_eq!(barrier_step(Stage::Connecting, [(Connected, false), (Ready, true)]), BarrierStep::LocalConnected);
        assert_eq!(
            barrier_step(Stage::Connecting, [(Started, false), (Connected, false)]),
            BarrierStep::LocalConnected
        );
        // Once started, restarted nodes (back to Starting) do not move the barrier again.
        assert_eq!(barrier_step(Stage::Started, [(Started, false)]), BarrierStep::Hold);
        assert_eq!(barrier_step(Stage::Started, [(Starting, false)]), BarrierStep::Hold);
    }

    #[test]
    fn both_barriers_can_pass_in_one_round() {
        // As `advance_barrier` does: `connect`, then look again with the same phases.
        let phases = [(Phase::Connected, false), (Phase::Starting, true)];
        let mut stage = Stage::Spawned;
        if barrier_step(stage, phases) == BarrierStep::Connect {
            stage = Stage::Connecting;
        }
        assert_eq!(barrier_step(stage, phases), BarrierStep::LocalConnected);
    }

    #[test]
    fn the_hosts_gate_opens_when_every_host_with_nodes_is_connected_and_times_out() {
        let hosts = strings(&["a", "b", "c"]);
        let (t, timeout) = (Duration::from_secs(1), Duration::from_secs(10));
        assert_eq!(hosts_gate(&hosts, &set(&["a", "b", "c"]), t, timeout), HostsGate::Open);
        assert_eq!(hosts_gate(&hosts, &set(&["a", "c"]), t, timeout), HostsGate::Wait);
        assert_eq!(
            hosts_gate(&hosts, &set(&["a"]), Duration::from_secs(11), timeout),
            HostsGate::TimedOut(strings(&["b", "c"]))
        );
        // Only the hosts with nodes count; a launcher of another graph's host does not.
        assert_eq!(hosts_gate(&strings(&["a"]), &set(&["a", "z"]), Duration::from_secs(11), timeout), HostsGate::Open);
    }

    #[test]
    fn an_earlier_launcher_of_another_graph_or_of_this_host_is_a_claim() {
        let alive = |states: &[(&str, &str)]| -> BTreeSet<(String, String)> {
            states.iter().map(|(h, s)| (h.to_string(), s.to_string())).collect()
        };
        let graph = |id: u64, start: u128| format!("{GRAPH_STATE}-{id:016x}-{start}");
        // This graph's other host, and later arrivals of anything: no claim.
        let ok = alive(&[("b", &graph(7, 100)), ("c", &graph(9, 300)), ("a", CONNECTED)]);
        assert_eq!(earlier_claim(&ok, "a", 7, 200), None);
        // Another graph there first, on any host.
        let other = alive(&[("b", &graph(9, 100))]);
        let (host, what) = earlier_claim(&other, "a", 7, 200).unwrap();
        assert_eq!(host, "b");
        assert!(what.contains("another graph") && what.contains("0000000000000009"), "{what}");
        // This graph's launcher for this very host, there first.
        let twice = alive(&[("a", &graph(7, 100))]);
        assert!(earlier_claim(&twice, "a", 7, 200).unwrap().1.contains("started earlier"));
        // Our own token is not a claim on ourselves.
        assert_eq!(earlier_claim(&alive(&[("a", &graph(7, 200))]), "a", 7, 200), None);
    }

    #[test]
    fn hosts_in_picks_one_state() {
        let alive: BTreeSet<(String, String)> = [("a", CONNECTED), ("a", WORKING), ("b", WORKING)]
            .iter()
            .map(|(h, s)| (h.to_string(), s.to_string()))
            .collect();
        assert_eq!(hosts_in(&alive, CONNECTED), set(&["a"]));
        assert_eq!(hosts_in(&alive, WORKING), set(&["a", "b"]));
    }

    #[test]
    fn a_host_is_gone_when_its_launcher_goes_and_back_when_it_returns() {
        let mut w = HostWatch { with_nodes: strings(&["a", "b", "c"]), ..Default::default() };
        // First sight: no notice; this host (a) is never watched.
        assert_eq!(w.update("a", &set(&["b"])), vec![]);
        assert_eq!(w.update("a", &set(&["b", "c"])), vec![]);
        assert_eq!(w.seen, set(&["b", "c"]));
        assert_eq!(w.update("a", &set(&["c"])), vec![HostChange::Gone("b".into())]);
        // Gone once, not at every look.
        assert_eq!(w.update("a", &set(&["c"])), vec![]);
        assert_eq!(w.update("a", &set(&[])), vec![HostChange::Gone("c".into())]);
        assert_eq!(w.update("a", &set(&["b", "c"])), vec![HostChange::Back("b".into()), HostChange::Back("c".into())]);
        assert_eq!(w.update("a", &set(&["b", "c"])), vec![]);
        assert!(w.gone.is_empty());
    }

    #[test]
    fn a_host_never_seen_is_not_gone() {
        let mut w = HostWatch { with_nodes: strings(&["a", "b"]), ..Default::default() };
        assert_eq!(w.update("a", &set(&[])), vec![]);
        assert_eq!(w.update("a", &set(&["a"])), vec![]);
        assert!(w.seen.is_empty() && w.gone.is_empty());
    }

    #[test]
    fn a_failed_node_restarts_up_to_its_bound_then_stops_the_graph() {
        let policy = OnFailure::Restart { max: 2 };
        assert_eq!(failure_action(policy, 0), FailureAction::Restart { attempt: 1, max: 2 });
        assert_eq!(failure_action(policy, 1), FailureAction::Restart { attempt: 2, max: 2 });
        assert_eq!(failure_action(policy, 2), FailureAction::Exhausted { restarts: 2 });
        assert_eq!(failure_action(OnFailure::Restart { max: 0 }, 0), FailureAction::Exhausted { restarts: 0 });
        assert_eq!(failure_action(OnFailure::StopGraph, 0), FailureAction::StopGraph);
    }

    #[test]
    fn the_graph_is_done_when_its_workers_are_after_start() {
        // (daemon, finished)
        assert!(!workers_finished(false, [(false, true)]), "not before start");
        assert!(workers_finished(true, [(false, true), (true, false)]), "daemons do not count");
        assert!(!workers_finished(true, [(false, true), (false, false)]));
        // Daemons only: done at start (they are stopped).
        assert!(workers_finished(true, [(true, false)]));
    }

    #[test]
    fn producers_stop_before_their_consumers_and_readers_of_each_other_together() {
        let ports = |publishes: &[&str], subscribes: &[&str]| runtime::Ports {
            publishes: publishes.iter().map(|t| t.to_string()).collect(),
            subscribes: subscribes.iter().map(|t| t.to_string()).collect(),
        };
        let control = msgs::topics::CONTROL.name;
        let graph: BTreeMap<String, runtime::Ports> = [
            ("sph".to_string(), ports(&["grid"], &["bodies", control])),
            ("rec".to_string(), ports(&[], &["grid", "bodies", control])),
            ("ping".to_string(), ports(&["a"], &["b"])),
            ("pong".to_string(), ports(&["b"], &["a"])),
        ]
        .into();
        let wave = |at_work: &[&str]| next_wave(strings(at_work), |n| graph.get(n));
        // The simulator (publisher of `bodies`, and of `control` like every node) is done.
        assert_eq!(wave(&["sph", "rec"]), strings(&["sph"]));
        assert_eq!(wave(&["rec"]), strings(&["rec"]));
        assert_eq!(wave(&["ping", "pong"]), strings(&["ping", "pong"]));
        // A node of no known ports is fed by nobody.
        assert_eq!(wave(&["rec", "sph", "unknown"]), strings(&["sph", "unknown"]));
    }

    #[test]
    fn exit_statuses_are_described_and_signals_on_stop_are_no_failure() {
        let code = |c: i32| ExitStatus::from_raw(c << 8);
        let signal = |s: i32| ExitStatus::from_raw(s);
        assert_eq!(describe(code(1)), "exit status 1");
        assert_eq!(describe(signal(9)), "signal 9");
        assert!(failed_on_stop(code(3)));
        assert!(!failed_on_stop(code(0)));
        assert!(!failed_on_stop(signal(libc::SIGTERM)));
    }
}
