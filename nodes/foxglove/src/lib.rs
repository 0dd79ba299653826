//! The live Foxglove bridge: bus frames converted into Foxglove's well-known schemas (Foxglove does
//! not decode our CBOR frames) and served over the Foxglove WebSocket protocol by the `foxglove`
//! SDK, or written to an MCAP "viz" file for Foxglove's file mode.
//!
//! | bus topic            | Foxglove topic                | schema                              |
//! |----------------------|-------------------------------|-------------------------------------|
//! | `bodies` + `contacts`| `/scene`                      | `foxglove.SceneUpdate`              |
//! | (scene extent)       | `/tf`                         | `foxglove.FrameTransform` world->box|
//! | `grid/*`             | `/grid/*`                     | `foxglove.Grid`, FLOAT32 per channel|
//! | `grid/*`             | `/grid/*/heat/<channel>`      | `foxglove.RawImage` (rgb8 heat map) |
//! | `stats/solve`        | `/stats/solve`                | JSON, schema `dc.SolveStats`        |
//! | `metrics/step`       | `/metrics/step`               | JSON, schema `dc.MetricsStep`       |
//! | `control`            | `/control`                    | JSON, schema `dc.Control`           |
//!
//! Back-pressure: the bus holds a publisher back while a subscriber's queue is full, so the node
//! drains every subscriber at full rate whatever the clients do. What reaches a live client is
//! throttled per topic ([`throttle::Throttle`]) and converted only when a client subscribes; the SDK
//! queues messages per client and drops the oldest for a slow one, so no client can hold up the bus.
//!
//! A viz file ([`BridgeConfig::file`]) is not throttled: every recorded step gets its scene, grids,
//! heat maps and statistics, each stamped with simulation time ([`timeline`]: step x dt from the
//! run's parameters), so Foxglove's file mode plays the physics at real speed.

pub mod bridge;
pub mod convert;
pub mod throttle;
pub mod timeline;

pub use bridge::{Bridge, BridgeConfig, Rates};

/// Errors of the bridge.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A grid frame whose geometry does not match its values (skipped and counted).
    #[error("topic `{topic}`: undecodable grid: {what}")]
    BadGrid { topic: String, what: String },
    #[error("foxglove: {0}")]
    Foxglove(#[from] foxglove::FoxgloveError),
}
