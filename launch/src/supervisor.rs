//! Starts one host's part of a graph as child processes, forwards their logs prefixed with the node
//! name, releases them together once every node's ports exist (on every host of the graph),
//! restarts nodes whose policy says so and tells the graph (control: node down / up), and stops
//! the whole graph on Ctrl-C or when a node fails.

use crate::graph::{Graph, NodeSpec, OnFailure};
use crate::plan::{self, Plan};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long nodes get to finish after SIGTERM before SIGKILL.
const STOP_GRACE: Duration = Duration::from_secs(5);
/// Knobs of a run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// How long a launcher waits for the other hosts' launchers to have their nodes connected.
    pub hosts_timeout: Duration,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions { hosts_timeout: Duration::from_secs(120) }
    }
}

/// How a graph run ended.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("node `{node}` exited with {status}")]
    NodeFailed { node: String, status: String },
    #[error("node `{node}` exited with {status} after {restarts} restarts (its bound): stopping the graph")]
    RestartsExhausted { node: String, status: String, restarts: u32 },
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
    #[error("host {missing} did not get its nodes connected within {secs} s (is `dc launch --host` running there, and can this host reach it?)")]
    HostsMissing { missing: String, secs: f64 },
}

/// Where captured node output goes.
pub enum Output {
    /// Print `[node] line` on our stdout / stderr.
    Forward,
    /// Keep every stdout line per node instead of printing it (for `dc bench`); stderr is
    /// still forwarded.
    Capture,
}

enum Event {
    Ready(usize),
    Connected(usize),
    /// The node finished its work and keeps its publishers alive until released.
    Done(usize),
    Line(usize, String),
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
}

impl Running {
    fn finished(&self) -> bool {
        self.done || self.exited.is_some()
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
                Some(runtime::open_router(endpoint).map_err(bus_err)?)
            }
            _ => None,
        };
        let name = plan::launcher_name(host);
        let node = runtime::Node::new(name.clone(), plan.bus(&name, host), false);
        let control = node.publisher(msgs::topics::CONTROL).map_err(|e| bus_err(e.to_string()))?;
        let sync = if plan.multi_host {
            let session = node.zenoh_session().map_err(|e| bus_err(e.to_string()))?;
            Some(runtime::HostSync::new(session, &format!("dc/{}/_launch", graph.namespace)).map_err(bus_err)?)
        } else {
            None
        };
        Ok(LauncherBus { control, sync, _node: node, _router: router })
    }

    /// Tells the graph that `node` went down or came back, with the topics it publishes.
    fn notice(&mut self, kind: msgs::ControlKind, node: &str, host: &str, publishes: &[String], status: &str) {
        let details = serde_json::json!({ "node": node, "host": host, "publishes": publishes, "status": status });
        let msg = msgs::ControlMsg::control(msgs::StepHeader::default(), kind, 0, &details.to_string());
        if let Err(e) = self.control.publish_frame(&msg) {
            tracing::warn!("could not publish the {kind:?} notice of `{node}`: {e}");
        }
    }
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
    let specs: Vec<NodeSpec> = graph.nodes_on(host).cloned().collect();
    if specs.is_empty() {
        return Err(RunError::NoNodes(host.to_string()));
    }
    match runtime::cleanup_stale_resources() {
        Ok(0) => {}
        Ok(n) => tracing::info!("cleaned shared-memory resources of {n} dead iceoryx2 nodes"),
        Err(e) => tracing::warn!("stale resource cleanup failed: {e}"),
    }
    let ports = plan::describe_ports(graph)?;
    let plan = Plan::new(graph, &ports);
    let mut bus = LauncherBus::open(graph, &plan, host)?;
    let (tx, rx) = mpsc::channel::<Event>();
    let width = specs.iter().map(|s| s.name.len()).max().unwrap_or(0);
    let forward = matches!(output, Output::Forward);
    let mut nodes: Vec<Running> = Vec::new();
    let mut report = RunReport::default();

    let spawn = |i: usize, spec: &NodeSpec| -> Result<(Child, Option<ChildStdin>), RunError> {
        let bus_json = serde_json::to_string(&plan.bus(&spec.name, host)).expect("bus config serialises");
        let mut cmd = Command::new(&spec.program);
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
        eprintln!("[dc] node `{}` started (pid {})", spec.name, child.id());
        let prefix = format!("[{:width$}]", spec.name);
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        let (tx_out, tx_err) = (tx.clone(), tx.clone());
        let p = prefix.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let event = match line.as_str() {
                    runtime::READY_MARKER => Event::Ready(i),
                    runtime::CONNECTED_MARKER => Event::Connected(i),
                    runtime::DONE_MARKER => Event::Done(i),
                    _ => {
                        if forward {
                            println!("{p} {line}");
                        }
                        Event::Line(i, line)
                    }
                };
                let _ = tx_out.send(event);
            }
        });
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{prefix} {line}");
            }
            drop(tx_err);
        });
        let stdin = child.stdin.take();
        Ok((child, stdin))
    };

    for (i, spec) in specs.iter().enumerate() {
        match spawn(i, spec) {
            Ok((child, stdin)) => {
                nodes.push(Running { spec: spec.clone(), child, stdin, exited: None, done: false, phase: Phase::Starting, restarts: 0 })
            }
            Err(e) => {
                stop_all(&mut nodes);
                return Err(e);
            }
        }
    }

    // Two barriers: every node's ports exist (ready) -> "connect"; every node attached its
    // subscribers (connected) -> "start". With several hosts, "start" waits for every host's
    // nodes to be connected, so no source publishes into a graph half there.
    let (mut connecting, mut started) = (false, false);
    let hosts_with_nodes: Vec<String> =
        graph.hosts.keys().filter(|h| graph.nodes_on(h).next().is_some()).cloned().collect();
    let barrier_since = Instant::now();
    // Other hosts seen running, and those that went away.
    let (mut seen_hosts, mut gone_hosts) = (BTreeSet::<String>::new(), BTreeSet::<String>::new());
    let mut working_declared = false;
    loop {
        // Drain events (handshake markers, captured lines) with a short wait, then look at exits.
        let mut first = rx.recv_timeout(Duration::from_millis(20)).ok();
        while let Some(ev) = first.take().or_else(|| rx.try_recv().ok()) {
            match ev {
                Event::Ready(i) => nodes[i].phase = nodes[i].phase.max(Phase::Ready),
                Event::Connected(i) => nodes[i].phase = nodes[i].phase.max(Phase::Connected),
                Event::Done(i) => nodes[i].done = true,
                Event::Line(i, line) => {
                    if matches!(output, Output::Capture) {
                        report.stdout.entry(nodes[i].spec.name.clone()).or_default().push(line);
                    }
                }
            }
        }
        if !connecting && nodes.iter().all(|n| n.phase >= Phase::Ready || n.finished()) {
            connecting = true;
            tell_all(&mut nodes, runtime::CONNECT_LINE);
        }
        if connecting && !started && nodes.iter().all(|n| n.phase >= Phase::Connected || n.finished()) {
            let all_hosts = match &mut bus.sync {
                None => true,
                Some(sync) => {
                    // `working` before `connected`: a host that sees us connected has seen that we
                    // have workers too (one session delivers in order), so it cannot mistake us
                    // for done and stop its daemons under our feet.
                    if !working_declared && specs.iter().any(|s| !s.daemon) {
                        sync.declare(host, "working").map_err(RunError::Bus)?;
                        working_declared = true;
                    }
                    sync.declare(host, "connected").map_err(RunError::Bus)?;
                    let alive = sync.alive();
                    let missing: Vec<&String> =
                        hosts_with_nodes.iter().filter(|h| !alive.contains(&((*h).clone(), "connected".to_string()))).collect();
                    if !missing.is_empty() && barrier_since.elapsed() > options.hosts_timeout {
                        stop_all(&mut nodes);
                        let missing = missing.iter().map(|h| format!("`{h}`")).collect::<Vec<_>>().join(", ");
                        return Err(RunError::HostsMissing { missing, secs: options.hosts_timeout.as_secs_f64() });
                    }
                    missing.is_empty()
                }
            };
            if all_hosts {
                started = true;
                tell_all(&mut nodes, runtime::START_LINE);
                for n in nodes.iter_mut() {
                    n.phase = n.phase.max(Phase::Started);
                }
                tracing::debug!("all {} nodes connected: started", nodes.len());
            }
        }
        // Another host whose launcher vanished (its liveliness went: killed, or unreachable past
        // zenoh's lease) takes its nodes with it: tell ours, so that a simulator stops waiting
        // for grids that cannot come. Back when its launcher is.
        if started {
            if let Some(sync) = &mut bus.sync {
                let alive: BTreeSet<String> =
                    sync.alive().iter().filter(|(_, state)| state == "connected").map(|(h, _)| h.clone()).collect();
                let mut notices = Vec::new();
                for h in hosts_with_nodes.iter().filter(|h| h.as_str() != host) {
                    match (seen_hosts.contains(h), alive.contains(h)) {
                        (true, false) => {
                            eprintln!("[dc] host `{h}` is gone: its nodes count as down");
                            seen_hosts.remove(h);
                            notices.push((msgs::ControlKind::NodeDown, h.clone()));
                        }
                        (false, true) => {
                            if gone_hosts.remove(h) {
                                eprintln!("[dc] host `{h}` is back");
                                notices.push((msgs::ControlKind::NodeUp, h.clone()));
                            }
                            seen_hosts.insert(h.clone());
                        }
                        _ => {}
                    }
                }
                for (kind, h) in notices {
                    if kind == msgs::ControlKind::NodeDown {
                        gone_hosts.insert(h.clone());
                    }
                    for node in graph.nodes_on(&h) {
                        let publishes = published(&plan, &node.name);
                        bus.notice(kind, &node.name, &h, &publishes, if kind == msgs::ControlKind::NodeDown { "host gone" } else { "host back" });
                    }
                }
            }
        }
        // A restarted node was told to connect and start at spawn; once connected it is back.
        for n in nodes.iter_mut().filter(|n| n.restarts > 0 && n.exited.is_none() && n.phase == Phase::Connected) {
            n.phase = Phase::Started;
            eprintln!("[dc] node `{}` is back (restart {})", n.spec.name, n.restarts);
            let publishes = published(&plan, &n.spec.name);
            bus.notice(msgs::ControlKind::NodeUp, &n.spec.name, host, &publishes, "running");
        }
        if interrupt.load(std::sync::atomic::Ordering::SeqCst) {
            eprintln!("[dc] interrupted: stopping the graph");
            stop_all(&mut nodes);
            return Err(RunError::Interrupted);
        }
        for i in 0..nodes.len() {
            if nodes[i].exited.is_some() {
                continue;
            }
            let Ok(Some(status)) = nodes[i].child.try_wait() else { continue };
            nodes[i].exited = Some(status);
            if status.success() {
                continue;
            }
            let name = nodes[i].spec.name.clone();
            let described = describe(status);
            // Its shared-memory ports must go at once: publishers would wait on its full queues.
            if let Err(e) = runtime::cleanup_stale_resources() {
                tracing::warn!("cleaning the dead node's resources: {e}");
            }
            let publishes = published(&plan, &name);
            match nodes[i].spec.on_failure {
                OnFailure::Restart { max } if nodes[i].restarts < max => {
                    nodes[i].restarts += 1;
                    eprintln!("[dc] node `{name}` exited with {described}: restarting it ({} of at most {max})", nodes[i].restarts);
                    bus.notice(msgs::ControlKind::NodeDown, &name, host, &publishes, &described);
                    let spec = nodes[i].spec.clone();
                    let (child, stdin) = match spawn(i, &spec) {
                        Ok(c) => c,
                        Err(e) => {
                            stop_all(&mut nodes);
                            return Err(e);
                        }
                    };
                    let n = &mut nodes[i];
                    (n.child, n.stdin, n.exited, n.done, n.phase) = (child, stdin, None, false, Phase::Starting);
                    report.restarts.insert(name, n.restarts);
                    // It reads these lines once its ports exist: the rest of the graph is running.
                    if connecting {
                        tell(n, runtime::CONNECT_LINE);
                    }
                    if started {
                        tell(n, runtime::START_LINE);
                    }
                }
                OnFailure::Restart { .. } => {
                    let restarts = nodes[i].restarts;
                    eprintln!("[dc] node `{name}` exited with {described} after {restarts} restarts: stopping the graph");
                    bus.notice(msgs::ControlKind::NodeDown, &name, host, &publishes, &described);
                    stop_all(&mut nodes);
                    drain_lines(&rx, &mut report, &nodes, &output);
                    return Err(RunError::RestartsExhausted { node: name, status: described, restarts });
                }
                OnFailure::StopGraph => {
                    eprintln!("[dc] node `{name}` exited with {described}: stopping the graph");
                    stop_all(&mut nodes);
                    drain_lines(&rx, &mut report, &nodes, &output);
                    return Err(RunError::NodeFailed { node: name, status: described });
                }
            }
        }
        let workers_done = started && nodes.iter().filter(|n| !n.spec.daemon).all(Running::finished);
        if workers_done && other_hosts_done(&mut bus, host, &mut working_declared) {
            // Daemons first (they drain what the finished workers sent, whose publishers are
            // still alive), then the lingering workers.
            stop_where(&mut nodes, |n| !n.done);
            stop_all(&mut nodes);
            drain_lines(&rx, &mut report, &nodes, &output);
            // A node that fails while being stopped is still a failure worth reporting.
            if let Some(n) = nodes.iter().find(|n| n.exited.is_some_and(|s| !s.success() && s.code().is_some())) {
                let status = describe(n.exited.unwrap());
                return Err(RunError::NodeFailed { node: n.spec.name.clone(), status });
            }
            return Ok(report);
        }
    }
}

/// On a graph of several hosts, this host's workers are done: say so and tell whether every
/// other host's are too (a host that disappeared loses its token and counts as done).
fn other_hosts_done(bus: &mut LauncherBus, host: &str, working_declared: &mut bool) -> bool {
    let Some(sync) = &mut bus.sync else { return true };
    if *working_declared {
        sync.withdraw(host, "working");
        *working_declared = false;
    }
    !sync.alive().iter().any(|(_, state)| state == "working")
}

/// The topics `node` publishes, for the down / up notices.
fn published(plan: &Plan, node: &str) -> Vec<String> {
    plan.members.iter().find(|m| m.name == node).map(|m| m.ports.publishes.iter().cloned().collect()).unwrap_or_default()
}

fn tell(n: &mut Running, line: &str) {
    if let Some(stdin) = &mut n.stdin {
        let _ = writeln!(stdin, "{line}").and_then(|_| stdin.flush());
    }
}

/// Writes a line to every running node's stdin.
fn tell_all(nodes: &mut [Running], line: &str) {
    for n in nodes.iter_mut().filter(|n| n.exited.is_none()) {
        if let Some(stdin) = &mut n.stdin {
            let _ = writeln!(stdin, "{line}").and_then(|_| stdin.flush());
        }
    }
}

fn drain_lines(rx: &mpsc::Receiver<Event>, report: &mut RunReport, nodes: &[Running], output: &Output) {
    // Reader threads finish once the children's pipes close.
    let deadline = Instant::now() + Duration::from_secs(2);
    while let Ok(ev) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        if let (Event::Line(i, line), Output::Capture) = (ev, output) {
            report.stdout.entry(nodes[i].spec.name.clone()).or_default().push(line);
        }
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

/// SIGTERM to every running node, then SIGKILL after the grace period.
fn stop_all(nodes: &mut [Running]) {
    stop_where(nodes, |_| true)
}

/// Stops the running nodes `which` selects: stdin closed (a node waiting for `start`, or lingering
/// after its work, sees EOF and leaves), SIGTERM to those not done, SIGKILL after the grace period.
fn stop_where(nodes: &mut [Running], which: impl Fn(&Running) -> bool) {
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
                eprintln!("[dc] node `{}` ignored SIGTERM for {STOP_GRACE:?}: killing it", n.spec.name);
                let _ = n.child.kill();
                n.exited = n.child.wait().ok();
            }
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
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
