//! The bridge: Foxglove channels on a [`foxglove::Context`] fed with bus frames, throttled per
//! topic, converted only when someone listens (a WebSocket client subscribed, or an MCAP sink).

use crate::convert::{self, SceneStyle};
use crate::throttle::Throttle;
use crate::Error;
use foxglove::messages::{FrameTransform, Grid, RawImage, SceneUpdate};
use foxglove::{Channel, Context, PartialMetadata, RawChannel, Schema};
use msgs::{Body, Contact, Control, ControlKind, GridHeader, SolveStatsHeader, StepHeader};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Foxglove topic of the scene.
pub const SCENE_TOPIC: &str = "/scene";
/// Foxglove topic of the world -> box transform.
pub const TF_TOPIC: &str = "/tf";
/// Foxglove topic of control messages.
pub const CONTROL_TOPIC: &str = "/control";

/// The Foxglove topic of a bus topic: `grid/contacts` -> `/grid/contacts`.
pub fn foxglove_topic(bus_topic: &str) -> String {
    format!("/{bus_topic}")
}

/// The Foxglove topic of the heat map of one channel of a grid topic.
pub fn heat_topic(bus_topic: &str, channel: &str) -> String {
    format!("/{bus_topic}/heat/{channel}")
}

/// Rates and style of the bridge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BridgeConfig {
    /// Most messages per second per topic for the scene, grids and heat maps (0: unlimited).
    pub max_hz: f64,
    /// Most messages per second per topic for the small JSON topics (statistics for plots).
    pub plot_hz: f64,
    pub style: SceneStyle,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig { max_hz: 30.0, plot_hz: 100.0, style: SceneStyle::default() }
    }
}

/// How long the scene waits for the contacts of its bodies' step before it goes out without them
/// (a graph that publishes bodies only), in nanoseconds.
const PAIR_WAIT_NS: u64 = 250_000_000;
/// How often the transform is repeated (late joiners need one), in hertz.
const TF_HZ: f64 = 1.0;

type Key = (u64, u32, u32);

fn key(h: &StepHeader) -> Key {
    (h.run_id, h.simulation, h.step)
}

/// The bodies and contacts of one step, joined for the scene.
#[derive(Default)]
struct SceneJoin {
    bodies: Option<(StepHeader, Vec<Body>)>,
    contacts: Option<(StepHeader, Vec<Contact>)>,
    /// When the first half of the pending pair arrived.
    since_ns: Option<u64>,
}

/// A grid topic's outputs.
struct GridOut {
    grid: Channel<Grid>,
    heat: BTreeMap<String, Channel<RawImage>>,
    throttle: Throttle,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum JsonKind {
    SolveStats,
    MetricsStep,
}

struct JsonOut {
    channel: Arc<RawChannel>,
    kind: JsonKind,
    throttle: Throttle,
}

/// What the bridge has done, for the node's summary.
#[derive(Debug, Default, Clone)]
pub struct Counters {
    /// Messages logged per Foxglove topic.
    pub sent: BTreeMap<String, u64>,
    /// Grid frames whose geometry did not match their values.
    pub bad_grids: u64,
}

/// Bus frames in, Foxglove messages out.
pub struct Bridge {
    ctx: Arc<Context>,
    config: BridgeConfig,
    scene: Channel<SceneUpdate>,
    tf: Channel<FrameTransform>,
    control: Arc<RawChannel>,
    scene_throttle: Throttle,
    join: SceneJoin,
    tf_throttle: Throttle,
    /// The simulation whose scene centre the transform was computed from.
    tf_for: Option<(u64, u32)>,
    grids: BTreeMap<String, GridOut>,
    json: BTreeMap<String, JsonOut>,
    pub counters: Counters,
}

fn json_channel(
    ctx: &Arc<Context>,
    topic: &str,
    schema_name: &str,
    schema: &'static str,
) -> Result<Arc<RawChannel>, Error> {
    Ok(ctx
        .channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(schema_name, "jsonschema", schema.as_bytes()))
        .build_raw()?)
}

impl Bridge {
    /// Creates the fixed channels (scene, transform, control, statistics) on `ctx`; grid channels
    /// appear with the first frame of each grid topic (their fields are the grid's channel names).
    pub fn new(ctx: &Arc<Context>, config: BridgeConfig) -> Result<Bridge, Error> {
        let mut json = BTreeMap::new();
        for (topic, kind, name, schema) in [
            (
                msgs::topics::SOLVE_STATS.name,
                JsonKind::SolveStats,
                "dc.SolveStats",
                convert::SOLVE_STATS_SCHEMA.as_str(),
            ),
            (
                msgs::topics::METRICS_STEP.name,
                JsonKind::MetricsStep,
                "dc.MetricsStep",
                convert::METRICS_STEP_SCHEMA.as_str(),
            ),
        ] {
            let channel = json_channel(ctx, &foxglove_topic(topic), name, schema)?;
            json.insert(topic.to_string(), JsonOut { channel, kind, throttle: Throttle::new(config.plot_hz) });
        }
        Ok(Bridge {
            ctx: ctx.clone(),
            config,
            scene: ctx.channel_builder(SCENE_TOPIC).build(),
            tf: ctx.channel_builder(TF_TOPIC).build(),
            control: json_channel(ctx, CONTROL_TOPIC, "dc.Control", convert::CONTROL_SCHEMA.as_str())?,
            scene_throttle: Throttle::new(config.max_hz),
            join: SceneJoin::default(),
            tf_throttle: Throttle::new(TF_HZ),
            tf_for: None,
            grids: BTreeMap::new(),
            json,
            counters: Counters::default(),
        })
    }

    fn count(&mut self, topic: &str) {
        *self.counters.sent.entry(topic.to_string()).or_default() += 1;
    }

    /// A bodies frame at `now_ns` (the log time of what it produces).
    pub fn on_bodies(&mut self, h: &StepHeader, bodies: &[Body], now_ns: u64) {
        let sim = (h.run_id, h.simulation);
        if self.tf.has_sinks() && (self.tf_for != Some(sim) || self.tf_throttle.due(now_ns)) {
            if let Some(center) = convert::scene_center(bodies) {
                self.tf
                    .log_with_meta(&convert::frame_transform(center, now_ns), PartialMetadata::with_log_time(now_ns));
                self.tf_throttle.take(now_ns);
                self.tf_for = Some(sim);
                self.count(TF_TOPIC);
            }
        }
        if !self.scene.has_sinks() {
            return;
        }
        if !self.scene_throttle.due(now_ns) {
            self.scene_throttle.skipped += 1;
            return;
        }
        self.join.since_ns.get_or_insert(now_ns);
        let slot = self.join.bodies.get_or_insert_with(|| (*h, Vec::new()));
        slot.0 = *h;
        slot.1.clear();
        slot.1.extend_from_slice(bodies);
        self.try_emit_scene(now_ns);
    }

    /// A contacts frame at `now_ns`.
    pub fn on_contacts(&mut self, h: &StepHeader, contacts: &[Contact], now_ns: u64) {
        if !self.scene.has_sinks() || !self.scene_throttle.due(now_ns) {
            return;
        }
        self.join.since_ns.get_or_insert(now_ns);
        let slot = self.join.contacts.get_or_insert_with(|| (*h, Vec::new()));
        slot.0 = *h;
        slot.1.clear();
        slot.1.extend_from_slice(contacts);
        self.try_emit_scene(now_ns);
    }

    /// Sends the scene once bodies and contacts of one step are both there (or the bodies alone
    /// after [`PAIR_WAIT_NS`]).
    fn try_emit_scene(&mut self, now_ns: u64) {
        let Some((bh, _)) = &self.join.bodies else { return };
        let matched = self.join.contacts.as_ref().is_some_and(|(ch, _)| key(ch) == key(bh));
        let waited = self.join.since_ns.is_some_and(|t| now_ns.saturating_sub(t) >= PAIR_WAIT_NS);
        if !matched && !waited {
            return;
        }
        let (bh, bodies) = self.join.bodies.take().expect("checked above");
        let contacts = match self.join.contacts.take() {
            Some((ch, c)) if key(&ch) == key(&bh) => c,
            _ => Vec::new(),
        };
        self.join.since_ns = None;
        let scene = convert::scene_update(&bh, &bodies, &contacts, &self.config.style, now_ns);
        self.scene.log_with_meta(&scene, PartialMetadata::with_log_time(now_ns));
        self.scene_throttle.take(now_ns);
        self.count(SCENE_TOPIC);
    }

    /// A grid frame of bus topic `topic`. A frame whose geometry does not match its values is
    /// counted and returned as an error naming the topic (the caller logs it and goes on).
    pub fn on_grid(&mut self, topic: &str, h: &GridHeader, items: &[f32], now_ns: u64) -> Result<(), Error> {
        if let Err(e) = convert::check_grid(topic, h, items) {
            self.counters.bad_grids += 1;
            return Err(e);
        }
        if !self.grids.contains_key(topic) {
            let out = GridOut {
                grid: self.ctx.channel_builder(foxglove_topic(topic)).build(),
                heat: BTreeMap::new(),
                throttle: Throttle::new(self.config.max_hz),
            };
            self.grids.insert(topic.to_string(), out);
        }
        let channels: Vec<String> = (0..h.channels as usize).map(|c| convert::channel_name(h, c)).collect();
        let out = self.grids.get_mut(topic).expect("inserted above");
        for name in &channels {
            if !out.heat.contains_key(name) {
                let ch = self.ctx.channel_builder(heat_topic(topic, name)).build();
                out.heat.insert(name.clone(), ch);
            }
        }
        if !out.throttle.due(now_ns) {
            out.throttle.skipped += 1;
            return Ok(());
        }
        let heat_wanted = channels.iter().any(|n| out.heat[n].has_sinks());
        if !out.grid.has_sinks() && !heat_wanted {
            return Ok(());
        }
        out.throttle.take(now_ns);
        let meta = || PartialMetadata::with_log_time(now_ns);
        let mut sent = Vec::new();
        if out.grid.has_sinks() {
            out.grid.log_with_meta(&convert::grid(topic, h, items, now_ns)?, meta());
            sent.push(foxglove_topic(topic));
        }
        for (c, name) in channels.iter().enumerate() {
            let channel = &out.heat[name];
            if channel.has_sinks() {
                channel.log_with_meta(&convert::heat_image(topic, h, items, c, now_ns)?, meta());
                sent.push(heat_topic(topic, name));
            }
        }
        for t in sent {
            self.count(&t);
        }
        Ok(())
    }

    /// A statistics frame of bus topic `topic` (`stats/solve` or `metrics/step`); other topics
    /// of this frame type are ignored.
    pub fn on_stats(&mut self, topic: &str, h: &SolveStatsHeader, items: &[f32], now_ns: u64) {
        let Some(out) = self.json.get_mut(topic) else { return };
        if !out.channel.has_sinks() || !out.throttle.admit(now_ns) {
            return;
        }
        let value = match out.kind {
            JsonKind::SolveStats => convert::solve_stats_json(h, items),
            JsonKind::MetricsStep => convert::metrics_step_json(h, items),
        };
        out.channel.log_with_meta(value.to_string().as_bytes(), PartialMetadata::with_log_time(now_ns));
        let t = foxglove_topic(topic);
        self.count(&t);
    }

    /// A control message (never throttled: a handful per simulation). A new simulation moves the
    /// transform to its box with its first bodies frame.
    pub fn on_control(&mut self, c: &Control, details: &[u8], now_ns: u64) {
        if c.kind() == Some(ControlKind::SimulationStart) {
            self.tf_for = None;
        }
        if self.control.has_sinks() {
            let value = convert::control_json(c, details);
            self.control.log_with_meta(value.to_string().as_bytes(), PartialMetadata::with_log_time(now_ns));
            self.count(CONTROL_TOPIC);
        }
    }

    /// Frames held back by the throttles while someone listened, per kind: (scene steps, grids,
    /// statistics).
    pub fn throttled(&self) -> (u64, u64, u64) {
        (
            self.scene_throttle.skipped,
            self.grids.values().map(|g| g.throttle.skipped).sum(),
            self.json.values().map(|j| j.throttle.skipped).sum(),
        )
    }
}
