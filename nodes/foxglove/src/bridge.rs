//! The bridge: Foxglove channels on a [`foxglove::Context`] fed with bus frames, converted only
//! when someone listens (a WebSocket client subscribed, or an MCAP sink). A live bridge throttles
//! per topic and shows the latest step; a file bridge writes every frame of every step.

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

/// Per-topic rate limits of a live stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rates {
    /// Most messages per second per topic for the scene, grids and heat maps (0: unlimited).
    pub max_hz: f64,
    /// Most messages per second per topic for the small JSON topics (statistics for plots).
    pub plot_hz: f64,
}

impl Default for Rates {
    fn default() -> Self {
        Rates { max_hz: 30.0, plot_hz: 100.0 }
    }
}

/// Pace and style of the bridge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BridgeConfig {
    /// `Some` for a live stream: throttled per topic, the scene of the latest step only. `None`
    /// for a file: every frame is converted and every step gets its scene.
    pub rates: Option<Rates>,
    pub style: SceneStyle,
}

impl BridgeConfig {
    /// A live stream at `rates`.
    pub fn live(rates: Rates, style: SceneStyle) -> BridgeConfig {
        BridgeConfig { rates: Some(rates), style }
    }

    /// A file: nothing throttled, nothing dropped.
    pub fn file(style: SceneStyle) -> BridgeConfig {
        BridgeConfig { rates: None, style }
    }

    /// The throttle of the scene, grids and heat maps (unlimited for a file).
    fn data_throttle(&self) -> Throttle {
        Throttle::new(self.rates.map_or(0.0, |r| r.max_hz))
    }

    /// The throttle of the JSON statistics (unlimited for a file).
    fn plot_throttle(&self) -> Throttle {
        Throttle::new(self.rates.map_or(0.0, |r| r.plot_hz))
    }
}

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig::live(Rates::default(), SceneStyle::default())
    }
}

/// How long a live scene waits for the contacts of its bodies' step before it goes out without
/// them (a graph that publishes bodies only), in nanoseconds.
const PAIR_WAIT_NS: u64 = 250_000_000;
/// Steps a file's scene join holds while their other half is missing. A recording interleaves
/// its topics in batches (the recorder takes up to 64 frames of one topic at a time), so the
/// contacts of a step follow its bodies within a few batches; past this many waiting steps the
/// oldest goes out with what it has (bodies alone), as do the ones still waiting at the end.
const FILE_PENDING_STEPS: usize = 1024;
/// How often the transform is repeated (late joiners need one), in hertz.
const TF_HZ: f64 = 1.0;

type Key = (u64, u32, u32);

fn key(h: &StepHeader) -> Key {
    (h.run_id, h.simulation, h.step)
}

/// The bodies and contacts of the latest step, joined for a live scene.
#[derive(Default)]
struct LatestJoin {
    bodies: Option<(StepHeader, Vec<Body>)>,
    contacts: Option<(StepHeader, Vec<Contact>)>,
    /// When the first half of the pending pair arrived.
    since_ns: Option<u64>,
}

/// Half or all of one step's scene in a file.
struct PendingStep {
    key: Key,
    /// The bodies, their header and their time.
    bodies: Option<(StepHeader, Vec<Body>, u64)>,
    contacts: Option<Vec<Contact>>,
}

/// The bodies and contacts of every step, matched by step, for a file.
struct EveryJoin {
    /// False when the file has no contacts: each bodies frame is its step's scene at once.
    contacts_expected: bool,
    /// Steps waiting for their other half, oldest first.
    pending: std::collections::VecDeque<PendingStep>,
    /// Steps that went out without contacts.
    bodies_alone: u64,
    /// Contacts whose bodies never came.
    contacts_alone: u64,
}

impl EveryJoin {
    /// The waiting entry of step `key`, added at the back when new.
    fn entry(&mut self, key: Key) -> &mut PendingStep {
        // Newest last, and a step's halves arrive close together: search from the back.
        match self.pending.iter().rposition(|p| p.key == key) {
            Some(i) => &mut self.pending[i],
            None => {
                self.pending.push_back(PendingStep { key, bodies: None, contacts: None });
                self.pending.back_mut().expect("pushed")
            }
        }
    }

    /// Takes step `key` out when both halves are there.
    fn take_complete(&mut self, key: Key) -> Option<(StepHeader, Vec<Body>, u64, Vec<Contact>)> {
        let i = self.pending.iter().rposition(|p| p.key == key && p.bodies.is_some() && p.contacts.is_some())?;
        let p = self.pending.remove(i).expect("found");
        let (h, bodies, t) = p.bodies.expect("checked");
        Some((h, bodies, t, p.contacts.expect("checked")))
    }

    /// Takes the oldest waiting step out (`all`: every one, else only past the limit), for its
    /// scene without contacts where it has bodies.
    fn take_overdue(&mut self, all: bool) -> Option<(StepHeader, Vec<Body>, u64)> {
        while (all && !self.pending.is_empty()) || self.pending.len() > FILE_PENDING_STEPS {
            let p = self.pending.pop_front().expect("not empty");
            match p.bodies {
                Some(b) => {
                    self.bodies_alone += 1;
                    return Some(b);
                }
                None => self.contacts_alone += 1,
            }
        }
        None
    }
}

/// How the scene's two halves (bodies, contacts) are joined.
enum SceneJoin {
    Live(LatestJoin),
    File(EveryJoin),
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
            json.insert(topic.to_string(), JsonOut { channel, kind, throttle: config.plot_throttle() });
        }
        Ok(Bridge {
            ctx: ctx.clone(),
            config,
            scene: ctx.channel_builder(SCENE_TOPIC).build(),
            tf: ctx.channel_builder(TF_TOPIC).build(),
            control: json_channel(ctx, CONTROL_TOPIC, "dc.Control", convert::CONTROL_SCHEMA.as_str())?,
            scene_throttle: config.data_throttle(),
            join: match config.rates {
                Some(_) => SceneJoin::Live(LatestJoin::default()),
                None => SceneJoin::File(EveryJoin {
                    contacts_expected: true,
                    pending: Default::default(),
                    bodies_alone: 0,
                    contacts_alone: 0,
                }),
            },
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
        match &mut self.join {
            SceneJoin::Live(join) => {
                join.since_ns.get_or_insert(now_ns);
                let slot = join.bodies.get_or_insert_with(|| (*h, Vec::new()));
                slot.0 = *h;
                slot.1.clear();
                slot.1.extend_from_slice(bodies);
                self.try_emit_live_scene(now_ns);
            }
            SceneJoin::File(join) if !join.contacts_expected => self.emit_scene(h, bodies, &[], now_ns),
            SceneJoin::File(join) => {
                join.entry(key(h)).bodies = Some((*h, bodies.to_vec(), now_ns));
                self.emit_file_scenes(Some(key(h)));
            }
        }
    }

    /// A contacts frame at `now_ns`.
    pub fn on_contacts(&mut self, h: &StepHeader, contacts: &[Contact], now_ns: u64) {
        if !self.scene.has_sinks() || !self.scene_throttle.due(now_ns) {
            return;
        }
        match &mut self.join {
            SceneJoin::Live(join) => {
                join.since_ns.get_or_insert(now_ns);
                let slot = join.contacts.get_or_insert_with(|| (*h, Vec::new()));
                slot.0 = *h;
                slot.1.clear();
                slot.1.extend_from_slice(contacts);
                self.try_emit_live_scene(now_ns);
            }
            SceneJoin::File(join) => {
                join.entry(key(h)).contacts = Some(contacts.to_vec());
                self.emit_file_scenes(Some(key(h)));
            }
        }
    }

    /// Live: sends the scene once bodies and contacts of one step are both there (or the bodies
    /// alone after [`PAIR_WAIT_NS`]).
    fn try_emit_live_scene(&mut self, now_ns: u64) {
        let SceneJoin::Live(join) = &mut self.join else { return };
        let Some((bh, _)) = &join.bodies else { return };
        let matched = join.contacts.as_ref().is_some_and(|(ch, _)| key(ch) == key(bh));
        let waited = join.since_ns.is_some_and(|t| now_ns.saturating_sub(t) >= PAIR_WAIT_NS);
        if !matched && !waited {
            return;
        }
        let (bh, bodies) = join.bodies.take().expect("checked above");
        let contacts = match join.contacts.take() {
            Some((ch, c)) if key(&ch) == key(&bh) => c,
            _ => Vec::new(),
        };
        join.since_ns = None;
        self.emit_scene(&bh, &bodies, &contacts, now_ns);
    }

    /// File: sends the scene of step `completed` if both its halves are there, then the scenes
    /// of steps that waited too long; `None`: the scenes of every waiting step (the end).
    fn emit_file_scenes(&mut self, completed: Option<Key>) {
        let SceneJoin::File(join) = &mut self.join else { return };
        if let Some((h, bodies, t, contacts)) = completed.and_then(|k| join.take_complete(k)) {
            self.emit_scene(&h, &bodies, &contacts, t);
        }
        let all = completed.is_none();
        loop {
            let SceneJoin::File(join) = &mut self.join else { return };
            let Some((h, bodies, t)) = join.take_overdue(all) else { return };
            self.emit_scene(&h, &bodies, &[], t);
        }
    }

    fn emit_scene(&mut self, h: &StepHeader, bodies: &[Body], contacts: &[Contact], time_ns: u64) {
        let scene = convert::scene_update(h, bodies, contacts, &self.config.style, time_ns);
        self.scene.log_with_meta(&scene, PartialMetadata::with_log_time(time_ns));
        self.scene_throttle.take(time_ns);
        self.count(SCENE_TOPIC);
    }

    /// File: whether contacts frames will come (true unless told otherwise); without them each
    /// bodies frame goes out as its step's scene at once instead of waiting for its contacts.
    pub fn expect_contacts(&mut self, expected: bool) {
        if let SceneJoin::File(join) = &mut self.join {
            join.contacts_expected = expected;
        }
    }

    /// Sends what is still waiting: a file's steps whose contacts never came go out with their
    /// bodies alone. Call once after the last frame.
    pub fn finish(&mut self) {
        self.emit_file_scenes(None);
    }

    /// File: steps whose scene went out without contacts, and contacts frames without bodies
    /// (both 0 for a live bridge).
    pub fn unpaired(&self) -> (u64, u64) {
        match &self.join {
            SceneJoin::Live(_) => (0, 0),
            SceneJoin::File(j) => (j.bodies_alone, j.contacts_alone),
        }
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
                throttle: self.config.data_throttle(),
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
