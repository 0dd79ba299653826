//! A solve's wall-time budget (`SolveParams::time_budget_us`), shared by the sweeps and the
//! second-order methods: each checks it after a sweep or a factorisation.

use std::time::{Duration, Instant};

/// The instant a solve that starts now with a budget of `budget_us` microseconds must stop by.
pub fn deadline_after(budget_us: Option<f32>) -> Option<Instant> {
    budget_us.map(|us| Instant::now() + Duration::from_secs_f64(us.max(0.0) as f64 * 1e-6))
}

/// Whether `deadline` has passed (never without one).
pub fn past(deadline: Option<Instant>) -> bool {
    deadline.is_some_and(|d| Instant::now() >= d)
}
