//! iceoryx2 transport: each topic is a publish-subscribe service of `[T]` slices with user header
//! `H`, paired with an event service so a waiting subscriber sleeps on a file descriptor instead of
//! spinning (iceoryx2 pub/sub has no blocking receive).
//!
//! Settings chosen against iceoryx2 0.10 defaults:
//! - `enable_safe_overflow(false)` + `RetryUntilDelivered`: a full subscriber queue holds the
//!   publisher back instead of silently overwriting unread samples; a best-effort topic
//!   ([`BusConfig::best_effort`]) enables safe overflow instead: the oldest unread sample goes;
//! - `AllocationStrategy::PowerOfTwo`: slices may grow (contacts 0 -> 30,000) past the initial size;
//! - limits raised above the defaults (2 publishers, buffer 2, 20 nodes), too small for our graphs.

use crate::config::{BusConfig, Error, Result};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use std::time::Duration;

type PubSubFactory<H, T> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [T], H>;

pub(crate) struct IoxNode {
    node: Node<ipc::Service>,
}

fn err(topic: &str, what: impl std::fmt::Display) -> Error {
    Error::Iceoryx2 { topic: topic.to_string(), what: what.to_string() }
}

fn service_name(bus: &BusConfig, topic: &str, suffix: &str) -> Result<ServiceName> {
    let name = format!("{}{suffix}", bus.iox_key(topic));
    ServiceName::new(&name).map_err(|e| err(topic, format!("invalid service name `{name}`: {e:?}")))
}

/// Most writers of one topic on one host (every simulator of `dc eval --jobs N` and the
/// launcher write `control`): iceoryx2 sizes a service for them when it is created, and the
/// launcher's check refuses a graph that needs more (naming the topic and its writers).
pub const MAX_PUBLISHERS: usize = 32;
/// Most readers of one topic on one host.
pub const MAX_SUBSCRIBERS: usize = 64;
/// Most processes using one topic on one host.
pub const MAX_NODES: usize = 128;

/// Whether `name` can name a graph node: the runtime names its iceoryx2 node after it and cannot
/// start under a name iceoryx2 refuses, so the launcher applies this rule when it reads a file.
pub fn check_node_name(name: &str) -> std::result::Result<(), String> {
    if name.len() > NodeName::max_len() {
        return Err(format!("{} bytes, more than the {} a node name may have", name.len(), NodeName::max_len()));
    }
    NodeName::new(name).map(|_| ()).map_err(|e| format!("not a valid iceoryx2 node name ({e:?})"))
}

impl IoxNode {
    pub(crate) fn new(name: &str) -> Result<IoxNode> {
        quiet_iceoryx2_logs();
        let node_name = NodeName::new(name).map_err(|e| Error::Node(format!("invalid node name `{name}`: {e:?}")))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            // Signals are ours (ctrlc): the node's shutdown flag drives every loop.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| Error::Node(format!("{e:?}")))?;
        Ok(IoxNode { node })
    }

    fn pubsub<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &self,
        bus: &BusConfig,
        topic: &str,
    ) -> Result<PubSubFactory<H, T>> {
        let builder =
            self.node.service_builder(&service_name(bus, topic, "")?).publish_subscribe::<[T]>().user_header::<H>();
        if bus.observe {
            // An observer takes the topic as its graph made it (delivery, queue sizes) and never
            // creates one: no graph, no topic.
            return builder.open().map_err(|e| err(topic, format!("open publish-subscribe service: {e:?}")));
        }
        builder
            .enable_safe_overflow(bus.is_best_effort(topic))
            .subscriber_max_buffer_size(bus.queue_depth.max(1))
            .history_size(0)
            .max_publishers(MAX_PUBLISHERS)
            .max_subscribers(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| err(topic, format!("open publish-subscribe service: {e:?}")))
    }

    fn event(
        &self,
        bus: &BusConfig,
        topic: &str,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>> {
        let builder = self.node.service_builder(&service_name(bus, topic, "/@event")?).event();
        if bus.observe {
            return builder.open().map_err(|e| err(topic, format!("open event service: {e:?}")));
        }
        builder
            .max_notifiers(MAX_PUBLISHERS)
            .max_listeners(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| err(topic, format!("open event service: {e:?}")))
    }

    pub(crate) fn publisher<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &self,
        bus: &BusConfig,
        topic: &str,
    ) -> Result<IoxPublisher<H, T>> {
        let service = self.pubsub::<H, T>(bus, topic)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(1024)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .create()
            .map_err(|e| {
                let writers = service.dynamic_config().number_of_publishers();
                err(topic, format!("create publisher: {e:?} ({writers} writers, at most {MAX_PUBLISHERS})"))
            })?;
        let notifier = self
            .event(bus, topic)?
            .notifier_builder()
            .create()
            .map_err(|e| err(topic, format!("create notifier: {e:?}")))?;
        Ok(IoxPublisher { topic: topic.to_string(), publisher, notifier })
    }

    pub(crate) fn subscriber<H: msgs::FrameHeader, T: msgs::FrameItem>(
        &self,
        bus: &BusConfig,
        topic: &str,
    ) -> Result<IoxSubscriber<H, T>> {
        let service = self.pubsub::<H, T>(bus, topic)?;
        // An observer's queue is as deep as the service allows: it holds a reliable topic's
        // writer back only when that much is unread.
        let depth =
            if bus.observe { service.static_config().subscriber_max_buffer_size() } else { bus.queue_depth.max(1) };
        let subscriber = service
            .subscriber_builder()
            .buffer_size(depth)
            .create()
            .map_err(|e| err(topic, format!("create subscriber: {e:?}")))?;
        let listener = self
            .event(bus, topic)?
            .listener_builder()
            .create()
            .map_err(|e| err(topic, format!("create listener: {e:?}")))?;
        Ok(IoxSubscriber { topic: topic.to_string(), subscriber, listener })
    }
}

pub(crate) struct IoxPublisher<H: msgs::FrameHeader, T: msgs::FrameItem> {
    topic: String,
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [T], H>,
    notifier: Notifier<ipc::Service>,
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> IoxPublisher<H, T> {
    /// Loans `len` elements in shared memory, lets `fill` write header and items in place, hands
    /// the frame (still in shared memory) to `after`, sends, and wakes the subscribers.
    pub(crate) fn send_with(
        &self,
        len: usize,
        fill: impl FnOnce(&mut H, &mut [T]),
        after: impl FnOnce(&H, &[T]) -> Result<()>,
    ) -> Result<()> {
        let sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| err(&self.topic, format!("loan {len} elements: {e:?}")))?;
        let mut sample = sample.write_from_fn(|_| T::default());
        let mut header = H::default();
        fill(&mut header, sample.payload_mut());
        *sample.user_header_mut() = header;
        after(&header, sample.payload())?;
        sample.send().map_err(|e| err(&self.topic, format!("send: {e:?}")))?;
        self.notifier.notify().map_err(|e| err(&self.topic, format!("notify: {e:?}")))?;
        Ok(())
    }

    /// Copies `items` into a loaned slice and sends it.
    pub(crate) fn send_slice(&self, header: &H, items: &[T]) -> Result<()> {
        let mut sample = self
            .publisher
            .loan_slice_uninit(items.len())
            .map_err(|e| err(&self.topic, format!("loan {} elements: {e:?}", items.len())))?;
        *sample.user_header_mut() = *header;
        let sample = sample.write_from_slice(items);
        sample.send().map_err(|e| err(&self.topic, format!("send: {e:?}")))?;
        self.notifier.notify().map_err(|e| err(&self.topic, format!("notify: {e:?}")))?;
        Ok(())
    }
}

/// A subscriber that can attach to its publishers' connections before data flows.
pub(crate) trait Attach {
    fn attach(&self);
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> Attach for IoxSubscriber<H, T> {
    fn attach(&self) {
        // `has_samples` updates the connections without taking a sample.
        if let Err(e) = self.subscriber.has_samples() {
            tracing::warn!(topic = %self.topic, "attaching to publishers: {e:?}");
        }
    }
}

pub(crate) type IoxSample<H, T> = iceoryx2::sample::Sample<ipc::Service, [T], H>;

pub(crate) struct IoxSubscriber<H: msgs::FrameHeader, T: msgs::FrameItem> {
    topic: String,
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, [T], H>,
    listener: Listener<ipc::Service>,
}

impl<H: msgs::FrameHeader, T: msgs::FrameItem> IoxSubscriber<H, T> {
    pub(crate) fn try_recv(&self) -> Result<Option<IoxSample<H, T>>> {
        self.subscriber.receive().map_err(|e| err(&self.topic, format!("receive: {e:?}")))
    }

    /// Sleeps on the topic's event until a notification or `timeout`.
    pub(crate) fn wait(&self, timeout: Duration) -> Result<()> {
        match self.listener.timed_wait(|_| {}, timeout) {
            // A signal (Ctrl-C, the launcher's SIGTERM) interrupts the wait; the caller then sees
            // the node's shutdown flag, which the signal handler set.
            Ok(_) | Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => Ok(()),
            Err(e) => Err(err(&self.topic, format!("wait for event: {e:?}"))),
        }
    }
}

/// iceoryx2 logs to stderr on its own (e.g. that no config file exists, which is our normal case);
/// only its errors matter to a node's log unless `IOX2_LOG_LEVEL` says otherwise.
fn quiet_iceoryx2_logs() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| set_log_level_from_env_or(LogLevel::Error));
}

pub(crate) fn cleanup_dead_nodes() -> Result<usize> {
    quiet_iceoryx2_logs();
    let mut cleaned = 0;
    let mut failures = Vec::new();
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) => cleaned += 1,
                Err(e) => failures.push(format!("{e:?}")),
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| Error::Node(format!("list nodes: {e:?}")))?;
    for f in failures {
        tracing::warn!("could not clean a dead iceoryx2 node: {f}");
    }
    Ok(cleaned)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_longest_namespace_gives_valid_service_names() {
        let bus = BusConfig {
            namespace: "n".repeat(crate::config::MAX_NAMESPACE_LEN),
            host: "a-host-name-of-some-length".into(),
            ..BusConfig::default()
        };
        let longest = msgs::topics::TABLE.iter().map(|t| t.name).max_by_key(|n| n.len()).unwrap();
        assert!(service_name(&bus, longest, "/@event").is_ok());
    }

    #[test]
    fn a_node_name_iceoryx2_refuses_is_refused_by_the_check_too() {
        let longest = "n".repeat(NodeName::max_len());
        assert!(check_node_name(&longest).is_ok() && IoxNode::new(&longest).is_ok());
        let e = check_node_name(&format!("{longest}n")).unwrap_err();
        assert!(e.contains(&format!("more than the {}", NodeName::max_len())), "{e}");
    }
}

/// A topic alive on this host's iceoryx2 bus: its namespace (with `@host` for a host of a
/// multi-host graph), its writers and readers now, and whether it is delivered best effort.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveTopic {
    pub namespace: String,
    pub topic: String,
    pub writers: usize,
    pub readers: usize,
    pub best_effort: bool,
}

/// Every Deep Contact topic with a service on this host (`dc/<namespace>/<topic>`), sorted by
/// namespace and topic; `namespace` keeps one namespace (and its hosts' `NS@host`). Writers and
/// readers are counted on each topic's event service (one notifier per writer, one listener per
/// reader), which any process may open without joining the topic.
pub fn live_topics(namespace: Option<&str>) -> Result<Vec<LiveTopic>> {
    live_topics_on(&IoxNode::new("dc-topic-list")?, namespace)
}

/// [`live_topics`] through a node this process already has (an observer counting writers).
pub(crate) fn live_topics_on(node: &IoxNode, namespace: Option<&str>) -> Result<Vec<LiveTopic>> {
    use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;
    quiet_iceoryx2_logs();
    let mut found: Vec<(String, String, bool)> = Vec::new();
    <ipc::Service as iceoryx2::service::Service>::list(Config::global_config(), |details| {
        let config = &details.static_details;
        if let StaticPattern::PublishSubscribe(pubsub) = config.messaging_pattern() {
            let name = config.name().as_str();
            if let Some((ns, topic)) = name.strip_prefix("dc/").and_then(|rest| rest.split_once('/')) {
                let keep = namespace.is_none_or(|want| ns == want || ns.starts_with(&format!("{want}@")));
                if keep && msgs::topics::info(topic).is_some() {
                    found.push((ns.to_string(), topic.to_string(), pubsub.has_safe_overflow()));
                }
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| Error::Node(format!("listing iceoryx2 services: {e:?}")))?;
    found.sort();
    let mut topics = Vec::new();
    for (ns, topic, best_effort) in found {
        let name = format!("dc/{ns}/{topic}/@event");
        let service_name = ServiceName::new(&name).map_err(|e| err(&topic, format!("{e:?}")))?;
        // A service whose last user just left may be gone already: not alive, not listed.
        let Ok(events) = node.node.service_builder(&service_name).event().open() else { continue };
        let dynamic = events.dynamic_config();
        let (writers, readers) = (dynamic.number_of_notifiers(), dynamic.number_of_listeners());
        topics.push(LiveTopic { namespace: ns, topic, writers, readers, best_effort });
    }
    Ok(topics)
}
