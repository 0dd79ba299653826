//! The bus's configuration as a node reads it (namespace, transports, zenoh, TLS), the
//! runtime's errors and the shutdown signal: what every other module of the runtime stands on.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Errors of the runtime.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("topic `{topic}`: iceoryx2: {what}")]
    Iceoryx2 { topic: String, what: String },
    #[error("topic `{topic}`: zenoh: {what}")]
    Zenoh { topic: String, what: String },
    #[error("topic `{topic}`: {source}")]
    Codec { topic: String, source: msgs::CodecError },
    #[error("bad bus configuration in DC_BUS: {0}")]
    Config(String),
    #[error("iceoryx2 node: {0}")]
    Node(String),
    #[error("launcher pipe: {0}")]
    Launcher(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Which transport carries a topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// Zero-copy shared memory on this host.
    #[default]
    Iceoryx2,
    /// CBOR over zenoh (across hosts).
    Zenoh,
    /// Both: a publisher whose topic is consumed locally and remotely publishes once to each; a
    /// subscriber with publishers on this host and on others reads both.
    Both,
}

impl Transport {
    pub fn uses_iceoryx2(self) -> bool {
        matches!(self, Transport::Iceoryx2 | Transport::Both)
    }
    pub fn uses_zenoh(self) -> bool {
        matches!(self, Transport::Zenoh | Transport::Both)
    }
}

/// Zenoh session settings of one node.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct ZenohConfig {
    /// Endpoints this node listens on, e.g. `tcp/127.0.0.1:7447` (never every interface by default).
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints this node connects to (other nodes, or a router).
    #[serde(default)]
    pub connect: Vec<String>,
    /// `peer` (default) or `client` (through a router).
    #[serde(default)]
    pub mode: Option<String>,
    /// TLS for every link (endpoints are then `tls/...`); None: plain TCP.
    #[serde(default)]
    pub tls: Option<TlsConfig>,
}

/// A node's TLS files (PEM): the graph's CA, and this host's certificate and private key, used
/// both to accept links and to open them.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct TlsConfig {
    /// The CA every certificate of the graph is signed by.
    pub ca: String,
    pub cert: String,
    pub key: String,
    /// Mutual TLS: a peer must present a certificate signed by the CA too (not only the side
    /// that accepts the link).
    pub mutual: bool,
}

/// How a node reaches the bus; written by the launcher, read by the runtime.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct BusConfig {
    /// Separates graphs on one machine: iceoryx2 services are `dc/<namespace>/<topic>`, zenoh
    /// keys `dc/<namespace>/<topic>` (`dc/<topic>` when empty).
    #[serde(default)]
    pub namespace: String,
    /// Transport of topics not listed in `topics`.
    #[serde(default)]
    pub default_transport: Transport,
    /// Per-topic transport.
    #[serde(default)]
    pub topics: BTreeMap<String, Transport>,
    /// Topics delivered best effort: a subscriber that falls behind loses the oldest frames
    /// instead of holding the publisher back (viewers and taps that must never slow the loop).
    /// Every other topic is reliable: nothing is lost, a full queue waits.
    #[serde(default)]
    pub best_effort: std::collections::BTreeSet<String>,
    /// Per topic this node publishes over zenoh: how many subscribers the launcher planned for it
    /// over zenoh. The publisher holds its first frame until that many have announced themselves
    /// (liveliness tokens), so none misses the start; 0 or absent: until any one matches.
    #[serde(default)]
    pub zenoh_readers: BTreeMap<String, usize>,
    #[serde(default)]
    pub zenoh: ZenohConfig,
    /// Queue depth per subscriber; a full queue holds the publisher back (no loss).
    #[serde(default = "default_queue_depth")]
    pub queue_depth: usize,
    /// The host of a multi-host graph: iceoryx2 services are then `dc/<namespace>@<host>/<topic>`,
    /// so two "hosts" sharing one machine's shared memory (network namespaces, tests) stay apart.
    #[serde(default)]
    pub host: String,
    /// This process observes a running graph (`dc topic echo`, `dc record -a`): it opens the
    /// graph's iceoryx2 topics as the graph made them and never creates one.
    #[serde(default)]
    pub observe: bool,
}

/// The topics a node publishes and subscribes, as `DC_DESCRIBE=1` reports them.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq, Eq)]
pub struct Ports {
    pub publishes: std::collections::BTreeSet<String>,
    pub subscribes: std::collections::BTreeSet<String>,
}

/// Line prefix of a described node's [`Ports`] JSON on stdout.
pub const PORTS_MARKER: &str = "\u{1e}dc-ports ";

fn default_queue_depth() -> usize {
    16
}

/// The longest bus namespace: with the longest topic, a host qualifier and an event suffix the
/// iceoryx2 service name stays well inside its limit (tested).
pub const MAX_NAMESPACE_LEN: usize = 64;

/// Whether `namespace` can name a graph's bus: at most [`MAX_NAMESPACE_LEN`] ASCII letters,
/// digits, `-`, `_` or `.`, so every iceoryx2 service name and zenoh key built from it is valid
/// (checked when a launch file is read, not when its nodes start).
pub fn check_namespace(namespace: &str) -> std::result::Result<(), String> {
    if namespace.len() > MAX_NAMESPACE_LEN {
        return Err(format!("{} bytes, more than the {MAX_NAMESPACE_LEN} a bus namespace may have", namespace.len()));
    }
    if let Some(c) = namespace.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))) {
        return Err(format!(
            "`{}` is not allowed in a bus namespace (ASCII letters, digits, `-`, `_`, `.`)",
            c.escape_debug()
        ));
    }
    Ok(())
}

impl BusConfig {
    pub fn transport(&self, topic: &str) -> Transport {
        self.topics.get(topic).copied().unwrap_or(self.default_transport)
    }

    /// Whether `topic` is delivered best effort (see [`BusConfig::best_effort`]).
    pub fn is_best_effort(&self, topic: &str) -> bool {
        self.best_effort.contains(topic)
    }

    /// The bus key of `topic`: `dc/<namespace>/<topic>`.
    pub fn key(&self, topic: &str) -> String {
        if self.namespace.is_empty() {
            format!("dc/{topic}")
        } else {
            format!("dc/{}/{topic}", self.namespace)
        }
    }

    /// The iceoryx2 service name of `topic`: the bus key, qualified by the host when one is set.
    pub fn iox_key(&self, topic: &str) -> String {
        if self.host.is_empty() {
            self.key(topic)
        } else {
            format!("dc/{}@{}/{topic}", self.namespace, self.host)
        }
    }

    pub(crate) fn from_env() -> Result<BusConfig> {
        match std::env::var("DC_BUS") {
            Ok(json) => serde_json::from_str(&json).map_err(|e| Error::Config(e.to_string())),
            Err(_) => Ok(BusConfig { queue_depth: default_queue_depth(), ..Default::default() }),
        }
    }
}

/// Set by Ctrl-C / SIGTERM.
pub(crate) static SIGNALLED: AtomicBool = AtomicBool::new(false);

/// A node's shutdown signal: its own flag or a process-wide Ctrl-C / SIGTERM.
#[derive(Clone, Debug, Default)]
pub struct ShutdownSignal(pub(crate) Arc<AtomicBool>);

impl ShutdownSignal {
    pub fn is_set(&self) -> bool {
        self.0.load(Ordering::SeqCst) || SIGNALLED.load(Ordering::SeqCst)
    }
    pub fn set(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
}
