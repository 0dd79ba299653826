//! Typed publishers and subscribers over whichever transport the bus configuration names.

use crate::config::{Error, Result, ShutdownSignal};
use crate::iox::{IoxPublisher, IoxSample, IoxSubscriber};
use crate::zen::{ZenPublisher, ZenSubscriber};
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
        match decode_payload::<H, T>(sample.payload()) {
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

/// Decodes a zenoh payload. A large frame arrives in pieces (zenoh's fragments): read across
/// them, copying the items once; a frame in one piece is decoded in place. No length the
/// payload claims is trusted beyond the bytes it has (a peer may lie).
pub(crate) fn decode_payload<H: FrameHeader, T: FrameItem>(
    payload: &zenoh::bytes::ZBytes,
) -> std::result::Result<Frame<H, T>, msgs::CodecError> {
    let mut pieces = payload.slices();
    if let (Some(_), Some(_)) = (pieces.next(), pieces.next()) {
        if let Some(frame) = msgs::decode_reader::<H, T>(payload.reader(), payload.len()) {
            return Ok(frame);
        }
    }
    msgs::decode::<H, T>(&payload.to_bytes())
}

#[cfg(test)]
mod fuzz {
    //! The zenoh receive path fed fragmented and lying frames: no panic, no allocation beyond
    //! a bound (a claimed length is never allocated before the bytes are there), every valid
    //! frame decoded as sent.
    use super::decode_payload;
    use msgs::{Body, Control, Frame, StepHeader};
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;
    use zenoh::bytes::ZBytes;

    /// The largest single allocation of each thread (the other tests of this binary run
    /// beside this one and must not count).
    struct Largest;
    thread_local! {
        static LARGEST: Cell<usize> = const { Cell::new(0) };
    }
    fn note(size: usize) {
        let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
    }
    fn largest() -> usize {
        LARGEST.with(Cell::get)
    }
    fn reset() {
        LARGEST.with(|l| l.set(0));
    }
    unsafe impl GlobalAlloc for Largest {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            note(layout.size());
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            note(new_size);
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }
    #[global_allocator]
    static ALLOCATOR: Largest = Largest;

    /// xorshift64*: the cases are the same on every run.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n.max(1) as u64) as usize
        }
    }

    /// `bytes` as a payload in pieces of random sizes (zenoh's fragments).
    fn fragmented(rng: &mut Rng, bytes: &[u8]) -> ZBytes {
        let mut writer = ZBytes::writer();
        let mut rest = bytes;
        while !rest.is_empty() {
            let n = 1 + rng.below(rest.len().min(4096));
            writer.append(ZBytes::from(rest[..n].to_vec()));
            rest = &rest[n..];
        }
        writer.finish()
    }

    /// One lie or damage to an encoded frame.
    fn damage(rng: &mut Rng, b: &mut Vec<u8>) {
        let items_head = b.iter().rposition(|&x| x == 0x61).map(|p| p + 2).unwrap_or(0).min(b.len());
        match rng.below(6) {
            // The items' byte string claims a length (up to 2^63) it does not have.
            0 => {
                b.truncate(items_head);
                b.push(0x5b);
                b.extend_from_slice(&(1u64 << (20 + rng.below(44))).to_be_bytes());
                let pad = rng.below(300_000);
                b.resize(b.len() + pad, 0);
            }
            // A 4-byte length that lies.
            1 => {
                b.truncate(items_head);
                b.push(0x5a);
                b.extend_from_slice(&(rng.next() as u32).to_be_bytes());
                let pad = rng.below(5000);
                b.resize(b.len() + pad, 0xab);
            }
            // Cut anywhere.
            2 => {
                let cut = rng.below(b.len());
                b.truncate(cut);
            }
            // Random bytes flipped.
            3 => {
                for _ in 0..1 + rng.below(8) {
                    let i = rng.below(b.len());
                    b[i] = rng.next() as u8;
                }
            }
            // A header field's length or an array count claiming much more (header CBOR).
            4 => {
                let i = rng.below(items_head.max(1));
                b[i] = [0x5b, 0x7b, 0x9b, 0xbb][rng.below(4)];
            }
            // Garbage of any length.
            _ => {
                let n = rng.below(2000);
                *b = (0..n).map(|_| rng.next() as u8).collect();
            }
        }
    }

    #[test]
    fn lying_and_fragmented_frames_never_panic_or_allocate_what_they_claim() {
        let cases: u64 = std::env::var("DC_FUZZ_FRAMES").ok().and_then(|v| v.parse().ok()).unwrap_or(12_000);
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let bodies: Vec<Body> = (0..200).map(|i| Body { id: i, ..Default::default() }).collect();
        let valid = msgs::encode(&Frame::new(StepHeader { run_id: 7, simulation: 1, step: 2 }, bodies)).unwrap();
        let control = msgs::encode(&Frame::new(Control::default(), vec![1u8; 100])).unwrap();
        let (mut decoded, mut refused) = (0u64, 0u64);
        for case in 0..cases {
            reset();
            let mut bytes = if case % 2 == 0 { valid.clone() } else { control.clone() };
            let untouched = rng.below(10) == 0;
            if !untouched {
                damage(&mut rng, &mut bytes);
            }
            let largest_input = largest();
            reset();
            let payload = fragmented(&mut rng, &bytes);
            let ok = if case % 2 == 0 {
                let r = decode_payload::<StepHeader, Body>(&payload);
                if untouched {
                    assert_eq!(msgs::encode(r.as_ref().unwrap()).unwrap(), valid, "case {case}");
                }
                r.is_ok()
            } else {
                decode_payload::<Control, u8>(&payload).is_ok()
            };
            if ok {
                decoded += 1;
            } else {
                refused += 1;
            }
            // A decode allocates at most a few copies of what it was given (and small scratch).
            let bound = 4 * bytes.len().max(largest_input) + (1 << 20);
            let largest = largest();
            assert!(largest <= bound, "case {case}: allocated {largest} bytes for a {}-byte payload", bytes.len());
        }
        eprintln!("{cases} frames: {decoded} decoded, {refused} refused");
        assert!(refused > cases / 2 && decoded > cases / 20, "{decoded} decoded, {refused} refused");
    }
}
