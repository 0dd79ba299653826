//! The workspace's report helpers, apart from any node: PNG charts ([`plot`]: line charts with
//! bands, scatter plots, labelled points, one style per series name) and order statistics
//! ([`stats`]: the one quantile and median every report uses).
//!
//! A library of its own so that a node which only needs a median or a chart (the U-Net trainer,
//! the bus benchmark) does not depend on the metrics node.

pub mod plot;
pub mod stats;

pub use plot::{chart, Axis, Mark, Panel, PlotError, Scale, Series};
pub use stats::{median, quantile, quantile_nearest_rank};
