//! The `dc` command's library: launch-file parsing and checking ([`graph`]), routing topics over
//! the transports ([`plan`]) and the process supervisor ([`supervisor`]).

pub mod graph;
pub mod plan;
pub mod supervisor;
