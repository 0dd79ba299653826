//! Launch files: a TOML graph of nodes placed on hosts, and the checks that run before anything
//! starts. Every error names the file, the line and what is wrong.
//!
//! ```toml
//! [graph]
//! name = "demo"              # also the bus namespace unless `namespace` is given
//!
//! [hosts.local]              # optional for one-host graphs
//! address = "127.0.0.1"      # where this host's zenoh endpoints listen
//! zenoh_port = 0             # first port for this host's nodes; 0 (one host): the launcher's router
//!
//! [topics]                   # transport per topic; default iceoryx2 (same host)
//! "bench/bodies" = "zenoh"
//!
//! [qos]                      # delivery per topic: "reliable" (default) or "best-effort"
//! "bodies" = "best-effort"   # a reader that falls behind loses old frames, never slows writers
//!
//! [security]                 # optional: TLS on every zenoh link (PEM files, relative to this file)
//! ca = "certs/ca.pem"        # the CA that signs every host's certificate
//! cert = "certs/{host}.pem"  # `{host}` becomes each host's name
//! key = "certs/{host}.key"
//! mutual = true              # default: both ends of a link show a certificate
//!
//! [[nodes]]
//! name = "source"
//! binary = "dc-bench-bus"
//! host = "local"             # optional for one-host graphs
//! daemon = false             # daemons run until the other nodes are done, then are stopped
//! on_failure = "stop-graph"  # or "restart" (at most `max_restarts` times, default 3)
//! params = { role = "source", count = 100 }
//! ```
//!
//! Topics need no `[topics]` entry: the launcher asks every node which topics it publishes and
//! subscribes (`DC_DESCRIBE=1`) and routes each one over iceoryx2 within a host and over zenoh
//! between hosts (both, when a topic has readers on its own host and on others). `[topics]`
//! forces a transport for every port of a topic (benchmarks: everything over zenoh).
//!
//! Several hosts: every host gives `address` and a `zenoh_port` (its zenoh endpoints are
//! `tcp/<address>:<zenoh_port + i>`, the same on every machine reading the file), or one host is
//! the zenoh `router = true` (at `tcp/<address>:<zenoh_port>`) that every node connects to.

use runtime::Transport;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// Host used when a launch file names none.
pub const DEFAULT_HOST: &str = "local";
/// Queue depth per subscriber unless the file says otherwise.
const DEFAULT_QUEUE_DEPTH: usize = 16;

/// A problem in a launch file, located by line.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    pub line: usize,
    pub message: String,
}

/// Why a launch file was refused.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error("{file}: cannot read: {source}")]
    Read { file: String, source: std::io::Error },
    #[error("{}", render_problems(file, problems))]
    Invalid { file: String, problems: Vec<Problem> },
}

fn render_problems(file: &str, problems: &[Problem]) -> String {
    problems
        .iter()
        .map(|p| match p.line {
            // A graph built in code has no lines.
            0 => format!("{file}: {}", p.message),
            line => format!("{file}:{line}: {}", p.message),
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    graph: RawGraph,
    #[serde(default)]
    hosts: BTreeMap<String, Spanned<RawHost>>,
    #[serde(default)]
    topics: BTreeMap<Spanned<String>, Spanned<String>>,
    #[serde(default)]
    qos: BTreeMap<Spanned<String>, Spanned<String>>,
    #[serde(default)]
    security: Option<Spanned<RawSecurity>>,
    #[serde(default)]
    nodes: Vec<Spanned<RawNode>>,
}

#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
struct RawSecurity {
    ca: String,
    cert: String,
    key: String,
    #[serde(default = "yes")]
    mutual: bool,
}

fn yes() -> bool {
    true
}

/// TLS on every zenoh link of a graph (`[security]`): the CA, and per host its certificate and key
/// (absolute paths, `{host}` already replaced).
#[derive(Debug, Clone, PartialEq)]
pub struct Security {
    pub ca: PathBuf,
    pub certs: BTreeMap<String, (PathBuf, PathBuf)>,
    pub mutual: bool,
}

impl Security {
    /// The TLS files of `host`'s nodes and launcher.
    pub fn of_host(&self, host: &str) -> Option<runtime::TlsConfig> {
        let (cert, key) = self.certs.get(host)?;
        let text = |p: &Path| p.display().to_string();
        Some(runtime::TlsConfig { ca: text(&self.ca), cert: text(cert), key: text(key), mutual: self.mutual })
    }
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawGraph {
    name: Option<String>,
    namespace: Option<String>,
    /// Queue depth per subscriber.
    queue_depth: Option<usize>,
}

#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
struct RawHost {
    #[serde(default = "default_address")]
    address: String,
    #[serde(default)]
    zenoh_port: u16,
    /// Extra zenoh endpoints to connect to (e.g. a router).
    #[serde(default)]
    zenoh_connect: Vec<String>,
    /// This host's launcher runs the graph's zenoh router; every node connects to it.
    #[serde(default)]
    router: bool,
}

fn default_address() -> String {
    "127.0.0.1".to_string()
}

/// The host of a graph that names none: `local`, on loopback, free ports.
fn default_host() -> Host {
    Host { name: DEFAULT_HOST.into(), address: default_address(), zenoh_port: 0, zenoh_connect: vec![], router: false }
}

/// What is wrong with a node name, if anything.
fn name_problem(label: &str) -> Option<String> {
    let ok = !label.is_empty() && label.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    (!ok).then(|| format!("node name `{label}` must be non-empty letters, digits, `-` or `_`"))
}

/// Finds node `label`'s binary, or says why not.
fn resolve_binary(label: &str, binary: &str) -> Result<PathBuf, String> {
    find_binary(binary).ok_or_else(|| {
        format!("node `{label}`: unknown node binary `{binary}` (not beside dc nor on PATH; was it built?)")
    })
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNode {
    name: Option<Spanned<String>>,
    binary: Option<Spanned<String>>,
    host: Option<Spanned<String>>,
    #[serde(default)]
    daemon: bool,
    on_failure: Option<Spanned<String>>,
    max_restarts: Option<u32>,
    #[serde(default)]
    params: toml::Table,
    #[serde(default)]
    env: BTreeMap<String, String>,
}

/// One host of a graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Host {
    pub name: String,
    pub address: String,
    pub zenoh_port: u16,
    pub zenoh_connect: Vec<String>,
    pub router: bool,
}

/// What the launcher does when a node exits with a failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OnFailure {
    /// Stop every node of the graph (on this host) and report the failure.
    #[default]
    StopGraph,
    /// Start the node again, at most `max` times over the run.
    Restart { max: u32 },
}

/// One node of a graph, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSpec {
    pub name: String,
    /// The binary as written in the file.
    pub binary: String,
    /// The binary found on disk.
    pub program: PathBuf,
    pub host: String,
    pub daemon: bool,
    pub on_failure: OnFailure,
    /// Command-line arguments built from the parameters.
    pub args: Vec<String>,
    pub env: BTreeMap<String, String>,
    pub line: usize,
}

impl NodeSpec {
    /// A node built in code, for [`Graph::single_host`] (which finds its binary): on the default
    /// host, stopping the graph when it fails, run with `args`.
    pub fn new(name: impl Into<String>, binary: impl Into<String>, daemon: bool, args: Vec<String>) -> NodeSpec {
        NodeSpec {
            name: name.into(),
            binary: binary.into(),
            program: PathBuf::new(),
            host: DEFAULT_HOST.into(),
            daemon,
            on_failure: OnFailure::default(),
            args,
            env: BTreeMap::new(),
            line: 0,
        }
    }

    /// The node with environment variable `key` set to `value`.
    pub fn with_env(mut self, key: impl Into<String>, value: impl Into<String>) -> NodeSpec {
        self.env.insert(key.into(), value.into());
        self
    }
}

/// A checked graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Graph {
    pub file: String,
    pub name: String,
    pub namespace: String,
    pub queue_depth: usize,
    pub hosts: BTreeMap<String, Host>,
    pub topics: BTreeMap<String, Transport>,
    /// Topics delivered best effort (`[qos]`); the others are reliable.
    pub best_effort: std::collections::BTreeSet<String>,
    /// TLS on every zenoh link (`[security]`).
    pub security: Option<Security>,
    pub nodes: Vec<NodeSpec>,
}

/// Why a node refused its parameters, on one line: clap's message without its usage and help
/// footer; a node that crashed instead (a panic, an abort, a signal) is said to have crashed,
/// with its message and without the backtrace or notes that follow it.
fn refusal(status: std::process::ExitStatus, stderr: &str) -> String {
    let msg = stderr
        .lines()
        .take_while(|l| {
            !l.starts_with("Usage:") && !l.starts_with("For more information") && !l.starts_with("stack backtrace:")
        })
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("note: "))
        .collect::<Vec<_>>()
        .join(" ");
    let msg = msg.trim_start_matches("error: ");
    // 101: a Rust panic; no code: killed by a signal (an allocation failure aborts).
    match status.code() {
        Some(101) | None => format!("crashed while checking its parameters ({status}): {msg}"),
        Some(_) => format!("bad parameters: {msg}"),
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// Turns a parameter table into `--key=value` arguments (`true` -> `--key`, `false` -> nothing,
/// arrays -> the flag repeated).
pub fn params_to_args(params: &toml::Table) -> Result<Vec<String>, String> {
    let mut args = Vec::new();
    for (key, value) in params {
        let mut push = |v: &toml::Value| -> Result<(), String> {
            match v {
                toml::Value::Boolean(true) => args.push(format!("--{key}")),
                toml::Value::Boolean(false) => {}
                toml::Value::String(s) => args.push(format!("--{key}={s}")),
                toml::Value::Integer(i) => args.push(format!("--{key}={i}")),
                toml::Value::Float(f) => args.push(format!("--{key}={f}")),
                other => return Err(format!("parameter `{key}`: unsupported value {other}")),
            }
            Ok(())
        };
        match value {
            toml::Value::Array(items) => items.iter().try_for_each(&mut push)?,
            v => push(v)?,
        }
    }
    Ok(args)
}

/// Finds a node binary: next to the running `dc` first (a cargo target dir), then on `PATH`.
pub fn find_binary(name: &str) -> Option<PathBuf> {
    let direct = Path::new(name);
    if direct.components().count() > 1 {
        return direct.is_file().then(|| direct.to_path_buf());
    }
    let beside = std::env::current_exe().ok().and_then(|exe| exe.parent().map(|d| d.join(name)));
    if let Some(p) = beside.filter(|p| p.is_file()) {
        return Some(p);
    }
    std::env::var_os("PATH").and_then(|paths| std::env::split_paths(&paths).map(|d| d.join(name)).find(|p| p.is_file()))
}

impl Graph {
    /// Reads and checks a launch file. Parameter checks that need the node binaries run in
    /// [`Graph::check_params`].
    pub fn load(path: &Path) -> Result<Graph, GraphError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| GraphError::Read { file: file.clone(), source })?;
        Graph::parse(&file, &text)
    }

    /// Parses and checks launch-file text; `file` names it in errors.
    pub fn parse(file: &str, text: &str) -> Result<Graph, GraphError> {
        let invalid = |problems| GraphError::Invalid { file: file.to_string(), problems };
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start)).unwrap_or(1);
            invalid(vec![Problem { line, message: e.message().trim().to_string() }])
        })?;
        let mut problems = Vec::new();
        let mut problem =
            |offset: usize, message: String| problems.push(Problem { line: line_of(text, offset), message });

        let name = raw.graph.name.clone().unwrap_or_else(|| {
            Path::new(file).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
        });
        let namespace = raw.graph.namespace.clone().unwrap_or_else(|| name.clone());
        if let Err(why) = runtime::check_namespace(&namespace) {
            let what = if raw.graph.namespace.is_some() { "namespace" } else { "name (the bus namespace)" };
            problem(text.find("[graph]").unwrap_or(0), format!("graph {what}: {why}"));
        }

        let mut hosts = BTreeMap::new();
        for (host_name, spanned) in &raw.hosts {
            let h = spanned.get_ref();
            hosts.insert(
                host_name.clone(),
                Host {
                    name: host_name.clone(),
                    address: h.address.clone(),
                    zenoh_port: h.zenoh_port,
                    zenoh_connect: h.zenoh_connect.clone(),
                    router: h.router,
                },
            );
        }
        if hosts.is_empty() {
            hosts.insert(DEFAULT_HOST.to_string(), default_host());
        }
        let routers: Vec<_> = raw.hosts.iter().filter(|(_, h)| h.get_ref().router).collect();
        if routers.len() > 1 {
            problem(
                routers[1].1.span().start,
                format!(
                    "hosts `{}` and `{}` both say `router = true`: a graph has one zenoh router",
                    routers[0].0, routers[1].0
                ),
            );
        }
        if raw.hosts.len() > 1 {
            // Every machine computes the same endpoints from the file, so ports cannot be picked
            // at random: each host needs its first port (only the router's, with a router).
            for (name, h) in &raw.hosts {
                let needs_port = if routers.is_empty() { true } else { h.get_ref().router };
                if needs_port && h.get_ref().zenoh_port == 0 {
                    problem(h.span().start, format!("host `{name}`: a graph with several hosts needs `zenoh_port` (its zenoh endpoints must be known to the other hosts)"));
                }
            }
        }

        let mut topics = BTreeMap::new();
        for (topic, transport) in &raw.topics {
            if msgs::topics::info(topic.get_ref()).is_none() {
                problem(
                    topic.span().start,
                    format!("unknown topic `{}` (known: {})", topic.get_ref(), msgs::topics::names_list()),
                );
            }
            match transport.get_ref().as_str() {
                "iceoryx2" => topics.insert(topic.get_ref().clone(), Transport::Iceoryx2),
                "zenoh" => topics.insert(topic.get_ref().clone(), Transport::Zenoh),
                "both" => topics.insert(topic.get_ref().clone(), Transport::Both),
                other => {
                    problem(
                        transport.span().start,
                        format!("topic `{}`: unknown transport `{other}` (iceoryx2, zenoh or both)", topic.get_ref()),
                    );
                    None
                }
            };
        }
        let security = raw.security.as_ref().and_then(|sec| {
            let at = sec.span().start;
            let r = sec.get_ref();
            let base = Path::new(file).parent().unwrap_or(Path::new("."));
            let resolve = |p: &str, host: &str| -> PathBuf {
                let p = PathBuf::from(p.replace("{host}", host));
                if p.is_absolute() {
                    p
                } else {
                    base.join(p)
                }
            };
            let mut missing = Vec::new();
            let ca = resolve(&r.ca, "");
            let mut certs = BTreeMap::new();
            for host in hosts.keys() {
                let (cert, key) = (resolve(&r.cert, host), resolve(&r.key, host));
                missing
                    .extend([&ca, &cert, &key].into_iter().filter(|p| !p.is_file()).map(|p| p.display().to_string()));
                certs.insert(host.clone(), (cert, key));
            }
            missing.sort();
            missing.dedup();
            if missing.is_empty() {
                Some(Security { ca, certs, mutual: r.mutual })
            } else {
                problem(
                    at,
                    format!("[security]: no such file: {} (scripts/make-certs.sh makes a test CA)", missing.join(", ")),
                );
                None
            }
        });
        let mut best_effort = std::collections::BTreeSet::new();
        for (topic, qos) in &raw.qos {
            if msgs::topics::info(topic.get_ref()).is_none() {
                problem(
                    topic.span().start,
                    format!("[qos]: unknown topic `{}` (known: {})", topic.get_ref(), msgs::topics::names_list()),
                );
            }
            match qos.get_ref().as_str() {
                "reliable" => {}
                "best-effort" => {
                    best_effort.insert(topic.get_ref().clone());
                }
                other => problem(
                    qos.span().start,
                    format!("[qos] topic `{}`: unknown delivery `{other}` (reliable or best-effort)", topic.get_ref()),
                ),
            }
        }

        let mut nodes: Vec<NodeSpec> = Vec::new();
        let mut seen: BTreeMap<String, usize> = BTreeMap::new();
        if raw.nodes.is_empty() {
            problem(0, "the graph has no nodes ([[nodes]] tables)".into());
        }
        for spanned in &raw.nodes {
            let start = spanned.span().start;
            let line = line_of(text, start);
            let node = spanned.get_ref();
            let Some(node_name) = &node.name else {
                problem(start, "node without a `name`".into());
                continue;
            };
            let label = node_name.get_ref().clone();
            if let Some(why) = name_problem(&label) {
                problem(node_name.span().start, why);
            }
            if let Some(first) = seen.insert(label.clone(), line) {
                problem(
                    node_name.span().start,
                    format!("duplicate node name `{label}` (first defined on line {first})"),
                );
            }
            let host = match &node.host {
                Some(h) if hosts.contains_key(h.get_ref()) => h.get_ref().clone(),
                Some(h) => {
                    problem(
                        h.span().start,
                        format!(
                            "node `{label}`: unknown host `{}` (hosts: {})",
                            h.get_ref(),
                            hosts.keys().cloned().collect::<Vec<_>>().join(", ")
                        ),
                    );
                    continue;
                }
                None if hosts.len() == 1 => hosts.keys().next().cloned().unwrap_or_default(),
                None => {
                    problem(start, format!("node `{label}`: `host` is required when the graph has several hosts"));
                    continue;
                }
            };
            let Some(binary) = &node.binary else {
                problem(start, format!("node `{label}`: missing `binary`"));
                continue;
            };
            let program = match resolve_binary(&label, binary.get_ref()) {
                Ok(p) => p,
                Err(why) => {
                    problem(binary.span().start, why);
                    continue;
                }
            };
            let on_failure = match (node.on_failure.as_ref().map(|p| p.get_ref().as_str()), node.max_restarts) {
                (None | Some("stop-graph"), None) => OnFailure::StopGraph,
                (Some("restart"), max) => OnFailure::Restart { max: max.unwrap_or(3) },
                (None | Some("stop-graph"), Some(_)) => {
                    problem(start, format!("node `{label}`: `max_restarts` needs `on_failure = \"restart\"`"));
                    continue;
                }
                (Some(other), _) => {
                    let at = node.on_failure.as_ref().map(|p| p.span().start).unwrap_or(start);
                    problem(at, format!("node `{label}`: unknown on_failure `{other}` (stop-graph or restart)"));
                    continue;
                }
            };
            let args = match params_to_args(&node.params) {
                Ok(a) => a,
                Err(e) => {
                    problem(start, format!("node `{label}`: {e}"));
                    continue;
                }
            };
            nodes.push(NodeSpec {
                name: label,
                binary: binary.get_ref().clone(),
                program,
                host,
                daemon: node.daemon,
                on_failure,
                args,
                env: node.env.clone(),
                line,
            });
        }
        if !nodes.is_empty() && nodes.iter().all(|n| n.daemon) {
            // Daemons are stopped once the workers finish: with none, the graph would start,
            // stop at once and exit 0 having done nothing.
            problem(
                0,
                "every node is a daemon, so none does work and the graph would stop at once \
                        (make at least one node `daemon = false`)"
                    .into(),
            );
        }
        if !problems.is_empty() {
            problems.sort_by_key(|p| p.line);
            return Err(invalid(problems));
        }
        Ok(Graph {
            file: file.to_string(),
            name,
            namespace,
            queue_depth: raw.graph.queue_depth.unwrap_or(DEFAULT_QUEUE_DEPTH),
            hosts,
            topics,
            best_effort,
            security,
            nodes,
        })
    }

    /// The scheme of the graph's zenoh endpoints: `tls` when `[security]` is given, else `tcp`.
    pub fn link_scheme(&self) -> &'static str {
        if self.security.is_some() {
            "tls"
        } else {
            "tcp"
        }
    }

    /// A graph built in code (`dc eval`, `dc bench`) rather than read from a file: every node on
    /// the one default host (loopback, free ports), named `<name>` in messages. The nodes get a
    /// launch file's checks: valid and unique names, binaries found beside dc or on PATH (every
    /// problem is reported at once). Parameters are checked by [`Graph::check_params`].
    pub fn single_host(name: &str, namespace: &str, nodes: Vec<NodeSpec>) -> Result<Graph, GraphError> {
        let file = format!("<{name}>");
        let mut problems = Vec::new();
        let mut problem = |message: String| problems.push(Problem { line: 0, message });
        let mut seen = std::collections::BTreeSet::new();
        let mut checked = Vec::with_capacity(nodes.len());
        for mut node in nodes {
            if let Some(why) = name_problem(&node.name) {
                problem(why);
            }
            if !seen.insert(node.name.clone()) {
                problem(format!("duplicate node name `{}`", node.name));
            }
            if node.host != DEFAULT_HOST {
                problem(format!("node `{}`: unknown host `{}` (hosts: {DEFAULT_HOST})", node.name, node.host));
                continue;
            }
            match resolve_binary(&node.name, &node.binary) {
                Ok(program) => node.program = program,
                Err(why) => {
                    problem(why);
                    continue;
                }
            }
            checked.push(node);
        }
        if !problems.is_empty() {
            return Err(GraphError::Invalid { file, problems });
        }
        Ok(Graph {
            file,
            name: name.to_string(),
            namespace: namespace.to_string(),
            queue_depth: DEFAULT_QUEUE_DEPTH,
            hosts: [(DEFAULT_HOST.to_string(), default_host())].into(),
            topics: BTreeMap::new(),
            best_effort: Default::default(),
            security: None,
            nodes: checked,
        })
    }

    /// Asks each node binary whether it accepts its parameters (`DC_VALIDATE=1`), so that a
    /// missing, unknown or ill-typed parameter fails before anything starts.
    pub fn check_params(&self) -> Result<(), GraphError> {
        let mut problems = Vec::new();
        for node in &self.nodes {
            let out = std::process::Command::new(&node.program)
                .args(&node.args)
                .env("DC_VALIDATE", "1")
                // A node that crashes while checking says why in a line, not a backtrace.
                .env("RUST_BACKTRACE", "0")
                .stdin(std::process::Stdio::null())
                .output();
            match out {
                Ok(o) if o.status.success() => {}
                Ok(o) => problems.push(Problem {
                    line: node.line,
                    message: format!(
                        "node `{}` ({}): {}",
                        node.name,
                        node.binary,
                        refusal(o.status, &String::from_utf8_lossy(&o.stderr))
                    ),
                }),
                Err(e) => problems.push(Problem {
                    line: node.line,
                    message: format!("node `{}`: cannot run `{}`: {e}", node.name, node.program.display()),
                }),
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(GraphError::Invalid { file: self.file.clone(), problems })
        }
    }

    /// Nodes placed on `host`.
    pub fn nodes_on<'a>(&'a self, host: &'a str) -> impl Iterator<Item = &'a NodeSpec> + 'a {
        self.nodes.iter().filter(move |n| n.host == host)
    }

    /// Whether any topic travels over zenoh (then every node gets a zenoh endpoint).
    pub fn uses_zenoh(&self) -> bool {
        self.hosts.len() > 1 || self.topics.values().any(|t| t.uses_zenoh())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problems(text: &str) -> Vec<Problem> {
        match Graph::parse("g.toml", text) {
            Err(GraphError::Invalid { problems, .. }) => problems,
            other => panic!("expected problems, got {other:?}"),
        }
    }

    #[test]
    fn params_become_flags() {
        let t: toml::Table = toml::from_str("a = 1\nb = true\nc = false\nd = 'x'\ne = [1, 2]\nf = 0.5").unwrap();
        assert_eq!(params_to_args(&t).unwrap(), ["--a=1", "--b", "--d=x", "--e=1", "--e=2", "--f=0.5"]);
    }

    #[test]
    fn a_graph_name_that_cannot_name_a_bus_is_refused_by_the_check() {
        let long = format!("[graph]\nname = \"{}\"\n[[nodes]]\nname = 'a'\nbinary = 'sh'\n", "g".repeat(5000));
        let p = problems(&long);
        assert!(p.iter().any(|p| p.line == 1 && p.message.contains("5000 bytes")), "{p:?}");
        let p = problems("[graph]\nname = \"grafo-ñ\"\n[[nodes]]\nname = 'a'\nbinary = 'sh'\n");
        assert!(p.iter().any(|p| p.message.contains("`ñ` is not allowed")), "{p:?}");
        let p = problems("[graph]\nname = \"ok\"\nnamespace = \"a/b\"\n[[nodes]]\nname = 'a'\nbinary = 'sh'\n");
        assert!(p.iter().any(|p| p.message.contains("graph namespace")), "{p:?}");
    }

    #[test]
    fn syntax_error_names_the_line() {
        let p = problems("[graph]\nname = \"x\"\n[[nodes]]\nname = = 3\n");
        assert_eq!(p[0].line, 4, "{p:?}");
    }

    #[test]
    fn unknown_binary_host_and_duplicate_names_are_reported_with_lines() {
        let text = r#"
[hosts.a]
[hosts.b]

[[nodes]]
name = "x"
binary = "dc-no-such-binary"
host = "a"

[[nodes]]
name = "x"
binary = "dc-no-such-binary"
host = "c"
"#;
        let p = problems(text);
        let messages: Vec<_> = p.iter().map(|p| (p.line, p.message.as_str())).collect();
        assert!(
            messages.iter().any(|(l, m)| *l == 7 && m.contains("unknown node binary `dc-no-such-binary`")),
            "{messages:?}"
        );
        assert!(messages.iter().any(|(l, m)| *l == 11 && m.contains("duplicate node name `x`")), "{messages:?}");
        assert!(messages.iter().any(|(l, m)| *l == 13 && m.contains("unknown host `c`")), "{messages:?}");
    }

    #[test]
    fn unknown_topic_and_transport_are_reported() {
        let p = problems(
            "[topics]\n\"bodies\" = \"carrier-pigeon\"\n\"nope\" = \"zenoh\"\n[[nodes]]\nname='a'\nbinary='sh'\n",
        );
        assert!(p.iter().any(|p| p.line == 2 && p.message.contains("unknown transport")), "{p:?}");
        assert!(p.iter().any(|p| p.line == 3 && p.message.contains("unknown topic `nope`")), "{p:?}");
    }

    #[test]
    fn unknown_keys_are_refused() {
        let p = problems("[[nodes]]\nname='a'\nbinary='sh'\nparmas = {}\n");
        assert!(p[0].message.contains("parmas"), "{p:?}");
    }

    #[test]
    fn a_graph_built_in_code_gets_the_checks_of_a_file() {
        let g = Graph::single_host(
            "demo",
            "demo-1",
            vec![NodeSpec::new("a", "sh", false, vec!["-c".into(), "true".into()]).with_env("K", "v")],
        )
        .unwrap();
        assert_eq!((g.file.as_str(), g.name.as_str(), g.namespace.as_str()), ("<demo>", "demo", "demo-1"));
        assert_eq!(g.hosts.keys().collect::<Vec<_>>(), [DEFAULT_HOST]);
        assert_eq!(g.nodes_on(DEFAULT_HOST).count(), 1);
        assert!(g.nodes[0].program.is_file(), "{:?}", g.nodes[0].program);
        assert_eq!(g.nodes[0].env["K"], "v");
        assert_eq!(g.nodes[0].on_failure, OnFailure::StopGraph);

        let nodes = vec![
            NodeSpec::new("a", "sh", false, vec![]),
            NodeSpec::new("a", "dc-no-such-binary", true, vec![]),
            NodeSpec::new("b c", "sh", false, vec![]),
        ];
        let err = Graph::single_host("demo", "demo", nodes).unwrap_err().to_string();
        assert!(err.contains("<demo>: duplicate node name `a`"), "{err}");
        assert!(err.contains("<demo>: node `a`: unknown node binary `dc-no-such-binary`"), "{err}");
        assert!(err.contains("<demo>: node name `b c` must be"), "{err}");
    }

    #[test]
    fn a_node_that_crashes_while_checking_is_said_to_have_crashed_without_a_backtrace() {
        use std::os::unix::process::ExitStatusExt;
        let usage = "error: invalid value 'x' for '--n <N>'\n\nUsage: dc-sim [OPTIONS]\n\nFor more information, try '--help'.\n";
        assert_eq!(
            refusal(std::process::ExitStatus::from_raw(2 << 8), usage),
            "bad parameters: invalid value 'x' for '--n <N>'"
        );
        let panic = "\nthread 'main' (7) panicked at src/scene.rs:297:72:\nattempt to multiply with overflow\n\
                     stack backtrace:\n   0: __rustc::rust_begin_unwind\nnote: Some details are omitted\n";
        let m = refusal(std::process::ExitStatus::from_raw(101 << 8), panic);
        assert!(m.starts_with("crashed while checking its parameters (exit status: 101): thread"), "{m}");
        assert!(m.ends_with("attempt to multiply with overflow"), "{m}");
        let abort = "memory allocation of 34359738368 bytes failed\nstack backtrace:\n   0: std::alloc::rust_oom\n";
        let m = refusal(std::process::ExitStatus::from_raw(6), abort);
        assert!(m.contains("crashed") && m.ends_with("memory allocation of 34359738368 bytes failed"), "{m}");
    }

    #[test]
    fn a_valid_graph_parses() {
        let g = Graph::parse("g.toml", "[[nodes]]\nname='a'\nbinary='sh'\nparams={c='true'}\n").unwrap();
        assert_eq!(g.nodes[0].host, DEFAULT_HOST);
        assert_eq!(g.nodes[0].args, ["--c=true"]);
        assert_eq!(g.namespace, "g");
    }
}
