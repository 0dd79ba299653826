//! The transports used directly, as their own documentation shows, without `runtime`'s ports: the
//! baseline our layer is measured against. Same process layout (a source and a sink process started
//! by the launcher), same payload types and sizes, same delivery (reliable: iceoryx2 retries until
//! delivered with an event to wake the sink, zenoh blocks on congestion into a FIFO of the same
//! depth), same zenoh endpoints. What is left out is exactly what `runtime` adds: CBOR framing,
//! the header/item split, the ready barrier's subscriber bookkeeping, statistics and errors.
//!
//! A raw frame over zenoh is the header's bytes followed by the items' bytes, handed to zenoh in a
//! buffer it takes over (no copy).

use anyhow::{anyhow, Context, Result};
use iceoryx2::prelude::*;
use msgs::{FrameHeader, FrameItem};
use runtime::Node;
use std::time::{Duration, Instant};
use zenoh::Wait;

type IoxService<H, T> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [T], H>;

/// iceoryx2's publish-subscribe service of `topic` and its wake-up event, as the runtime names
/// them (so the launcher's cleanup covers them) but opened here.
fn iox_services<H: FrameHeader, T: FrameItem>(
    node: &Node,
    iox: &iceoryx2::node::Node<ipc::Service>,
    topic: &str,
) -> Result<(IoxService<H, T>, iceoryx2::service::port_factory::event::PortFactory<ipc::Service>)> {
    let bus = node.bus();
    let name = format!("{}-raw", bus.iox_key(topic));
    let service = iox
        .service_builder(&ServiceName::new(&name).map_err(|e| anyhow!("{e:?}"))?)
        .publish_subscribe::<[T]>()
        .user_header::<H>()
        .enable_safe_overflow(false)
        .subscriber_max_buffer_size(bus.queue_depth.max(1))
        .history_size(0)
        .open_or_create()
        .map_err(|e| anyhow!("raw iceoryx2 service `{name}`: {e:?}"))?;
    let event = iox
        .service_builder(&ServiceName::new(&format!("{name}/@event")).map_err(|e| anyhow!("{e:?}"))?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow!("raw iceoryx2 event `{name}`: {e:?}"))?;
    Ok((service, event))
}

fn iox_node(node: &Node) -> Result<iceoryx2::node::Node<ipc::Service>> {
    let name = NodeName::new(&format!("{}-raw", node.name())).map_err(|e| anyhow!("{e:?}"))?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("raw iceoryx2 node: {e:?}"))
}

/// The zenoh session of a raw port: the node's endpoints (so it meets its peer), zenoh's defaults
/// for everything else.
fn zenoh_session(node: &Node) -> Result<zenoh::Session> {
    runtime::open_zenoh_session(&node.bus().zenoh).map_err(|e| anyhow!("raw zenoh session: {e}"))
}

/// Publishes frames of `len` items through a transport's own API. (One per process: the
/// variants' sizes do not matter.)
#[allow(clippy::large_enum_variant)]
pub enum RawPublisher<H: FrameHeader, T: FrameItem> {
    Iceoryx2 {
        _node: iceoryx2::node::Node<ipc::Service>,
        service: IoxService<H, T>,
        publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [T], H>,
        notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
    },
    Zenoh {
        _session: zenoh::Session,
        publisher: zenoh::pubsub::Publisher<'static>,
        scratch: Vec<T>,
    },
}

impl<H: FrameHeader, T: FrameItem> RawPublisher<H, T> {
    pub fn new(node: &Node, topic: &str, len: usize) -> Result<Self> {
        if node.bus().transport(topic).uses_zenoh() {
            let session = zenoh_session(node)?;
            let publisher = session
                .declare_publisher(format!("{}-raw", node.bus().key(topic)))
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .wait()
                .map_err(|e| anyhow!("raw zenoh publisher: {e}"))?;
            return Ok(RawPublisher::Zenoh { _session: session, publisher, scratch: Vec::new() });
        }
        let iox = iox_node(node)?;
        let (service, event) = iox_services::<H, T>(node, &iox, topic)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(len)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .create()
            .map_err(|e| anyhow!("raw iceoryx2 publisher: {e:?}"))?;
        let notifier = event.notifier_builder().create().map_err(|e| anyhow!("raw iceoryx2 notifier: {e:?}"))?;
        Ok(RawPublisher::Iceoryx2 { _node: iox, service, publisher, notifier })
    }

    /// Waits until a subscriber is there (zenoh's matching status; iceoryx2's service count).
    pub fn wait_for_subscriber(&self, timeout: Duration) -> Result<()> {
        let start = Instant::now();
        while !self.has_subscribers()? {
            if start.elapsed() > timeout {
                anyhow::bail!("no raw subscriber after {timeout:?}");
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        Ok(())
    }

    fn has_subscribers(&self) -> Result<bool> {
        Ok(match self {
            RawPublisher::Iceoryx2 { service, .. } => service.dynamic_config().number_of_subscribers() > 0,
            RawPublisher::Zenoh { publisher, .. } => {
                publisher.matching_status().wait().map_err(|e| anyhow!("{e}"))?.matching()
            }
        })
    }

    /// Keeps the publisher (its shared memory, its links) until the subscriber has left: it may
    /// still be reading the last frames.
    pub fn wait_until_unsubscribed(&self, stopped: impl Fn() -> bool) -> Result<()> {
        while self.has_subscribers()? && !stopped() {
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// Sends `len` items that `fill` writes in place (starting from their defaults, as iceoryx2's
    /// `loan_slice` gives them) and the header `header()` gives once they are written (the send
    /// time is taken then). Over zenoh the items are filled in `scratch` and copied once into the
    /// buffer zenoh takes over.
    pub fn send(&mut self, len: usize, fill: impl FnOnce(&mut [T]), header: impl FnOnce() -> H) -> Result<()> {
        match self {
            RawPublisher::Iceoryx2 { publisher, notifier, .. } => {
                let mut sample = publisher.loan_slice(len).map_err(|e| anyhow!("loan: {e:?}"))?;
                fill(sample.payload_mut());
                *sample.user_header_mut() = header();
                sample.send().map_err(|e| anyhow!("send: {e:?}"))?;
                notifier.notify().map_err(|e| anyhow!("notify: {e:?}"))?;
            }
            RawPublisher::Zenoh { publisher, scratch, .. } => {
                scratch.clear();
                scratch.resize(len, T::default());
                fill(scratch);
                let header = header();
                let mut bytes =
                    Vec::with_capacity(std::mem::size_of::<H>() + std::mem::size_of_val(scratch.as_slice()));
                bytes.extend_from_slice(bytemuck::bytes_of(&header));
                bytes.extend_from_slice(bytemuck::cast_slice(scratch));
                publisher.put(bytes).wait().map_err(|e| anyhow!("put: {e}"))?;
            }
        }
        Ok(())
    }
}

/// Receives raw frames.
#[allow(clippy::large_enum_variant)]
pub enum RawSubscriber<H: FrameHeader, T: FrameItem> {
    Iceoryx2 {
        _node: iceoryx2::node::Node<ipc::Service>,
        subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, [T], H>,
        listener: iceoryx2::port::listener::Listener<ipc::Service>,
    },
    Zenoh {
        _session: zenoh::Session,
        subscriber: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    },
}

impl<H: FrameHeader, T: FrameItem> RawSubscriber<H, T> {
    pub fn new(node: &Node, topic: &str) -> Result<Self> {
        let depth = node.bus().queue_depth.max(1);
        if node.bus().transport(topic).uses_zenoh() {
            let session = zenoh_session(node)?;
            let subscriber = session
                .declare_subscriber(format!("{}-raw", node.bus().key(topic)))
                // The runtime's zenoh subscribers queue 16 frames per iceoryx2 slot.
                .with(zenoh::handlers::FifoChannel::new(depth * 16))
                .wait()
                .map_err(|e| anyhow!("raw zenoh subscriber: {e}"))?;
            return Ok(RawSubscriber::Zenoh { _session: session, subscriber });
        }
        let iox = iox_node(node)?;
        let (service, event) = iox_services::<H, T>(node, &iox, topic)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(depth)
            .create()
            .map_err(|e| anyhow!("raw iceoryx2 subscriber: {e:?}"))?;
        // Connects to the publishers now, so the first frames are delivered with back-pressure.
        subscriber.has_samples().map_err(|e| anyhow!("raw iceoryx2 subscriber: {e:?}"))?;
        let listener = event.listener_builder().create().map_err(|e| anyhow!("raw iceoryx2 listener: {e:?}"))?;
        Ok(RawSubscriber::Iceoryx2 { _node: iox, subscriber, listener })
    }

    /// The next frame's header, and whether its items equal `expected(header)` (`None`: not
    /// checked), waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration, check: impl FnOnce(&H, &[u8]) -> bool) -> Result<Option<(H, bool)>> {
        match self {
            RawSubscriber::Iceoryx2 { subscriber, listener, .. } => {
                let deadline = Instant::now() + timeout;
                loop {
                    if let Some(sample) = subscriber.receive().map_err(|e| anyhow!("receive: {e:?}"))? {
                        let header = *sample.user_header();
                        let ok = check(&header, bytemuck::cast_slice(sample.payload()));
                        return Ok(Some((header, ok)));
                    }
                    let now = Instant::now();
                    if now >= deadline {
                        return Ok(None);
                    }
                    listener.timed_wait(|_| {}, deadline - now).map_err(|e| anyhow!("wait: {e:?}"))?;
                }
            }
            RawSubscriber::Zenoh { subscriber, .. } => {
                let Some(sample) = subscriber.recv_timeout(timeout).map_err(|e| anyhow!("receive: {e}"))? else {
                    return Ok(None);
                };
                let bytes = sample.payload().to_bytes();
                let h = std::mem::size_of::<H>();
                let header: H =
                    bytemuck::pod_read_unaligned(bytes.get(..h).context("raw frame shorter than a header")?);
                let ok = check(&header, &bytes[h..]);
                Ok(Some((header, ok)))
            }
        }
    }
}
