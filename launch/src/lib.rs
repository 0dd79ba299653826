//! The `dc` command's library: launch-file parsing and checking ([`graph`]) and the process
//! supervisor ([`supervisor`]).

pub mod graph;
pub mod supervisor;
