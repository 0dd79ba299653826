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
//! Asking a node runs it, so the checks ([`run_check`]) run only the project's node binaries
//! (`dc-*` files beside the running `dc`) unless the graph is trusted (`--trust`), each in its
//! own process group, bounded in time and output. Every count and size in a file is bounded.
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

// Bounds of every count and size in a launch file, checked before anything starts: past them a
// file is a mistake or an attack, and would cost memory, processes or time before failing.
/// The largest launch file read (the repository's are a few KiB).
const MAX_FILE_BYTES: usize = 1 << 20;
/// Most frames a reader's queue holds: memory grows with it per reader and topic (16 by default;
/// 100000 took 16 GB of memory and 1.4 GB of /dev/shm).
pub const MAX_QUEUE_DEPTH: usize = 256;
/// Most nodes of a graph: each is a process, checked one by one before the start.
pub const MAX_GRAPH_NODES: usize = 256;
/// Most hosts of a graph.
const MAX_HOSTS: usize = 64;
/// Longest host name: it goes into iceoryx2 service names (`dc/<namespace>@<host>/...`), zenoh
/// keys and the launcher's iceoryx2 node name (`dc-launch-<host>`).
const MAX_HOST_NAME_LEN: usize = 64;
/// Longest host address (a DNS name has at most 253 bytes).
const MAX_ADDRESS_LEN: usize = 253;
/// Most extra zenoh endpoints of a host, and the longest one.
const MAX_CONNECT: usize = 16;
const MAX_ENDPOINT_LEN: usize = 256;
/// Longest graph name (the namespace has its own bound, [`runtime::MAX_NAMESPACE_LEN`]).
const MAX_GRAPH_NAME_LEN: usize = 128;
/// Most parameters of a node, the longest parameter name and string value, the most values of
/// an array parameter.
const MAX_PARAMS: usize = 128;
const MAX_PARAM_KEY_LEN: usize = 64;
const MAX_PARAM_VALUE_LEN: usize = 4096;
const MAX_PARAM_ITEMS: usize = 256;
/// Most environment variables of a node, the longest name and value.
const MAX_ENV: usize = 64;
const MAX_ENV_KEY_LEN: usize = 128;
const MAX_ENV_VALUE_LEN: usize = 4096;
/// Most restarts of a node (`max_restarts`).
const MAX_RESTARTS: u32 = 100;
/// Most problems reported of one file; the rest are counted.
const MAX_PROBLEMS: usize = 50;
/// How long a node's check (`DC_VALIDATE`, `DC_DESCRIBE`) may take unless `DC_CHECK_TIMEOUT`
/// (seconds) says otherwise; the project's nodes answer in well under a second.
const CHECK_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(20);
/// The most a check may print on stdout, and on stderr (a port list or an error is a few KiB).
const CHECK_OUTPUT_CAP: usize = 1 << 20;
/// How often a running check is looked at.
const CHECK_POLL: std::time::Duration = std::time::Duration::from_millis(10);

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
    /// The folder the nodes run in, so the folder relative paths in `params` (and a relative
    /// `binary`) resolve against: relative to the launch file's own folder, which is the default.
    root: Option<Spanned<String>>,
    /// Queue depth per subscriber.
    queue_depth: Option<Spanned<usize>>,
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

/// `s` for a message: at most 40 characters, escaped.
fn shown(s: &str) -> String {
    let head: String = s.chars().take(40).collect();
    let more = if s.chars().nth(40).is_some() { "..." } else { "" };
    format!("{}{more}", head.escape_debug())
}

/// What is wrong with a node name, if anything: the runtime's rule ([`runtime::check_node_name`],
/// which a node would otherwise apply only once started) and letters, digits, `-` or `_`.
fn name_problem(label: &str) -> Option<String> {
    let ok = !label.is_empty() && label.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if !ok {
        return Some(format!("node name `{}` must be non-empty letters, digits, `-` or `_`", shown(label)));
    }
    runtime::check_node_name(label).err().map(|why| format!("node name `{}`: {why}", shown(label)))
}

/// What is wrong with a host name, if anything (it goes into bus names and zenoh keys).
fn host_name_problem(name: &str) -> Option<String> {
    let ok = !name.is_empty()
        && name.len() <= MAX_HOST_NAME_LEN
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    (!ok).then(|| {
        format!("host name `{}` must be 1 to {MAX_HOST_NAME_LEN} letters, digits, `-`, `_` or `.`", shown(name))
    })
}

/// What is wrong with a parameter's name, if anything: it becomes `--<name>` on the node's
/// command line, so it must be a plain flag name (an empty one would be a bare `--`).
fn param_key_problem(key: &str) -> Option<String> {
    let ok = key.len() <= MAX_PARAM_KEY_LEN
        && key.chars().next().is_some_and(|c| c.is_ascii_alphanumeric())
        && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    (!ok).then(|| {
        format!(
            "parameter name `{}` must be a flag name: a letter or digit, then letters, digits, `-` or `_`, \
             at most {MAX_PARAM_KEY_LEN} bytes",
            shown(key)
        )
    })
}

/// What is wrong with a node's environment, if anything.
fn env_problem(env: &BTreeMap<String, String>) -> Option<String> {
    if env.len() > MAX_ENV {
        return Some(format!("{} environment variables, at most {MAX_ENV}", env.len()));
    }
    for (key, value) in env {
        let ok = key.len() <= MAX_ENV_KEY_LEN
            && key.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !ok {
            return Some(format!(
                "environment variable name `{}` must be letters, digits or `_`, not starting with a digit, \
                 at most {MAX_ENV_KEY_LEN} bytes",
                shown(key)
            ));
        }
        if value.len() > MAX_ENV_VALUE_LEN || value.contains('\0') {
            return Some(format!("environment variable `{key}`: at most {MAX_ENV_VALUE_LEN} bytes, without NUL"));
        }
    }
    None
}

/// Environment variables that choose which code a program runs (the dynamic loader's `LD_*`,
/// glibc's module and helper paths, `PATH` for what a node starts): a launch file setting one
/// runs more than dc's own binaries, so it needs `--trust` as a foreign binary does.
fn chooses_code(key: &str) -> bool {
    key.starts_with("LD_") || ["GCONV_PATH", "GETCONF_DIR", "LOCPATH", "NLSPATH", "MALLOC_TRACE", "PATH"].contains(&key)
}

/// The folder of the running `dc`, where the project's node binaries are built or installed.
fn own_folder() -> Option<PathBuf> {
    std::env::current_exe().ok()?.parent()?.canonicalize().ok()
}

/// Whether `program` is one of the project's node binaries: a `dc-*` file in dc's own folder.
/// (Its folder is resolved, so `..` cannot lead out; a link placed in dc's folder is trusted as
/// dc itself is, by whoever may write there.)
fn is_own_binary(program: &Path) -> bool {
    let named = program.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("dc-"));
    let folder = program.parent().and_then(|d| d.canonicalize().ok());
    named && program.is_file() && folder.is_some() && folder == own_folder()
}

/// How long a node's check may take: `DC_CHECK_TIMEOUT` seconds when set (tests make it short),
/// else [`CHECK_TIMEOUT`].
fn check_timeout() -> std::time::Duration {
    std::env::var("DC_CHECK_TIMEOUT")
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| *s > 0.0)
        .and_then(|s| std::time::Duration::try_from_secs_f64(s).ok())
        .unwrap_or(CHECK_TIMEOUT)
}

/// Runs `node`'s check: its binary with its arguments, `configure` adding the environment that
/// says which check, and returns what it printed. Unless `trust`, only the project's own node
/// binaries run (`dc-*` files beside dc, with no environment that changes what code runs):
/// reading a launch file (`dc list`, `--dry-run`) must not run what it names. The check runs in
/// its own process group with stdin closed; the group is killed when it prints more than 1 MiB
/// on stdout or stderr, or has not ended within 20 s (`DC_CHECK_TIMEOUT` seconds, if set), so a
/// node cannot make the launcher hang or fill its memory.
pub fn run_check(
    node: &NodeSpec,
    trust: bool,
    configure: impl FnOnce(&mut std::process::Command),
) -> Result<std::process::Output, String> {
    run_check_within(node, trust, check_timeout(), configure)
}

fn run_check_within(
    node: &NodeSpec,
    trust: bool,
    timeout: std::time::Duration,
    configure: impl FnOnce(&mut std::process::Command),
) -> Result<std::process::Output, String> {
    use std::io::Read;
    use std::os::unix::process::CommandExt;
    use std::process::Stdio;
    if !trust {
        if let Some(why) = node.untrusted() {
            return Err(why);
        }
    }
    let program = node.program.display();
    let mut command = std::process::Command::new(&node.program);
    command.args(&node.args);
    if let Some(dir) = &node.workdir {
        command.current_dir(dir);
    }
    configure(&mut command);
    command.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).process_group(0);
    // SAFETY: prctl is async-signal-safe and touches no memory of the parent.
    unsafe {
        command.pre_exec(|| {
            // Its own group misses a terminal's Ctrl-C: it goes when `dc` does.
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
            Ok(())
        });
    }
    let mut child = command.spawn().map_err(|e| format!("cannot run `{program}`: {e}"))?;
    let group = child.id() as libc::pid_t;
    let kill_group = || {
        // SAFETY: signals the check's own process group, whose id is its pid.
        unsafe { libc::killpg(group, libc::SIGKILL) };
    };
    let (tx, rx) = std::sync::mpsc::channel::<(usize, Vec<u8>)>();
    let pipes: [Option<Box<dyn Read + Send>>; 2] = [
        child.stdout.take().map(|p| Box::new(p) as Box<dyn Read + Send>),
        child.stderr.take().map(|p| Box::new(p) as Box<dyn Read + Send>),
    ];
    for (which, pipe) in pipes.into_iter().enumerate() {
        let tx = tx.clone();
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(pipe) = pipe {
                // One byte past the cap says the cap was passed.
                let _ = pipe.take(CHECK_OUTPUT_CAP as u64 + 1).read_to_end(&mut bytes);
            }
            let _ = tx.send((which, bytes));
        });
    }
    let deadline = std::time::Instant::now() + timeout;
    let mut output: [Option<Vec<u8>>; 2] = [None, None];
    let mut status = None;
    loop {
        if status.is_none() {
            match child.try_wait() {
                Ok(Some(s)) => {
                    status = Some(s);
                    // What it left running in its group would hold the pipes open.
                    kill_group();
                }
                Ok(None) => {}
                Err(e) => {
                    kill_group();
                    let _ = child.wait();
                    return Err(format!("cannot wait for `{program}`: {e}"));
                }
            }
        }
        if let Some(status) = status {
            if output.iter().all(Option::is_some) {
                let [stdout, stderr] = output.map(Option::unwrap_or_default);
                return Ok(std::process::Output { status, stdout, stderr });
            }
        }
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            kill_group();
            let _ = child.wait();
            return Err(format!(
                "its check (`{program}`) did not end within {} s (DC_CHECK_TIMEOUT sets the limit): stopped",
                timeout.as_secs_f64()
            ));
        }
        match rx.recv_timeout(left.min(CHECK_POLL)) {
            Ok((which, bytes)) if bytes.len() > CHECK_OUTPUT_CAP => {
                kill_group();
                let _ = child.wait();
                return Err(format!(
                    "its check (`{program}`) printed more than {} KiB on {}: output too long, stopped",
                    CHECK_OUTPUT_CAP >> 10,
                    ["stdout", "stderr"][which]
                ));
            }
            Ok((which, bytes)) => output[which] = Some(bytes),
            Err(_) => {}
        }
    }
}

/// Finds node `label`'s binary, or says why not; a path (`scripts/node.py`) is taken relative to
/// `root`, the graph's folder.
fn resolve_binary(label: &str, binary: &str, root: Option<&Path>) -> Result<PathBuf, String> {
    let rooted = match root {
        Some(root) if Path::new(binary).components().count() > 1 => root.join(binary).display().to_string(),
        _ => binary.to_string(),
    };
    find_binary(&rooted).ok_or_else(|| {
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
    /// The folder the node runs in (its relative paths resolve against it): the launch file's
    /// root; `None` for a node built in code, which runs where dc was started.
    pub workdir: Option<PathBuf>,
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
            workdir: None,
        }
    }

    /// The node with environment variable `key` set to `value`.
    pub fn with_env(mut self, key: impl Into<String>, value: impl Into<String>) -> NodeSpec {
        self.env.insert(key.into(), value.into());
        self
    }

    /// Why running this node would run code that is not the project's own, if it would: its
    /// program is not a `dc-*` file beside dc, or its environment chooses what code runs.
    fn untrusted(&self) -> Option<String> {
        let program = self.program.display();
        if !is_own_binary(&self.program) {
            let folder = own_folder().map_or_else(|| "dc's folder".to_string(), |d| d.display().to_string());
            return Some(format!(
                "not run: `{program}` is not one of dc's node binaries (`dc-*` files in {folder}), and \
                 checking the graph would run it; pass `--trust` to run the programs this file names"
            ));
        }
        let keys: Vec<&str> = self.env.keys().map(String::as_str).filter(|k| chooses_code(k)).collect();
        (!keys.is_empty()).then(|| {
            format!(
                "not run: `{program}` with `{}` set by the file, which chooses what code runs; pass \
                 `--trust` to allow it",
                keys.join("`, `")
            )
        })
    }
}

/// A checked graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Graph {
    pub file: String,
    /// The folder the file's nodes run in (`[graph] root`, by default the file's folder); `None`
    /// for a graph built in code, whose nodes run where dc was started.
    pub root: Option<PathBuf>,
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
    /// Whether the checks may run programs other than the project's node binaries (`--trust`);
    /// a graph read from a file starts untrusted, one built in code names only dc's binaries.
    pub trust: bool,
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
/// arrays -> the flag repeated). Names must be plain flag names; counts and lengths are bounded.
pub fn params_to_args(params: &toml::Table) -> Result<Vec<String>, String> {
    if params.len() > MAX_PARAMS {
        return Err(format!("{} parameters, at most {MAX_PARAMS}", params.len()));
    }
    let mut args = Vec::new();
    for (key, value) in params {
        if let Some(why) = param_key_problem(key) {
            return Err(why);
        }
        let mut push = |v: &toml::Value| -> Result<(), String> {
            match v {
                toml::Value::Boolean(true) => args.push(format!("--{key}")),
                toml::Value::Boolean(false) => {}
                toml::Value::String(s) if s.len() > MAX_PARAM_VALUE_LEN => {
                    return Err(format!(
                        "parameter `{key}`: a value of {} bytes, at most {MAX_PARAM_VALUE_LEN}",
                        s.len()
                    ))
                }
                // No command line carries a NUL: the node could not even be started.
                toml::Value::String(s) if s.contains('\0') => {
                    return Err(format!("parameter `{key}`: a value with a NUL character"))
                }
                toml::Value::String(s) => args.push(format!("--{key}={s}")),
                toml::Value::Integer(i) => args.push(format!("--{key}={i}")),
                toml::Value::Float(f) => args.push(format!("--{key}={f}")),
                other => return Err(format!("parameter `{key}`: unsupported value {other}")),
            }
            Ok(())
        };
        match value {
            toml::Value::Array(items) if items.len() > MAX_PARAM_ITEMS => {
                return Err(format!("parameter `{key}`: {} values, at most {MAX_PARAM_ITEMS}", items.len()))
            }
            toml::Value::Array(items) => items.iter().try_for_each(&mut push)?,
            v => push(v)?,
        }
    }
    Ok(args)
}

pub use runtime::find_binary;

impl Graph {
    /// Reads and checks a launch file. Parameter checks that need the node binaries run in
    /// [`Graph::check_params`].
    pub fn load(path: &Path) -> Result<Graph, GraphError> {
        use std::io::Read;
        let file = path.display().to_string();
        let read_error = |source| GraphError::Read { file: file.clone(), source };
        // Read no more than the bound: `dc list /dev/zero` must not fill memory.
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_FILE_BYTES as u64 + 1).read_to_end(&mut bytes))
            .map_err(read_error)?;
        if bytes.len() > MAX_FILE_BYTES {
            let message = format!("larger than {} KiB, the most a launch file may have", MAX_FILE_BYTES >> 10);
            return Err(GraphError::Invalid { file: file.clone(), problems: vec![Problem { line: 0, message }] });
        }
        let text = String::from_utf8(bytes)
            .map_err(|e| read_error(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))?;
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
        } else if name.len() > MAX_GRAPH_NAME_LEN {
            problem(
                text.find("[graph]").unwrap_or(0),
                format!("graph name: {} bytes, at most {MAX_GRAPH_NAME_LEN}", name.len()),
            );
        }
        // The folder the nodes run in: `root` taken from the file's own folder (the default),
        // so a graph means the same files whichever folder dc was started from.
        let root = {
            let base = Path::new(file).parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            let rel = raw.graph.root.as_ref().map_or(".", |r| r.get_ref().as_str());
            let at = raw.graph.root.as_ref().map_or(0, |r| r.span().start);
            let joined = base.join(rel);
            match joined.canonicalize() {
                Ok(dir) if dir.is_dir() => Some(dir),
                Ok(_) => {
                    problem(at, format!("[graph] root = \"{rel}\": {} is not a folder", joined.display()));
                    None
                }
                Err(e) => {
                    problem(at, format!("[graph] root = \"{rel}\": {}: {e}", joined.display()));
                    None
                }
            }
        };
        let queue_depth = match &raw.graph.queue_depth {
            None => DEFAULT_QUEUE_DEPTH,
            Some(depth) => {
                let d = *depth.get_ref();
                if !(1..=MAX_QUEUE_DEPTH).contains(&d) {
                    problem(
                        depth.span().start,
                        format!(
                            "[graph] queue_depth = {d}: must be 1 to {MAX_QUEUE_DEPTH} (the frames each reader \
                             may hold; memory grows with it)"
                        ),
                    );
                }
                d
            }
        };

        let mut hosts = BTreeMap::new();
        if let Some((_, past)) = raw.hosts.iter().nth(MAX_HOSTS) {
            problem(past.span().start, format!("{} hosts, at most {MAX_HOSTS}", raw.hosts.len()));
        }
        for (host_name, spanned) in raw.hosts.iter().take(MAX_HOSTS) {
            let h = spanned.get_ref();
            let at = spanned.span().start;
            if let Some(why) = host_name_problem(host_name) {
                problem(at, why);
            }
            if h.address.is_empty() || h.address.len() > MAX_ADDRESS_LEN {
                problem(at, format!("host `{}`: `address` must have 1 to {MAX_ADDRESS_LEN} bytes", shown(host_name)));
            }
            if h.zenoh_connect.len() > MAX_CONNECT {
                let n = h.zenoh_connect.len();
                problem(
                    at,
                    format!("host `{}`: {n} `zenoh_connect` endpoints, at most {MAX_CONNECT}", shown(host_name)),
                );
            }
            if h.zenoh_connect.iter().any(|e| e.is_empty() || e.len() > MAX_ENDPOINT_LEN) {
                problem(
                    at,
                    format!(
                        "host `{}`: a `zenoh_connect` endpoint must have 1 to {MAX_ENDPOINT_LEN} bytes",
                        shown(host_name)
                    ),
                );
            }
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
        if let Some(past) = raw.nodes.get(MAX_GRAPH_NODES) {
            problem(past.span().start, format!("{} nodes, at most {MAX_GRAPH_NODES} in a graph", raw.nodes.len()));
        }
        for spanned in raw.nodes.iter().take(MAX_GRAPH_NODES) {
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
            let program = match resolve_binary(&label, binary.get_ref(), root.as_deref()) {
                Ok(p) => p,
                Err(why) => {
                    problem(binary.span().start, why);
                    continue;
                }
            };
            let on_failure = match (node.on_failure.as_ref().map(|p| p.get_ref().as_str()), node.max_restarts) {
                (None | Some("stop-graph"), None) => OnFailure::StopGraph,
                (Some("restart"), Some(max)) if max > MAX_RESTARTS => {
                    problem(start, format!("node `{label}`: max_restarts = {max}, at most {MAX_RESTARTS}"));
                    continue;
                }
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
            if let Some(why) = env_problem(&node.env) {
                problem(start, format!("node `{label}`: {why}"));
                continue;
            }
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
                workdir: root.clone(),
            });
        }
        if routers.is_empty() {
            for (name, h) in &raw.hosts {
                // The launcher and each node of the host listen from `zenoh_port` up.
                let port = h.get_ref().zenoh_port as usize;
                let members = 1 + nodes.iter().filter(|n| &n.host == name).count();
                if port != 0 && port + members - 1 > u16::MAX as usize {
                    problem(
                        h.span().start,
                        format!(
                            "host `{}`: zenoh_port = {port} leaves no room for its {members} zenoh endpoints \
                             (ports zenoh_port and up, the last at most {})",
                            shown(name),
                            u16::MAX
                        ),
                    );
                }
            }
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
            if problems.len() > MAX_PROBLEMS {
                let more = problems.len() - MAX_PROBLEMS;
                problems.truncate(MAX_PROBLEMS);
                problems.push(Problem { line: 0, message: format!("... and {more} more problems") });
            }
            return Err(invalid(problems));
        }
        Ok(Graph {
            file: file.to_string(),
            root,
            name,
            namespace,
            queue_depth,
            hosts,
            topics,
            best_effort,
            security,
            nodes,
            trust: false,
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
            match resolve_binary(&node.name, &node.binary, None) {
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
            root: None,
            name: name.to_string(),
            namespace: namespace.to_string(),
            queue_depth: DEFAULT_QUEUE_DEPTH,
            hosts: [(DEFAULT_HOST.to_string(), default_host())].into(),
            topics: BTreeMap::new(),
            best_effort: Default::default(),
            security: None,
            nodes: checked,
            // The code names its own node binaries (`dc-sim`, ...), found as a file's are.
            trust: true,
        })
    }

    /// Asks each node binary whether it accepts its parameters (`DC_VALIDATE=1`), so that a
    /// missing, unknown or ill-typed parameter fails before anything starts (through
    /// [`run_check`]: only dc's own binaries unless [`Graph::trust`], bounded in time and output).
    pub fn check_params(&self) -> Result<(), GraphError> {
        self.check_params_on(None)
    }

    /// [`Graph::check_params`] for the nodes of `host` only (all with `None`): a host checks
    /// the files its own nodes read, which the other hosts need not have.
    pub fn check_params_on(&self, host: Option<&str>) -> Result<(), GraphError> {
        let mut problems = Vec::new();
        for node in self.nodes.iter().filter(|n| host.is_none_or(|h| n.host == h)) {
            let checked = run_check(node, self.trust, |command| {
                command
                    .env("DC_VALIDATE", "1")
                    // A node that crashes while checking says why in a line, not a backtrace.
                    .env("RUST_BACKTRACE", "0");
            });
            let why = match checked {
                Ok(o) if o.status.success() => continue,
                Ok(o) => refusal(o.status, &String::from_utf8_lossy(&o.stderr)),
                Err(why) => why,
            };
            problems
                .push(Problem { line: node.line, message: format!("node `{}` ({}): {why}", node.name, node.binary) });
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

    /// Every count and size of a file has a bound, refused by the check on its line: before, a
    /// queue depth of 100000 took 16 GB, a 300-byte node name failed only once started, and an
    /// empty parameter name became a bare `--` on the node's command line.
    #[test]
    fn counts_and_sizes_past_their_bounds_are_refused_on_their_line() {
        let node = "[[nodes]]\nname = 'a'\nbinary = 'sh'\n";
        let p = problems(&format!("[graph]\nqueue_depth = 100000\n{node}"));
        assert!(p.iter().any(|p| p.line == 2 && p.message.contains("queue_depth = 100000: must be 1 to 256")), "{p:?}");
        let p = problems(&format!("[graph]\nqueue_depth = 0\n{node}"));
        assert!(p.iter().any(|p| p.line == 2 && p.message.contains("queue_depth = 0")), "{p:?}");
        let g = Graph::parse("g.toml", &format!("[graph]\nqueue_depth = {MAX_QUEUE_DEPTH}\n{node}")).unwrap();
        assert_eq!(g.queue_depth, MAX_QUEUE_DEPTH);

        let p = problems(&format!("[[nodes]]\nbinary = 'sh'\nname = '{}'\n", "n".repeat(300)));
        assert!(p.iter().any(|p| p.line == 3 && p.message.contains("300 bytes, more than the 128")), "{p:?}");
        Graph::parse("g.toml", &format!("[[nodes]]\nbinary = 'sh'\nname = '{}'\n", "n".repeat(128))).unwrap();

        let long = format!("'{}'", "k".repeat(65));
        for key in ["''", "'a b'", "'-x'", "'a=b'", long.as_str()] {
            let p = problems(&format!("{node}params = {{ {key} = 1 }}\n"));
            assert!(p.iter().any(|p| p.line == 1 && p.message.contains("must be a flag name")), "{key}: {p:?}");
        }
        let g = Graph::parse("g.toml", &format!("{node}params = {{ a-b_2 = 1, 3d = true }}\n")).unwrap();
        assert_eq!(g.nodes[0].args, ["--3d", "--a-b_2=1"]);
        let p = problems(&format!("{node}params = {{ s = '{}' }}\n", "v".repeat(MAX_PARAM_VALUE_LEN + 1)));
        assert!(p[0].message.contains("at most 4096"), "{p:?}");
        let p = problems(&format!("{node}params = {{ s = \"a\\u0000b\" }}\n"));
        assert!(p[0].message.contains("NUL"), "{p:?}");
        let p = problems(&format!("{node}params = {{ s = [{}] }}\n", vec!["1"; MAX_PARAM_ITEMS + 1].join(",")));
        assert!(p[0].message.contains("257 values, at most 256"), "{p:?}");

        let many: String =
            (0..=MAX_GRAPH_NODES).map(|i| format!("[[nodes]]\nname = 'n{i}'\nbinary = 'sh'\n")).collect();
        let p = problems(&many);
        assert!(
            p.iter().any(|p| p.line == 3 * MAX_GRAPH_NODES + 1 && p.message.contains("257 nodes, at most 256")),
            "{p:?}"
        );

        let p = problems(&format!("{node}max_restarts = 1000000\non_failure = 'restart'\n"));
        assert!(p[0].message.contains("max_restarts = 1000000, at most 100"), "{p:?}");
        let p = problems(&format!("{node}env = {{ 'A=B' = 'x' }}\n"));
        assert!(p[0].message.contains("environment variable name `A=B`"), "{p:?}");
        let p = problems(&format!("{node}env = {{ K = \"\\u0000\" }}\n"));
        assert!(p[0].message.contains("without NUL"), "{p:?}");

        let p = problems(&format!("[hosts.'a b']\n{node}"));
        assert!(p.iter().any(|p| p.message.contains("host name `a b` must be")), "{p:?}");
        let p = problems(&format!("[hosts.local]\nzenoh_port = 65535\n{node}{}", node.replace("'a'", "'b'")));
        assert!(p.iter().any(|p| p.message.contains("zenoh_port = 65535 leaves no room for its 3")), "{p:?}");
        let hosts: String = (0..=MAX_HOSTS).map(|i| format!("[hosts.h{i:03}]\nzenoh_port = {}\n", 7000 + i)).collect();
        let p = problems(&format!("{hosts}{node}host = 'h000'\n"));
        assert!(p.iter().any(|p| p.message.contains("65 hosts, at most 64")), "{p:?}");
    }

    #[test]
    fn a_file_with_very_many_problems_reports_the_first_and_counts_the_rest() {
        let text: String = (0..200).map(|i| format!("[[nodes]]\nname = 'n{i}'\nbinary = 'dc-no-such-{i}'\n")).collect();
        let p = problems(&text);
        assert_eq!(p.len(), MAX_PROBLEMS + 1, "{p:?}");
        assert_eq!(p.last().unwrap().message, "... and 150 more problems");
        let dir = std::env::temp_dir().join(format!("dc-graph-size-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let big = dir.join("big.toml");
        std::fs::write(&big, "#".repeat(MAX_FILE_BYTES + 1)).unwrap();
        let e = Graph::load(&big).unwrap_err().to_string();
        assert!(e.contains("big.toml: larger than 1024 KiB"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_files_nodes_run_in_its_root_taken_from_the_files_own_folder() {
        let dir = std::env::temp_dir().join(format!("dc-root-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("launch")).unwrap();
        let file = dir.join("launch/g.toml");
        let node = "[[nodes]]\nname = 'a'\nbinary = 'sh'\n";
        std::fs::write(&file, format!("[graph]\nroot = '..'\n{node}")).unwrap();
        let g = Graph::load(&file).unwrap();
        let root = dir.canonicalize().unwrap();
        assert_eq!(g.root.as_deref(), Some(root.as_path()));
        assert_eq!(g.nodes[0].workdir.as_deref(), Some(root.as_path()));
        // By default the file's own folder.
        std::fs::write(&file, node).unwrap();
        assert_eq!(Graph::load(&file).unwrap().root, Some(root.join("launch")));
        std::fs::write(&file, format!("[graph]\nroot = 'no-such'\n{node}")).unwrap();
        match Graph::load(&file) {
            Err(GraphError::Invalid { problems, .. }) => {
                assert!(
                    problems.iter().any(|p| p.line == 2 && p.message.contains("root = \"no-such\"")),
                    "{problems:?}"
                )
            }
            other => panic!("expected a problem with the root, got {other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn node_running(program: &str, args: &[&str]) -> NodeSpec {
        NodeSpec {
            program: find_binary(program).unwrap(),
            args: args.iter().map(|a| a.to_string()).collect(),
            ..NodeSpec::new("probe", program, false, vec![])
        }
    }

    /// `dc list` ran what a file named (`env -S "sh -c ..."`); now only dc's own node binaries.
    #[test]
    fn a_check_runs_no_program_but_dcs_own_node_binaries_unless_trusted() {
        let dir = std::env::temp_dir().join(format!("dc-trust-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let marker = dir.join("ran");
        let touch = format!("touch {}", marker.display());
        let node = node_running("sh", &["-c", touch.as_str()]);
        let e = run_check(&node, false, |_| {}).unwrap_err();
        assert!(e.contains(&format!("`{}` is not one of dc's node binaries", node.program.display())), "{e}");
        assert!(e.contains("--trust"), "{e}");
        assert!(!marker.exists(), "the check ran the program");
        // Named like one of ours but elsewhere: not ours either.
        let fake = dir.join("dc-fake");
        std::fs::write(&fake, "#!/bin/sh\ntouch \"$0.ran\"\n").unwrap();
        assert!(!is_own_binary(&fake));
        // Trusted, it runs.
        assert!(run_check(&node, true, |_| {}).unwrap().status.success());
        assert!(marker.exists());

        // One of ours (a `dc-*` file beside the running executable) runs, unless its environment
        // chooses what code runs.
        let own = own_folder().unwrap().join(format!("dc-trust-test-{}", std::process::id()));
        std::fs::write(&own, "").unwrap();
        assert!(is_own_binary(&own));
        let ours = NodeSpec { program: own.clone(), ..NodeSpec::new("ours", "dc-x", false, vec![]) };
        assert_eq!(ours.clone().with_env("RUST_LOG", "warn").untrusted(), None);
        let e = ours.with_env("LD_PRELOAD", "/tmp/x.so").untrusted().unwrap();
        assert!(e.contains("`LD_PRELOAD` set by the file") && e.contains("--trust"), "{e}");
        assert!(chooses_code("PATH") && chooses_code("LD_LIBRARY_PATH") && !chooses_code("OMP_NUM_THREADS"));
        let _ = std::fs::remove_file(&own);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A node that never answered its check hung `dc list`; one printing without end (`yes`)
    /// grew it to gigabytes. Both are stopped, with their process group.
    #[test]
    fn a_check_that_does_not_end_or_prints_too_much_is_stopped() {
        let node = node_running("sh", &["-c", "sleep 1000; echo never"]);
        let started = std::time::Instant::now();
        let e = run_check_within(&node, true, std::time::Duration::from_millis(300), |_| {}).unwrap_err();
        assert!(e.contains("did not end within 0.3 s") && e.contains("DC_CHECK_TIMEOUT"), "{e}");
        assert!(started.elapsed() < std::time::Duration::from_secs(5), "{:?}", started.elapsed());

        let e = run_check(&node_running("yes", &[]), true, |_| {}).unwrap_err();
        assert!(e.contains("printed more than 1024 KiB on stdout: output too long"), "{e}");
        let e = run_check(&node_running("sh", &["-c", "yes >&2"]), true, |_| {}).unwrap_err();
        assert!(e.contains("on stderr"), "{e}");
        // What ends in time is read whole, stdout and stderr apart.
        let o = run_check(&node_running("sh", &["-c", "echo out; echo err >&2; exit 3"]), true, |_| {}).unwrap();
        assert_eq!(
            (o.stdout.as_slice(), o.stderr.as_slice(), o.status.code()),
            (&b"out\n"[..], &b"err\n"[..], Some(3))
        );
    }

    #[test]
    fn a_valid_graph_parses() {
        let g = Graph::parse("g.toml", "[[nodes]]\nname='a'\nbinary='sh'\nparams={c='true'}\n").unwrap();
        assert_eq!(g.nodes[0].host, DEFAULT_HOST);
        assert_eq!(g.nodes[0].args, ["--c=true"]);
        assert_eq!(g.namespace, "g");
    }
}
