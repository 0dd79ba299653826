//! Starts one host's part of a graph as child processes, forwards their logs prefixed with the node
//! name, releases them together once every node's ports exist, and stops the whole graph on Ctrl-C
//! or when a node fails.

use crate::graph::{Graph, NodeSpec};
use runtime::{BusConfig, ZenohConfig};
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long nodes get to finish after SIGTERM before SIGKILL.
const STOP_GRACE: Duration = Duration::from_secs(5);

/// How a graph run ended.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("node `{node}` exited with {status}")]
    NodeFailed { node: String, status: String },
    #[error("node `{node}` could not start: {what}")]
    Spawn { node: String, what: String },
    #[error("interrupted")]
    Interrupted,
    #[error("no node of the graph is placed on host `{0}`")]
    NoNodes(String),
}

/// Where captured node output goes.
pub enum Output {
    /// Print `[node] line` on our stdout / stderr.
    Forward,
    /// Keep every stdout line per node instead of printing it (for `dc bench`); stderr is
    /// still forwarded.
    Capture,
}

/// The bus configuration every node of `graph` on `host` receives, with zenoh endpoints assigned.
pub fn bus_configs(graph: &Graph, host: &str) -> BTreeMap<String, BusConfig> {
    // Every zenoh node listens on its own endpoint and connects to all others (a full mesh: since
    // zenoh 1.9 peers do not relay for third parties).
    let mut endpoints: BTreeMap<String, String> = BTreeMap::new();
    if graph.uses_zenoh() {
        for (h, spec) in &graph.hosts {
            for (i, node) in graph.nodes_on(h).enumerate() {
                let port = if spec.zenoh_port == 0 { free_port(&spec.address) } else { spec.zenoh_port + i as u16 };
                endpoints.insert(node.name.clone(), format!("tcp/{}:{port}", spec.address));
            }
        }
    }
    let mut out = BTreeMap::new();
    for node in graph.nodes_on(host) {
        let zenoh = match endpoints.get(&node.name) {
            Some(own) => ZenohConfig {
                listen: vec![own.clone()],
                connect: endpoints
                    .iter()
                    .filter(|(n, _)| *n != &node.name)
                    .map(|(_, e)| e.clone())
                    .chain(graph.hosts[host].zenoh_connect.iter().cloned())
                    .collect(),
                mode: None,
            },
            None => ZenohConfig::default(),
        };
        out.insert(
            node.name.clone(),
            BusConfig {
                namespace: graph.namespace.clone(),
                default_transport: runtime::Transport::Iceoryx2,
                topics: graph.topics.clone(),
                zenoh,
                queue_depth: graph.queue_depth,
            },
        );
    }
    out
}

fn free_port(address: &str) -> u16 {
    std::net::TcpListener::bind((address, 0))
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or(7447)
}

enum Event {
    Ready(usize),
    Connected(usize),
    /// The node finished its work and keeps its publishers alive until released.
    Done(usize),
    Line(usize, String),
}

struct Running {
    spec: NodeSpec,
    child: Child,
    stdin: Option<ChildStdin>,
    exited: Option<ExitStatus>,
    /// Said it is done (see [`runtime::DONE_MARKER`]); exits once its stdin closes.
    done: bool,
}

impl Running {
    fn finished(&self) -> bool {
        self.done || self.exited.is_some()
    }
}

/// What a finished run leaves: per node, its captured stdout lines (with [`Output::Capture`]).
#[derive(Debug, Default)]
pub struct RunReport {
    pub stdout: BTreeMap<String, Vec<String>>,
}

/// Runs the nodes of `graph` placed on `host` until they are all done (daemons are stopped when
/// the others are), a node fails, or `interrupt` fires.
pub fn run(
    graph: &Graph,
    host: &str,
    output: Output,
    interrupt: &std::sync::atomic::AtomicBool,
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
    let buses = bus_configs(graph, host);
    let (tx, rx) = mpsc::channel::<Event>();
    let width = specs.iter().map(|s| s.name.len()).max().unwrap_or(0);
    let mut nodes: Vec<Running> = Vec::new();
    let mut report = RunReport::default();

    for (i, spec) in specs.iter().enumerate() {
        let bus = serde_json::to_string(&buses[&spec.name]).expect("bus config serialises");
        let mut cmd = Command::new(&spec.program);
        cmd.args(&spec.args)
            .envs(&spec.env)
            .env("DC_NODE_NAME", &spec.name)
            .env("DC_BUS", bus)
            .env("DC_LAUNCHED", "1")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        die_with_parent(&mut cmd);
        let mut child = match cmd.spawn() {
            Ok(c) => c,
            Err(e) => {
                stop_all(&mut nodes);
                return Err(RunError::Spawn { node: spec.name.clone(), what: e.to_string() });
            }
        };
        let prefix = format!("[{:width$}]", spec.name);
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        let (tx_out, tx_err) = (tx.clone(), tx.clone());
        let p = prefix.clone();
        let forward = matches!(output, Output::Forward);
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if line == runtime::READY_MARKER {
                    let _ = tx_out.send(Event::Ready(i));
                } else if line == runtime::CONNECTED_MARKER {
                    let _ = tx_out.send(Event::Connected(i));
                } else if line == runtime::DONE_MARKER {
                    let _ = tx_out.send(Event::Done(i));
                } else {
                    if forward {
                        println!("{p} {line}");
                    }
                    let _ = tx_out.send(Event::Line(i, line));
                }
            }
        });
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{prefix} {line}");
            }
            drop(tx_err);
        });
        let stdin = child.stdin.take();
        nodes.push(Running { spec: spec.clone(), child, stdin, exited: None, done: false });
    }
    drop(tx);

    // Two barriers: every node's ports exist (ready) -> "connect"; every node attached its
    // subscribers (connected) -> "start".
    let mut ready = vec![false; nodes.len()];
    let mut connected = vec![false; nodes.len()];
    let (mut connecting, mut started) = (false, false);
    let capture = |report: &mut RunReport, i: usize, line: String, nodes: &[Running]| {
        if matches!(output, Output::Capture) {
            report.stdout.entry(nodes[i].spec.name.clone()).or_default().push(line);
        }
    };
    loop {
        // Drain events (ready markers, captured lines) with a short wait, then look at exits.
        let mut first = rx.recv_timeout(Duration::from_millis(20)).ok();
        while let Some(ev) = first.take().or_else(|| rx.try_recv().ok()) {
            match ev {
                Event::Ready(i) => ready[i] = true,
                Event::Connected(i) => connected[i] = true,
                Event::Done(i) => nodes[i].done = true,
                Event::Line(i, line) => capture(&mut report, i, line, &nodes),
            }
        }
        if !connecting && ready.iter().zip(&nodes).all(|(r, n)| *r || n.finished()) {
            connecting = true;
            tell_all(&mut nodes, runtime::CONNECT_LINE);
        }
        if connecting && !started && connected.iter().zip(&nodes).all(|(c, n)| *c || n.finished()) {
            started = true;
            tell_all(&mut nodes, runtime::START_LINE);
            tracing::debug!("all {} nodes connected: started", nodes.len());
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
            if let Ok(Some(status)) = nodes[i].child.try_wait() {
                nodes[i].exited = Some(status);
                if !status.success() {
                    let name = nodes[i].spec.name.clone();
                    let status = describe(status);
                    eprintln!("[dc] node `{name}` exited with {status}: stopping the graph");
                    stop_all(&mut nodes);
                    drain_lines(&rx, &mut report, &nodes, &output);
                    return Err(RunError::NodeFailed { node: name, status });
                }
            }
        }
        let workers_done = nodes.iter().filter(|n| !n.spec.daemon).all(Running::finished);
        if workers_done {
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
