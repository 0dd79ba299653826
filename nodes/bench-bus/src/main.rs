//! dc-bench-bus: publishes `Body` slices or 7x128x128 grids and checks / measures what arrives.
//!
//! Roles: `source` publishes, `sink` receives, verifies and measures; `inproc` runs both as threads
//! over a channel (the floor of the benchmark). In `--verify` mode every frame's contents are
//! checked bit for bit, in order, none lost; otherwise the sink prints one JSON [`BenchResult`] line.
//! `--raw` sends the same frames through iceoryx2's or zenoh's own API instead of `runtime`'s
//! ports (the baseline our layer is measured against, see `raw`).

mod raw;

use anyhow::{bail, Context, Result};
use bench_bus::*;
use charts::quantile_nearest_rank;
use clap::{Parser, ValueEnum};
use msgs::{topics, Body, GridHeader, StepHeader};
use runtime::Node;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
enum Role {
    Source,
    Sink,
    Inproc,
}

#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
enum Kind {
    Bodies,
    Grid,
}

#[derive(Parser, Debug)]
#[command(about = "Proves and measures the bus: publishes bodies or grids and checks what arrives")]
struct Args {
    #[arg(long, value_enum)]
    role: Role,
    #[arg(long, value_enum, default_value = "bodies")]
    kind: Kind,
    /// Bodies per frame (kind = bodies; 1 to 1,000,000: 48 MB a frame).
    #[arg(long, default_value_t = 10_000,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1_000_000))]
    n: usize,
    /// Frames of the throughput phase (or of the verification).
    #[arg(long, default_value_t = 200)]
    count: u32,
    /// Frames of the latency phase, sent one at a time with a pause between.
    #[arg(long, default_value_t = 200)]
    latency_count: u32,
    /// Check every frame's contents instead of measuring.
    #[arg(long)]
    verify: bool,
    /// Source: publish an undecodable payload before every K-th frame (zenoh topics only).
    #[arg(long, default_value_t = 0)]
    garbage_every: u32,
    /// Sink: give up (and fail) when nothing arrived for this long, seconds (above 0, at most a
    /// day).
    #[arg(long, default_value_t = 30.0, value_parser = msgs::flags::f64_above(0.0, 86_400.0))]
    timeout_s: f64,
    /// Sleep this long before creating the ports (a node that is slow to start; at most an hour).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=3_600_000))]
    create_delay_ms: u64,
    /// Sink: sleep this long after start before the first receive (a slow consumer; at most an
    /// hour).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=3_600_000))]
    start_delay_ms: u64,
    /// Label of the transport in the result line.
    #[arg(long, default_value = "")]
    label: String,
    /// Use this topic instead of `bench/bodies` / `bench/grid` (the same frame type: `bodies`
    /// carries body frames too), e.g. to tap the simulator's stream.
    #[arg(long)]
    topic: Option<String>,
    /// Sink: subscribe and never read, until stopped (a stuck viewer: on a reliable topic it
    /// holds the publisher back once its queue is full, on a best-effort one it must not).
    #[arg(long)]
    stall: bool,
    /// Use the transport's own API (iceoryx2 or zenoh, as the launcher routes the topic) instead
    /// of the runtime's ports: the raw baseline.
    #[arg(long)]
    raw: bool,
}

/// Header of frame `seq` of `phase` (0 latency, 1 throughput).
fn header(phase: u32, seq: u32) -> StepHeader {
    StepHeader { run_id: 0, simulation: phase, step: seq }
}

/// The header stamped with the send time (in `run_id`), taken once the contents are written so
/// latency measures the transport, not the filling.
fn stamped(h: StepHeader) -> StepHeader {
    StepHeader { run_id: monotonic_ns(), ..h }
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    if args.role == Role::Inproc {
        return inproc(&args);
    }
    std::thread::sleep(Duration::from_millis(args.create_delay_ms));
    let node = Node::from_env("dc-bench-bus")?;
    // Described (`DC_DESCRIBE`), a raw node names the runtime's ports below: the launcher then
    // plans the same graph (routes, zenoh router) for both.
    let describing = std::env::var("DC_DESCRIBE").is_ok_and(|v| v == "1");
    if args.raw && !describing {
        return raw_run(&node, &args);
    }
    match (args.role, args.kind) {
        (Role::Source, Kind::Bodies) => {
            let mut p =
                node.publisher_named::<StepHeader, Body>(args.topic.as_deref().unwrap_or(topics::BENCH_BODIES.name))?;
            if !node.ready()? {
                return Ok(());
            }
            source(&node, &args, |h, seq, garbage| {
                if garbage {
                    return Ok(p.publish_encoded(b"\xa3\x61v\x01\x61h\xff garbage")?);
                }
                Ok(p.publish_with(args.n, |header, b| {
                    fill_bodies(seq, b);
                    *header = stamped(h);
                })?)
            })
        }
        (Role::Source, Kind::Grid) => {
            let mut p = node
                .publisher_named::<msgs::GridHeader, f32>(args.topic.as_deref().unwrap_or(topics::BENCH_GRID.name))?;
            if !node.ready()? {
                return Ok(());
            }
            source(&node, &args, |h, seq, garbage| {
                if garbage {
                    return Ok(p.publish_encoded(&[0xff; 40])?);
                }
                Ok(p.publish_with(GRID_LEN, |header, v| {
                    fill_grid(seq, v);
                    *header = grid_header(stamped(h));
                })?)
            })
        }
        (Role::Sink, Kind::Bodies) => {
            let mut s =
                node.subscriber_named::<StepHeader, Body>(args.topic.as_deref().unwrap_or(topics::BENCH_BODIES.name))?;
            if !node.ready()? {
                return Ok(());
            }
            if args.stall {
                return stall(&node);
            }
            let mut expected = vec![Body::default(); args.n];
            let errors = std::cell::Cell::new(0);
            sink(
                &args,
                frame_bytes(&args),
                |timeout| {
                    let got = s.recv_timeout(timeout)?;
                    errors.set(s.decode_errors());
                    Ok(got.map(|r| {
                        let h = *r.header();
                        let ok = !args.verify || {
                            fill_bodies(h.step, &mut expected);
                            first_difference(r.items(), &expected).is_none()
                        };
                        (h, ok)
                    }))
                },
                || errors.get(),
                || node.is_shutdown(),
            )
        }
        (Role::Sink, Kind::Grid) => {
            let mut s = node
                .subscriber_named::<msgs::GridHeader, f32>(args.topic.as_deref().unwrap_or(topics::BENCH_GRID.name))?;
            if !node.ready()? {
                return Ok(());
            }
            if args.stall {
                return stall(&node);
            }
            let mut expected = vec![0f32; GRID_LEN];
            let errors = std::cell::Cell::new(0);
            sink(
                &args,
                frame_bytes(&args),
                |timeout| {
                    let got = s.recv_timeout(timeout)?;
                    errors.set(s.decode_errors());
                    Ok(got.map(|r| {
                        let h = r.header().step;
                        let ok = !args.verify || {
                            fill_grid(h.step, &mut expected);
                            *r.header() == grid_header(h) && first_difference(r.items(), &expected).is_none()
                        };
                        (h, ok)
                    }))
                },
                || errors.get(),
                || node.is_shutdown(),
            )
        }
        (Role::Inproc, _) => unreachable!("handled above"),
    }
}

/// The raw baseline's source or sink (see `raw`).
fn raw_run(node: &Node, args: &Args) -> Result<()> {
    if args.garbage_every > 0 || args.stall {
        bail!("--garbage-every and --stall test the runtime's ports, not --raw");
    }
    let topic = args.topic.as_deref().unwrap_or(match args.kind {
        Kind::Bodies => topics::BENCH_BODIES.name,
        Kind::Grid => topics::BENCH_GRID.name,
    });
    match (args.role, args.kind) {
        (Role::Source, Kind::Bodies) => raw_source::<StepHeader, Body>(node, args, topic, args.n, fill_bodies, |h| h),
        (Role::Source, Kind::Grid) => {
            raw_source::<GridHeader, f32>(node, args, topic, GRID_LEN, fill_grid, grid_header)
        }
        (Role::Sink, Kind::Bodies) => {
            let mut expected = vec![Body::default(); args.n];
            raw_sink::<StepHeader, Body>(
                node,
                args,
                topic,
                |h| *h,
                |h, items| {
                    fill_bodies(h.step, &mut expected);
                    items == bytemuck::cast_slice::<Body, u8>(&expected)
                },
            )
        }
        (Role::Sink, Kind::Grid) => {
            let mut expected = vec![0f32; GRID_LEN];
            raw_sink::<GridHeader, f32>(
                node,
                args,
                topic,
                |h| h.step,
                |h, items| {
                    fill_grid(h.step.step, &mut expected);
                    *h == grid_header(h.step) && items == bytemuck::cast_slice::<f32, u8>(&expected)
                },
            )
        }
        (Role::Inproc, _) => unreachable!("handled before"),
    }
}

fn raw_source<H: msgs::FrameHeader, T: msgs::FrameItem>(
    node: &Node,
    args: &Args,
    topic: &str,
    len: usize,
    fill: impl Fn(u32, &mut [T]),
    header: impl Fn(StepHeader) -> H,
) -> Result<()> {
    let mut publisher = raw::RawPublisher::<H, T>::new(node, topic, len)?;
    if !node.ready()? {
        return Ok(());
    }
    publisher.wait_for_subscriber(Duration::from_secs_f64(args.timeout_s))?;
    source(node, args, |h, seq, _| publisher.send(len, |items| fill(seq, items), || header(stamped(h))))?;
    publisher.wait_until_unsubscribed(|| node.is_shutdown())
}

fn raw_sink<H: msgs::FrameHeader, T: msgs::FrameItem>(
    node: &Node,
    args: &Args,
    topic: &str,
    step_of: impl Fn(&H) -> StepHeader,
    mut same: impl FnMut(&H, &[u8]) -> bool,
) -> Result<()> {
    let subscriber = raw::RawSubscriber::<H, T>::new(node, topic)?;
    if !node.ready()? {
        return Ok(());
    }
    sink(
        args,
        frame_bytes(args),
        |timeout| {
            let got = subscriber.recv_timeout(timeout, |h, items| !args.verify || same(h, items))?;
            Ok(got.map(|(h, ok)| (step_of(&h), ok)))
        },
        || 0,
        || node.is_shutdown(),
    )
}

/// Holds its subscription without reading until the node is stopped.
fn stall(node: &Node) -> Result<()> {
    tracing::info!("stalling: subscribed, never reading");
    while runtime::sleep_unless_shutdown(node, Duration::from_millis(100)) {}
    Ok(())
}

fn frame_bytes(args: &Args) -> usize {
    match args.kind {
        Kind::Bodies => args.n * std::mem::size_of::<Body>(),
        Kind::Grid => GRID_LEN * 4,
    }
}

/// Publishes the latency phase (paced) then the throughput phase (back to back); in verify mode
/// only `count` frames back to back.
fn source(node: &Node, args: &Args, mut send: impl FnMut(StepHeader, u32, bool) -> Result<()>) -> Result<()> {
    if !args.verify {
        for seq in 0..args.latency_count {
            send(header(0, seq), seq, false)?;
            if !runtime::sleep_unless_shutdown(node, Duration::from_millis(2)) {
                return Ok(());
            }
        }
    }
    for seq in 0..args.count {
        if node.is_shutdown() {
            break;
        }
        if args.garbage_every > 0 && seq % args.garbage_every == 0 {
            send(StepHeader::default(), seq, true).context("publishing a garbage payload")?;
        }
        send(header(1, seq), seq, false)?;
    }
    tracing::info!(frames = args.count, "source done");
    Ok(())
}

/// Receives every frame, checks order (and contents in verify mode), measures latency and throughput.
fn sink(
    args: &Args,
    bytes: usize,
    mut recv: impl FnMut(Duration) -> Result<Option<(StepHeader, bool)>>,
    decode_errors: impl Fn() -> u64,
    stopped: impl Fn() -> bool,
) -> Result<()> {
    std::thread::sleep(Duration::from_millis(args.start_delay_ms));
    let latency_count = if args.verify { 0 } else { args.latency_count };
    let mut latencies = Vec::with_capacity(latency_count as usize);
    let mut next = (if latency_count > 0 { 0 } else { 1 }, 0u32);
    let (mut first, mut last) = (None, Instant::now());
    let timeout = Duration::from_secs_f64(args.timeout_s);
    while next.0 < 2 {
        let Some((h, ok)) = recv(timeout)? else {
            if stopped() {
                tracing::info!("stopped before all frames arrived");
                return Ok(());
            }
            bail!(
                "lost frames: waited {:?} for frame {} of phase {} (decode errors: {})",
                timeout,
                next.1,
                next.0,
                decode_errors()
            );
        };
        let now = monotonic_ns();
        if (h.simulation, h.step) != next {
            bail!(
                "out of order: got frame {} of phase {}, expected {} of phase {}",
                h.step,
                h.simulation,
                next.1,
                next.0
            );
        }
        if !ok {
            bail!("frame {} differs from what was sent", h.step);
        }
        if h.simulation == 0 {
            latencies.push((now.saturating_sub(h.run_id)) as f64 / 1e3);
        } else {
            first.get_or_insert(Instant::now());
            last = Instant::now();
        }
        next.1 += 1;
        let phase_len = if next.0 == 0 { latency_count } else { args.count };
        if next.1 == phase_len {
            next = (next.0 + 1, 0);
        }
    }
    if args.verify {
        println!(
            "{}",
            serde_json::json!({"verified": args.count, "bytes_per_frame": bytes, "decode_errors": decode_errors()})
        );
        return Ok(());
    }
    let elapsed = last.duration_since(first.unwrap_or(last)).as_secs_f64().max(1e-9);
    // The throughput clock starts at the first frame: count-1 intervals.
    let fps = (args.count.saturating_sub(1)) as f64 / elapsed;
    let result = BenchResult {
        transport: args.label.clone(),
        payload: payload_label(args),
        bytes,
        latency_samples: latencies.len(),
        p50_us: quantile_nearest_rank(&latencies, 0.5),
        p99_us: quantile_nearest_rank(&latencies, 0.99),
        frames_per_s: fps,
        mb_per_s: fps * bytes as f64 / 1e6,
    };
    println!("{}", serde_json::to_string(&result)?);
    Ok(())
}

fn payload_label(args: &Args) -> String {
    match args.kind {
        Kind::Bodies => format!("{} bodies", args.n),
        Kind::Grid => format!("grid {}x{}x{}", GRID_CHANNELS.len(), GRID_SIDE, GRID_SIDE),
    }
}

/// Both ends in one process over a bounded channel: the floor the bus is measured against.
fn inproc(args: &Args) -> Result<()> {
    enum Payload {
        Bodies(Vec<Body>),
        Grid(Vec<f32>),
    }
    let (tx, rx) = std::sync::mpsc::sync_channel::<(StepHeader, Payload)>(16);
    let (n, kind, verify, count, latency_count) = (args.n, args.kind, args.verify, args.count, args.latency_count);
    let producer = std::thread::spawn(move || {
        let send = |h: StepHeader, seq: u32| {
            // A fresh buffer per frame, as a loan from shared memory would be.
            let payload = match kind {
                Kind::Bodies => {
                    let mut b = vec![Body::default(); n];
                    fill_bodies(seq, &mut b);
                    Payload::Bodies(b)
                }
                Kind::Grid => {
                    let mut v = vec![0f32; GRID_LEN];
                    fill_grid(seq, &mut v);
                    Payload::Grid(v)
                }
            };
            tx.send((stamped(h), payload)).is_ok()
        };
        if !verify {
            for seq in 0..latency_count {
                send(header(0, seq), seq);
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        for seq in 0..count {
            send(header(1, seq), seq);
        }
    });
    let mut expected_b = vec![Body::default(); n];
    let mut expected_g = vec![0f32; GRID_LEN];
    let result = sink(
        args,
        frame_bytes(args),
        |timeout| {
            Ok(rx.recv_timeout(timeout).ok().map(|(h, p)| {
                let ok = !verify
                    || match &p {
                        Payload::Bodies(b) => {
                            fill_bodies(h.step, &mut expected_b);
                            first_difference(b, &expected_b).is_none()
                        }
                        Payload::Grid(g) => {
                            fill_grid(h.step, &mut expected_g);
                            first_difference(g, &expected_g).is_none()
                        }
                    };
                (h, ok)
            }))
        },
        || 0,
        || false,
    );
    producer.join().map_err(|_| anyhow::anyhow!("producer thread panicked"))?;
    result
}
