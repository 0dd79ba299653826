//! The `dc` command's library: launch-file parsing and checking ([`graph`]), routing topics over
//! the transports ([`plan`]), the process supervisor ([`supervisor`]) and `dc eval --solvers`'s
//! table ([`solver_table`]).

/// `eprintln!` that never panics: a launcher whose stderr was closed keeps supervising its graph.
macro_rules! tell {
    ($($arg:tt)*) => {{
        let _ = runtime::try_eprint_line(&format!($($arg)*));
    }};
}

pub mod graph;
pub mod plan;
pub mod shard;
pub mod solver_table;
pub mod supervisor;

/// A bus namespace no earlier graph used: process ids are recycled, and a namespace shared with
/// a dead graph's leftovers (a subscriber that never reads) would stall publishers.
pub fn unique_namespace(prefix: &str) -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    format!("{prefix}-{}-{nanos}", std::process::id())
}
