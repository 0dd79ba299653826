//! The studies of the Deep Contact simulator, in one process and without the bus: they use the
//! `sim` crate as a user would, and `sim` never uses them.
//!
//! - [`compare`]: solvers side by side on the same states, the hindsight ceiling, a learned
//!   per-step choice of solver (`dc study solvers`);
//! - [`budget`]: the real-time regime, a fixed sweep budget per step, each model's accuracy
//!   after it placed on builtin's curve of accuracy against budget (`dc study budget`);
//! - [`bench`]: ms/step of our world against rapier's full pipeline (`dc study bench`);
//! - [`friction`]: what the per-step friction law costs in physics against the Box2D law, judged
//!   against the Box2D law's own variation between seeds (`dc study friction`);
//! - [`threads`]: what the colour order's threads buy, on the same states (`dc study threads`);
//! - [`shards`]: a study's results kept per shard (`--shard I/N`) and joined by the merge.

pub mod bench;
pub mod budget;
pub mod compare;
pub mod friction;
pub mod shards;
pub mod threads;
