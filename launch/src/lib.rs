//! The `dc` command's library: launch-file parsing and checking ([`graph`]), routing topics over
//! the transports ([`plan`]), the process supervisor ([`supervisor`]) and `dc eval --solvers`'s
//! table ([`solver_table`]).

pub mod graph;
pub mod plan;
pub mod solver_table;
pub mod supervisor;
