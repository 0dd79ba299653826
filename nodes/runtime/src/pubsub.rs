//! Typed publishers and subscribers over whichever transport the bus configuration names.

use crate::iox::{IoxPublisher, IoxSample, IoxSubscriber};
use crate::zen::{ZenPublisher, ZenSubscriber};
use crate::{Error, Result, ShutdownSignal};
use msgs::{Frame, FrameHeader, FrameItem};
use std::time::{Duration, Instant};

/// Publishes frames of one topic.
pub struct Publisher<H: FrameHeader, T: FrameItem> {
    topic: String,
    iox: Option<std::rc::Rc<IoxPublisher<H, T>>>,
    zen: Option<ZenPublisher>,
    scratch: Vec<T>,
    sent: u64,
}

impl<H: FrameHeader, T: FrameItem> Publisher<H, T> {
    pub(crate) fn new(topic: &str, iox: Option<std::rc::Rc<IoxPublisher<H, T>>>, zen: Option<ZenPublisher>) -> Self {
        Publisher { topic: topic.to_string(), iox, zen, scratch: Vec::new(), sent: 0 }
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Frames sent so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Publishes `header` and a copy of `items`.
    pub fn publish(&mut self, header: &H, items: &[T]) -> Result<()> {
        if let Some(iox) = &self.iox {
            iox.send_slice(header, items)?;
        }
        if let Some(zen) = &mut self.zen {
            zen.send(header, items)?;
        }
        self.sent += 1;
        Ok(())
    }

    pub fn publish_frame(&mut self, frame: &Frame<H, T>) -> Result<()> {
        self.publish(&frame.header, &frame.items)
    }

    /// Publishes a frame already encoded as CBOR (a recording being replayed). Over zenoh the bytes
    /// go out untouched; iceoryx2 needs the decoded frame, so a payload that does not decode is an
    /// error naming the topic.
    pub fn publish_encoded(&mut self, bytes: &[u8]) -> Result<()> {
        if let Some(iox) = &self.iox {
            let frame =
                msgs::decode::<H, T>(bytes).map_err(|source| Error::Codec { topic: self.topic.clone(), source })?;
            iox.send_slice(&frame.header, &frame.items)?;
        }
        if let Some(zen) = &mut self.zen {
            zen.send_encoded(bytes)?;
        }
        self.sent += 1;
        Ok(())
    }

    /// Publishes `len` items that `fill` writes in place, with the header (`H::default()` to
    /// start from) that `fill` may complete: in shared memory on iceoryx2 (zero copy), in a reused
    /// buffer on zenoh.
    pub fn publish_with(&mut self, len: usize, fill: impl FnOnce(&mut H, &mut [T])) -> Result<()> {
        match (&self.iox, &mut self.zen) {
            (Some(iox), zen) => iox.send_with(len, fill, |header, items| match zen {
                Some(z) => z.send(header, items),
                None => Ok(()),
            })?,
            (None, Some(zen)) => {
                self.scratch.clear();
                self.scratch.resize(len, T::default());
                let mut header = H::default();
                fill(&mut header, &mut self.scratch);
                zen.send(&header, &self.scratch)?;
            }
            (None, None) => {}
        }
        self.sent += 1;
        Ok(())
    }
}

/// A received frame: read in place from shared memory (iceoryx2) or decoded (zenoh).
pub enum Received<H: FrameHeader, T: FrameItem> {
    Shared(IoxSample<H, T>),
    Owned(Frame<H, T>),
}

impl<H: FrameHeader, T: FrameItem> Received<H, T> {
    pub fn header(&self) -> &H {
        match self {
            Received::Shared(s) => s.user_header(),
            Received::Owned(f) => &f.header,
        }
    }

    pub fn items(&self) -> &[T] {
        match self {
            Received::Shared(s) => s.payload(),
            Received::Owned(f) => &f.items,
        }
    }

    /// Copies the frame out (releases the shared-memory sample).
    pub fn to_frame(&self) -> Frame<H, T> {
        match self {
            Received::Shared(s) => Frame::new(*s.user_header(), s.payload().to_vec()),
            Received::Owned(f) => f.clone(),
        }
    }

    pub fn into_frame(self) -> Frame<H, T> {
        match self {
            Received::Owned(f) => f,
            shared => shared.to_frame(),
        }
    }
}

pub(crate) enum SubInner<H: FrameHeader, T: FrameItem> {
    Iox(std::rc::Rc<IoxSubscriber<H, T>>),
    Zenoh(ZenSubscriber),
    /// Publishers on this host and on others.
    Both(std::rc::Rc<IoxSubscriber<H, T>>, ZenSubscriber),
    /// No transport (a node describing its ports): never receives.
    Detached,
}

/// Receives frames of one topic, in order.
pub struct Subscriber<H: FrameHeader, T: FrameItem> {
    topic: String,
    inner: SubInner<H, T>,
    shutdown: ShutdownSignal,
    received: u64,
    decode_errors: u64,
}

/// A receive shorter than this is polled instead of slept (see [`Subscriber::recv_timeout`]).
const EXACT_WAIT: Duration = Duration::from_millis(5);

/// How often a blocked receive looks at the shutdown signal.
const SHUTDOWN_POLL: Duration = Duration::from_millis(100);

impl<H: FrameHeader, T: FrameItem> Subscriber<H, T> {
    pub(crate) fn new(topic: &str, inner: SubInner<H, T>, shutdown: ShutdownSignal) -> Self {
        Subscriber { topic: topic.to_string(), inner, shutdown, received: 0, decode_errors: 0 }
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Frames received so far.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Payloads that failed to decode (logged and skipped; the subscriber keeps running).
    pub fn decode_errors(&self) -> u64 {
        self.decode_errors
    }

    /// The next frame if one is waiting.
    pub fn try_recv(&mut self) -> Result<Option<Received<H, T>>> {
        loop {
            let (iox, zen) = match &self.inner {
                SubInner::Iox(i) => (Some(i), None),
                SubInner::Zenoh(z) => (None, Some(z)),
                SubInner::Both(i, z) => (Some(i), Some(z)),
                SubInner::Detached => (None, None),
            };
            let mut got = match iox {
                Some(i) => i.try_recv()?.map(Received::Shared),
                None => None,
            };
            if got.is_none() {
                if let Some(sample) = zen.map(ZenSubscriber::try_recv).transpose()?.flatten() {
                    match self.decode(&sample) {
                        Some(frame) => got = Some(Received::Owned(frame)),
                        None => continue,
                    }
                }
            }
            if got.is_some() {
                self.received += 1;
            }
            return Ok(got);
        }
    }

    /// Waits up to `timeout` for the next frame without spinning; `None` on timeout or when the
    /// node shuts down meanwhile.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<Received<H, T>>> {
        let deadline = Instant::now() + timeout;
        // The event wait's timeout is a socket timeout, counted in the kernel's ticks (1-4 ms):
        // a receive shorter than a few ticks (a deadline of a few hundred microseconds) is
        // polled, so that it ends on time (a late frame is then late, not waited for). Longer
        // receives sleep: a tick more is nothing to them, and idle nodes must not spin.
        let exact = timeout < EXACT_WAIT;
        loop {
            if let Some(r) = self.try_recv()? {
                return Ok(Some(r));
            }
            let now = Instant::now();
            if now >= deadline || self.shutdown.is_set() {
                return Ok(None);
            }
            let left = (deadline - now).min(SHUTDOWN_POLL);
            match &self.inner {
                SubInner::Iox(_) if exact => std::thread::yield_now(),
                SubInner::Iox(s) => s.wait(left)?,
                // Two sources and no common wait: short naps (this is the bridge case only).
                SubInner::Both(..) => std::thread::sleep(left.min(Duration::from_millis(1))),
                SubInner::Detached => std::thread::sleep(left),
                SubInner::Zenoh(s) => {
                    if let Some(sample) = s.recv_timeout(left)? {
                        if let Some(frame) = self.decode(&sample) {
                            self.received += 1;
                            return Ok(Some(Received::Owned(frame)));
                        }
                    }
                }
            }
        }
    }

    /// Waits for the next frame until the node shuts down (then `None`).
    pub fn recv(&mut self) -> Result<Option<Received<H, T>>> {
        loop {
            if self.shutdown.is_set() {
                return Ok(None);
            }
            if let Some(r) = self.recv_timeout(Duration::from_secs(3600))? {
                return Ok(Some(r));
            }
        }
    }

    fn decode(&mut self, sample: &zenoh::sample::Sample) -> Option<Frame<H, T>> {
        let payload = sample.payload();
        // A large frame arrives in pieces (zenoh's fragments): read across them, copying the
        // items once; a frame in one piece is decoded in place.
        let mut pieces = payload.slices();
        if let (Some(_), Some(_)) = (pieces.next(), pieces.next()) {
            if let Some(frame) = msgs::decode_reader::<H, T>(payload.reader()) {
                return Some(frame);
            }
        }
        let bytes = payload.to_bytes();
        match msgs::decode::<H, T>(&bytes) {
            Ok(frame) => Some(frame),
            Err(source) => {
                self.decode_errors += 1;
                let e = Error::Codec { topic: self.topic.clone(), source };
                tracing::error!(key = %sample.key_expr(), errors = self.decode_errors, "dropped a payload: {e}");
                None
            }
        }
    }
}
