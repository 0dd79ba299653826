//! zenoh transport: CBOR frames on key `dc/<namespace>/<topic>`, reliable, with blocking congestion
//! control (zenoh's default `Drop` loses data under load); a best-effort topic drops instead
//! (congestion control `Drop`, and a ring buffer at the subscriber that loses its oldest sample). Reliability is zenoh's default
//! (`Reliable`; choosing it explicitly is an unstable API in 1.10). Sessions listen only on the endpoints
//! the launch file names and never scout by multicast, so a test or a graph does not wander onto
//! the host's other interfaces.

use crate::config::{Error, Result, ZenohConfig};
use std::time::{Duration, Instant};
use zenoh::handlers::FifoChannelHandler;
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;
use zenoh::Wait;

/// How long a publisher waits for its subscribers before its first message. The launcher's ready
/// barrier guarantees the subscribers exist; this covers their declarations' trip (and a planned
/// subscriber that never comes, which is then said in a warning).
const MATCH_TIMEOUT: Duration = Duration::from_secs(10);

/// Where a subscriber of `key` announces itself: a liveliness token per subscriber, declared after
/// the subscriber itself, so a publisher that sees the token already routes to the subscriber.
fn readers_key(key: &str) -> String {
    format!("{key}/{READERS}")
}

/// Key segments of the liveliness tokens of a topic's subscribers and publishers
/// (`<key>/_readers/<zid>/<n>`, `<key>/_writers/<zid>/<n>/<delivery>`), which `dc topic list
/// --zenoh` counts.
pub const READERS: &str = "_readers";
pub const WRITERS: &str = "_writers";

/// Tells the ports (and their tokens) of one session apart.
static PORT_COUNT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Room for a frame's CBOR envelope and header (a grid header with its channel names is the
/// largest, ~200 bytes) beside its items.
const ENVELOPE_BYTES: usize = 512;

/// How long a client session waits for the graph's zenoh router before failing.
const CLIENT_CONNECT_TIMEOUT: Duration = Duration::from_secs(120);

pub(crate) fn open_session(cfg: &ZenohConfig) -> Result<zenoh::Session, String> {
    let mut config = zenoh::Config::default();
    let json = |v: &[String]| serde_json::to_string(v).expect("strings serialise");
    let mode = cfg.mode.clone().unwrap_or_else(|| "peer".to_string());
    // Never the zenoh default (every interface): loopback with an OS-chosen port unless told.
    let scheme = if cfg.tls.is_some() { "tls" } else { "tcp" };
    let listen = if cfg.listen.is_empty() { vec![format!("{scheme}/127.0.0.1:0")] } else { cfg.listen.clone() };
    let mut settings = vec![
        ("mode", format!("\"{mode}\"")),
        ("connect/endpoints", json(&cfg.connect)),
        ("scouting/multicast/enabled", "false".to_string()),
    ];
    if mode == "client" {
        // A client only connects (to the graph's router), and by default gives up at once when
        // the router is not up yet: the hosts of a graph start in any order, so it waits.
        settings.push(("connect/timeout_ms", CLIENT_CONNECT_TIMEOUT.as_millis().to_string()));
    } else {
        settings.push(("listen/endpoints", json(&listen)));
    }
    settings.extend(tls_settings(cfg.tls.as_ref()));
    for (key, value) in settings {
        config.insert_json5(key, &value).map_err(|e| format!("config {key} = {value}: {e}"))?;
    }
    zenoh::open(config).wait().map_err(|e| format!("open session: {e}"))
}

/// The zenoh settings of `tls`: the same certificate to accept and to open links, signed by the
/// graph's CA; peers' names (their addresses) are verified.
fn tls_settings(tls: Option<&crate::config::TlsConfig>) -> Vec<(&'static str, String)> {
    let Some(t) = tls else { return Vec::new() };
    let quoted = |s: &str| serde_json::to_string(s).expect("strings serialise");
    vec![
        ("transport/link/tls/root_ca_certificate", quoted(&t.ca)),
        ("transport/link/tls/listen_certificate", quoted(&t.cert)),
        ("transport/link/tls/listen_private_key", quoted(&t.key)),
        ("transport/link/tls/connect_certificate", quoted(&t.cert)),
        ("transport/link/tls/connect_private_key", quoted(&t.key)),
        ("transport/link/tls/enable_mtls", t.mutual.to_string()),
        ("transport/link/tls/verify_name_on_connect", "true".to_string()),
    ]
}

fn err(topic: &str, what: impl std::fmt::Display) -> Error {
    Error::Zenoh { topic: topic.to_string(), what: what.to_string() }
}

pub(crate) struct ZenPublisher {
    topic: String,
    publisher: zenoh::pubsub::Publisher<'static>,
    session: zenoh::Session,
    key: String,
    /// Subscribers the launcher planned over zenoh (0: unknown, wait for any match).
    readers: usize,
    matched: bool,
    /// Announces the publisher (see [`WRITERS`]); undeclared when dropped.
    _token: zenoh::liveliness::LivelinessToken,
}

impl ZenPublisher {
    pub(crate) fn new(
        session: &zenoh::Session,
        key: &str,
        topic: &str,
        best_effort: bool,
        readers: usize,
    ) -> Result<ZenPublisher> {
        let congestion = if best_effort { CongestionControl::Drop } else { CongestionControl::Block };
        let publisher = session
            .declare_publisher(key.to_string())
            .congestion_control(congestion)
            .encoding(zenoh::bytes::Encoding::APPLICATION_CBOR)
            .wait()
            .map_err(|e| err(topic, format!("declare publisher on `{key}`: {e}")))?;
        let n = PORT_COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let delivery = if best_effort { "best-effort" } else { "reliable" };
        let token_key = format!("{key}/{WRITERS}/{}/{n}/{delivery}", session.zid());
        let token = session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(|e| err(topic, format!("declare liveliness `{token_key}`: {e}")))?;
        Ok(ZenPublisher {
            _token: token,
            topic: topic.to_string(),
            publisher,
            session: session.clone(),
            key: key.to_string(),
            readers,
            matched: false,
        })
    }

    pub(crate) fn send<H: msgs::FrameHeader, T: msgs::FrameItem>(&mut self, header: &H, items: &[T]) -> Result<()> {
        if !self.matched {
            self.wait_for_match();
        }
        // Encoded into a buffer that zenoh takes over: a buffer of ours would be copied again.
        let mut bytes = Vec::with_capacity(ENVELOPE_BYTES + std::mem::size_of_val(items));
        msgs::encode_into(header, items, &mut bytes)
            .map_err(|source| Error::Codec { topic: self.topic.clone(), source })?;
        self.publisher.put(bytes).wait().map_err(|e| err(&self.topic, format!("put: {e}")))
    }

    /// Puts an already encoded payload as it is.
    pub(crate) fn send_encoded(&mut self, bytes: &[u8]) -> Result<()> {
        if !self.matched {
            self.wait_for_match();
        }
        self.publisher.put(bytes).wait().map_err(|e| err(&self.topic, format!("put: {e}")))
    }

    /// Waits (bounded) until every planned subscriber has announced itself — or, with none
    /// planned, until some subscriber matches — so the first frames reach every reader (a
    /// subscriber whose declaration arrives after them would miss them for good).
    fn wait_for_match(&mut self) {
        let start = Instant::now();
        let mut seen = 0;
        while start.elapsed() < MATCH_TIMEOUT {
            let ready = if self.readers > 0 {
                seen = self.announced_readers();
                seen >= self.readers
            } else {
                match self.publisher.matching_status().wait() {
                    Ok(s) => s.matching(),
                    Err(e) => {
                        tracing::warn!(topic = %self.topic, "zenoh matching status: {e}");
                        true
                    }
                }
            };
            if ready {
                self.matched = true;
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        if self.readers > 0 {
            tracing::warn!(
                topic = %self.topic,
                "{seen} of {} planned subscribers announced after {MATCH_TIMEOUT:?}: sending anyway",
                self.readers
            );
        }
        self.matched = true;
    }

    /// Subscribers of this key whose liveliness token this session knows of now.
    fn announced_readers(&self) -> usize {
        let replies = match self
            .session
            .liveliness()
            .get(format!("{}/**", readers_key(&self.key)))
            .timeout(Duration::from_millis(500))
            .wait()
        {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!(topic = %self.topic, "zenoh liveliness query: {e}");
                return 0;
            }
        };
        let mut tokens = std::collections::BTreeSet::new();
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                tokens.insert(sample.key_expr().as_str().to_string());
            }
        }
        tokens.len()
    }
}

pub(crate) struct ZenSubscriber {
    topic: String,
    queue: SubscriberQueue,
    /// Announces the subscriber to publishers (see [`readers_key`]); undeclared when dropped.
    _token: zenoh::liveliness::LivelinessToken,
}

/// A reliable subscriber's FIFO, or a best-effort one's ring.
enum SubscriberQueue {
    Fifo(zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>),
    Ring(zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<Sample>>),
}

impl ZenSubscriber {
    /// A subscriber with a FIFO of `capacity`: when it is full zenoh blocks the link, which with the
    /// publisher's blocking congestion control holds the publisher back instead of dropping. A
    /// best-effort one keeps a ring of `capacity` instead: a full ring loses its oldest sample.
    pub(crate) fn new(
        session: &zenoh::Session,
        key: &str,
        topic: &str,
        capacity: usize,
        best_effort: bool,
    ) -> Result<ZenSubscriber> {
        let declare = |e: zenoh::Error| err(topic, format!("declare subscriber on `{key}`: {e}"));
        let builder = session.declare_subscriber(key.to_string());
        let queue = if best_effort {
            SubscriberQueue::Ring(builder.with(zenoh::handlers::RingChannel::new(capacity)).wait().map_err(declare)?)
        } else {
            SubscriberQueue::Fifo(builder.with(zenoh::handlers::FifoChannel::new(capacity)).wait().map_err(declare)?)
        };
        // After the subscriber: a publisher that sees the token already routes to it.
        let n = PORT_COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let token_key = format!("{}/{}/{n}", readers_key(key), session.zid());
        let token = session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(|e| err(topic, format!("declare liveliness `{token_key}`: {e}")))?;
        Ok(ZenSubscriber { topic: topic.to_string(), queue, _token: token })
    }

    pub(crate) fn recv_timeout(&self, timeout: Duration) -> Result<Option<Sample>> {
        let got = match &self.queue {
            SubscriberQueue::Fifo(s) => s.recv_timeout(timeout),
            SubscriberQueue::Ring(s) => s.recv_timeout(timeout),
        };
        got.map_err(|e| err(&self.topic, format!("receive: {e}")))
    }

    pub(crate) fn try_recv(&self) -> Result<Option<Sample>> {
        let got = match &self.queue {
            SubscriberQueue::Fifo(s) => s.try_recv(),
            SubscriberQueue::Ring(s) => s.try_recv(),
        };
        got.map_err(|e| err(&self.topic, format!("receive: {e}")))
    }
}

/// Opens a zenoh router session listening on `endpoint` (the graph's router, run by a launcher).
pub fn open_router(endpoint: &str, tls: Option<&crate::config::TlsConfig>) -> Result<zenoh::Session, String> {
    let mut config = zenoh::Config::default();
    let mut settings = vec![
        ("mode", "\"router\"".to_string()),
        ("listen/endpoints", serde_json::to_string(&[endpoint]).expect("strings serialise")),
        ("scouting/multicast/enabled", "false".to_string()),
    ];
    settings.extend(tls_settings(tls));
    for (key, value) in settings {
        config.insert_json5(key, &value).map_err(|e| format!("config {key} = {value}: {e}"))?;
    }
    zenoh::open(config).wait().map_err(|e| format!("open router on {endpoint}: {e}"))
}

/// Launchers of one graph on several hosts agree through zenoh liveliness tokens
/// `<prefix>/<host>/<state>`: a token lives while its launcher says so and vanishes when the
/// launcher's session goes (a host that disappears loses its tokens after zenoh's lease).
pub struct HostSync {
    session: zenoh::Session,
    prefix: String,
    tokens: std::collections::BTreeMap<String, zenoh::liveliness::LivelinessToken>,
    watch: zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>,
    /// `(host, state)` pairs currently alive.
    alive: std::collections::BTreeSet<(String, String)>,
}

impl HostSync {
    pub fn new(session: &zenoh::Session, prefix: &str) -> Result<HostSync, String> {
        let watch = session
            .liveliness()
            .declare_subscriber(format!("{prefix}/**"))
            .history(true)
            .with(zenoh::handlers::FifoChannel::new(256))
            .wait()
            .map_err(|e| format!("watch liveliness `{prefix}/**`: {e}"))?;
        Ok(HostSync {
            session: session.clone(),
            prefix: prefix.to_string(),
            tokens: Default::default(),
            watch,
            alive: Default::default(),
        })
    }

    /// Declares `state` of `host` alive (idempotent).
    pub fn declare(&mut self, host: &str, state: &str) -> Result<(), String> {
        let key = format!("{}/{host}/{state}", self.prefix);
        if !self.tokens.contains_key(&key) {
            let token = self
                .session
                .liveliness()
                .declare_token(key.clone())
                .wait()
                .map_err(|e| format!("declare liveliness `{key}`: {e}"))?;
            self.tokens.insert(key, token);
        }
        Ok(())
    }

    /// Withdraws `state` of `host`.
    pub fn withdraw(&mut self, host: &str, state: &str) {
        let key = format!("{}/{host}/{state}", self.prefix);
        if let Some(token) = self.tokens.remove(&key) {
            if let Err(e) = token.undeclare().wait() {
                tracing::warn!("undeclare liveliness `{key}`: {e}");
            }
        }
    }

    /// The `(host, state)` pairs alive now, as far as this launcher has heard.
    pub fn alive(&mut self) -> &std::collections::BTreeSet<(String, String)> {
        while let Ok(Some(sample)) = self.watch.try_recv() {
            let key = sample.key_expr().as_str();
            let Some(rest) = key.strip_prefix(&self.prefix).map(|r| r.trim_start_matches('/')) else { continue };
            let Some((host, state)) = rest.split_once('/') else { continue };
            let entry = (host.to_string(), state.to_string());
            match sample.kind() {
                zenoh::sample::SampleKind::Put => self.alive.insert(entry),
                zenoh::sample::SampleKind::Delete => self.alive.remove(&entry),
            };
        }
        &self.alive
    }
}

/// Every Deep Contact topic with a publisher or subscriber reachable over zenoh through
/// `endpoint` (a node's or a graph's router's), from their liveliness tokens: writers, readers
/// and delivery per topic, sorted; `namespace` keeps one namespace. Listens for `wait`, long
/// enough for the gossip of a graph's peers to reach this session.
pub fn live_topics_zenoh(
    endpoint: &str,
    namespace: Option<&str>,
    wait: Duration,
) -> Result<Vec<crate::iox::LiveTopic>, String> {
    let config = ZenohConfig { connect: vec![endpoint.to_string()], ..Default::default() };
    let session = open_session(&config)?;
    // A query sent before this session has learnt the graph's routes comes back empty at once:
    // ask until two answers in a row agree and are not empty, or `wait` passes.
    let started = Instant::now();
    let mut tokens = std::collections::BTreeSet::new();
    loop {
        let replies = session
            .liveliness()
            .get("dc/**")
            .timeout(wait)
            .wait()
            .map_err(|e| format!("liveliness query through {endpoint}: {e}"))?;
        let mut now = std::collections::BTreeSet::new();
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                now.insert(sample.key_expr().as_str().to_string());
            }
        }
        let settled = !now.is_empty() && now == tokens;
        tokens = now;
        if settled || started.elapsed() >= wait {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut topics: std::collections::BTreeMap<(String, String), crate::iox::LiveTopic> = Default::default();
    for key in &tokens {
        let Some((ns, topic, writer, best_effort)) = parse_port_token(key) else { continue };
        if namespace.is_some_and(|want| want != ns) {
            continue;
        }
        let entry = topics.entry((ns.clone(), topic.clone())).or_insert_with(|| crate::iox::LiveTopic {
            namespace: ns,
            topic,
            writers: 0,
            readers: 0,
            best_effort: false,
        });
        if writer {
            entry.writers += 1;
            entry.best_effort |= best_effort;
        } else {
            entry.readers += 1;
        }
    }
    Ok(topics.into_values().collect())
}

/// `(namespace, topic, is a writer, best effort)` of a port's liveliness token
/// (`dc/<ns>/<topic>/_writers/<zid>/<n>/<delivery>`, `dc/<ns>/<topic>/_readers/<zid>/<n>`).
fn parse_port_token(key: &str) -> Option<(String, String, bool, bool)> {
    let rest = key.strip_prefix("dc/")?;
    let (path, writer, tail) = if let Some((p, t)) = rest.split_once(&format!("/{WRITERS}/")) {
        (p, true, t)
    } else {
        let (p, t) = rest.split_once(&format!("/{READERS}/"))?;
        (p, false, t)
    };
    // `dc/<topic>` (no namespace) first: `grid/bodies` is a topic, not `bodies` in `grid`.
    let (ns, topic) = if msgs::topics::info(path).is_some() {
        ("", path)
    } else {
        let (ns, topic) = path.split_once('/')?;
        msgs::topics::info(topic)?;
        (ns, topic)
    };
    Some((ns.to_string(), topic.to_string(), writer, writer && tail.ends_with("/best-effort")))
}

#[cfg(test)]
mod token_tests {
    use super::*;

    #[test]
    fn port_tokens_name_namespace_topic_and_delivery() {
        let w = "dc/eval-1/stats/solve/_writers/abc/3/best-effort";
        assert_eq!(parse_port_token(w), Some(("eval-1".into(), "stats/solve".into(), true, true)));
        let r = "dc/eval-1/bodies/_readers/abc/4";
        assert_eq!(parse_port_token(r), Some(("eval-1".into(), "bodies".into(), false, false)));
        assert_eq!(
            parse_port_token("dc/grid/bodies/_writers/z/1/reliable"),
            Some(("".into(), "grid/bodies".into(), true, false))
        );
        assert_eq!(parse_port_token("dc/ns/nothing/_readers/z/1"), None);
        assert_eq!(parse_port_token("dc/graph-1234/a"), None);
    }
}
