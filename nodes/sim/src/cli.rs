//! The command-line groups every simulator program shares (the node `dc-sim` and the studies
//! `dc-study`): which scene and seeds, and how each step is solved. One definition, so a flag
//! means the same in every program and the studies reproduce the node's runs.

use crate::error::SimError;
use crate::scene::{SamplerKind, SceneConfig, SceneKind};
use crate::solver::{FrictionModel, RowOrder, SolveParams, SolverSetting, StopRule, ThreadsError, MAX_THREADS};
use crate::world::WorldParams;
use std::time::Duration;

/// A number `ok` accepts, or an error saying what it `must` be.
fn f32_where(s: &str, ok: fn(f32) -> bool, must: &str) -> Result<f32, String> {
    msgs::flags::number_where(s, ok, must)
}

/// A finite number > 0 (tolerances, sizes).
pub fn positive_f32(s: &str) -> Result<f32, String> {
    f32_where(s, |v| v.is_finite() && v > 0.0, "a finite number > 0")
}

/// A finite number >= 0 (slops).
pub fn non_negative_f32(s: &str) -> Result<f32, String> {
    f32_where(s, |v| v.is_finite() && v >= 0.0, "a finite number >= 0")
}

/// A finite number (speeds that may be negative).
pub fn finite_f32(s: &str) -> Result<f32, String> {
    f32_where(s, f32::is_finite, "a finite number")
}

/// A relative compliance (`SolveParams::valid_compliance`).
fn compliance(s: &str) -> Result<f32, String> {
    f32_where(s, SolveParams::valid_compliance, &format!("a number {}", SolveParams::compliance_range()))
}

/// An over-relaxation factor (`SolveParams::valid_relaxation`).
fn relaxation(s: &str) -> Result<f32, String> {
    f32_where(s, SolveParams::valid_relaxation, &format!("a number {}", SolveParams::relaxation_range()))
}

/// A thread count for `--threads`: 1 to [`MAX_THREADS`].
fn threads(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("at least 1 thread".to_string()),
        Ok(n) if n > MAX_THREADS => Err(format!("at most {MAX_THREADS} threads")),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("a whole number of threads: {e}")),
    }
}

/// A duration that must be given (`10ms`, `2s`), never `none`.
pub fn required_duration(s: &str) -> Result<Duration, String> {
    crate::parse_deadline(s).map_err(|e| e.to_string())?.ok_or_else(|| "a duration is required, not `none`".to_string())
}

/// The scene and the seeds of a run.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene: ball-box, drum or mixed.
    #[arg(long, default_value = "ball-box", value_parser = |s: &str| s.parse::<SceneKind>())]
    pub scene: SceneKind,
    /// Seeds of the simulations (`0..30`, `0..=29`, `1,5,7`); overrides --seed/--simulations.
    #[arg(long)]
    pub seeds: Option<String>,
    /// First seed (with --simulations).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Number of simulations, seeds seed..seed+simulations.
    #[arg(long, default_value_t = 1)]
    pub simulations: u64,
    /// Steps per simulation.
    #[arg(long, default_value_t = 250)]
    pub steps: u32,
    /// Initial-world sampler: native or numpy (the original code's worlds, exactly).
    #[arg(long, default_value = "native", value_parser = |s: &str| s.parse::<SamplerKind>())]
    pub sampler: SamplerKind,
    /// Dynamic bodies.
    #[arg(long, default_value_t = 100)]
    pub n: usize,
    /// Box side (default 15 * sqrt(n / 100)).
    #[arg(long, value_parser = positive_f32)]
    pub side: Option<f32>,
    /// Drum angular speed, rad/s.
    #[arg(long, default_value_t = 1.0, value_parser = finite_f32)]
    pub drum_omega: f32,
}

impl SceneArgs {
    /// The seeds, sorted and without duplicates.
    pub fn seeds(&self) -> Result<Vec<u64>, SimError> {
        match &self.seeds {
            Some(s) => crate::parse_seeds(s),
            // The seed list's own bounds (count, largest seed), checked before it is built.
            None => msgs::parse_seeds(&format!("{}..{}", self.seed, self.seed.saturating_add(self.simulations)))
                .map_err(|why| SimError::InvalidParameter {
                    name: "--seed/--simulations",
                    value: format!("{} and {}", self.seed, self.simulations),
                    why,
                }),
        }
    }

    /// The seeds, once the runs over them with `params` are known to fit their bounds (counts,
    /// sizes and the memory they imply, checked before anything is allocated).
    pub fn checked_seeds(&self, params: WorldParams) -> Result<Vec<u64>, SimError> {
        let seeds = self.seeds()?;
        crate::run::RunSpec {
            scene: self.scene_config(seeds.first().copied().unwrap_or(self.seed)),
            params,
            seeds: seeds.clone(),
            steps: self.steps,
            run_id: 0,
            problems: false,
            label: None,
            shadow_builtin: false,
            error_split: false,
        }
        .validate()?;
        Ok(seeds)
    }

    /// The seeds as the user gave them (`0..30`), for reports.
    pub fn seeds_label(&self) -> String {
        self.seeds.clone().unwrap_or_else(|| format!("{}..{}", self.seed, self.seed.saturating_add(self.simulations)))
    }

    /// The scene of seed `seed`.
    pub fn scene_config(&self, seed: u64) -> SceneConfig {
        SceneConfig {
            kind: self.scene,
            n: self.n,
            seed,
            sampler: self.sampler,
            side: self.side,
            drum_omega: self.drum_omega,
            ..SceneConfig::default()
        }
    }
}

/// How each step is solved: the velocity solver, its stopping rule, the oracle's, the position
/// pass.
#[derive(clap::Args, Debug, Clone)]
pub struct SolveArgs {
    /// The velocity solver: pgs (projected Gauss-Seidel, the thesis's), sor:W (projected SOR,
    /// W in (0, 2)), nncg or nncg:R (nonsmooth nonlinear conjugate gradient, restarting when
    /// beta > R; nncg = nncg:1); `/down` visits the rows top-down (sor:1.4/down), `/colour` in
    /// colours swept on --threads threads (nncg:1.2/colour). The oracle,
    /// labels and shadow solves use the same. The default, NNCG restarting above 1.2 with rows
    /// top-down, needs 0.34x PGS's sweeps and 0.36x its time to the same natural residual on the
    /// evaluation seeds (docs/solvers.md); `--solver pgs --stop change` is the thesis's solver.
    #[arg(long, default_value_t = SolverSetting::RECOMMENDED, value_parser = |s: &str| s.parse::<SolverSetting>())]
    pub solver: SolverSetting,
    /// The friction law: box (Box2D's, `|t| <= mu n` of the step's own normal impulse) or
    /// per-step (the bound frozen at `mu` times the contact's previous normal impulse: each
    /// step's problem a convex QP; a new contact takes Box2D's law). docs/solvers.md says
    /// what each costs.
    #[arg(long, default_value_t = FrictionModel::Box, value_parser = |s: &str| s.parse::<FrictionModel>())]
    pub friction: FrictionModel,
    /// Row order of the solver's sweeps: recorded (contact keys), down (by contact height, top
    /// first, every step) or colour (coloured top-down, each colour on --threads threads);
    /// overrides the order --solver names.
    #[arg(long, value_parser = |s: &str| s.parse::<RowOrder>())]
    pub order: Option<RowOrder>,
    /// Stopping rule: change (the largest impulse change of a sweep <= --tolerance, the
    /// thesis's) or natural (the natural residual, what one projected Jacobi step would still
    /// change, <= --tolerance: the same accuracy for every solver).
    #[arg(long, default_value_t = StopRule::RECOMMENDED, value_parser = |s: &str| s.parse::<StopRule>())]
    pub stop: StopRule,
    /// Convergence tolerance of the stopping rule, in impulse units.
    #[arg(long, default_value_t = 1e-4, value_parser = positive_f32)]
    pub tolerance: f32,
    /// Sweep cap.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_sweeps: u32,
    /// Relative compliance of every contact row (0: rigid, the thesis's problem); the oracle,
    /// the labels and the shadow solves use the same. See `sim::SolveParams::compliance`.
    #[arg(long, default_value_t = 0.0, value_parser = compliance)]
    pub compliance: f32,
    /// Over-relaxation factor of the solver's row updates; in (0, 2). The same as
    /// `--solver sor:W`.
    #[arg(long, value_parser = relaxation, conflicts_with = "solver")]
    pub relaxation: Option<f32>,
    /// The oracle's tolerance (`copy` and the oracle ablations solve each step from builtin's
    /// warm start to it, with the run's solver and the change rule: the natural residual stalls
    /// at the f32 impulses' resolution long before 2e-6 on deep piles).
    #[arg(long, default_value_t = 2e-6, value_parser = positive_f32)]
    pub oracle_tolerance: f32,
    /// The oracle's sweep cap.
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(1..))]
    pub oracle_max_sweeps: u32,
    /// Linear slop of the position pass.
    #[arg(long, default_value_t = 0.0005, value_parser = non_negative_f32)]
    pub slop: f32,
    /// A wall-time budget per solve, milliseconds (the real-time regime at a fixed time a
    /// step): each solve stops at the tolerance or once the budget is spent, whichever comes
    /// first. Runs are then no longer bit for bit repeatable (they follow the clock). The
    /// oracle and the reference solves never have one.
    #[arg(long, value_parser = positive_f32)]
    pub time_budget_ms: Option<f32>,
    /// Threads the colour order sweeps on (`--solver nncg:1.2/colour`, `--order colour`): each
    /// colour's rows are updated on all of them at once. Default: the machine's cores; 1 sweeps
    /// on the calling thread. The answer is the same, bit for bit, on any number of threads.
    #[arg(long, default_value_t = crate::solver::machine_cores(), value_parser = threads)]
    pub threads: usize,
}

impl SolveArgs {
    /// Starts the process's sweep threads (`--threads`); the error says how many could not be
    /// started. Call once, before the first solve.
    pub fn start_threads(&self) -> Result<(), ThreadsError> {
        crate::solver::set_process_threads(self.threads)
    }

    /// The world's parameters; `budget`: exactly that many sweeps a step, stopping earlier
    /// only at the tolerance of the natural residual (the real-time regime).
    pub fn world_params(&self, budget: Option<u32>) -> WorldParams {
        let mut setting = self.solver;
        if let Some(w) = self.relaxation {
            setting.relaxation = w;
        }
        if let Some(order) = self.order {
            setting.order = order;
        }
        let solve = SolveParams {
            tolerance: self.tolerance,
            max_sweeps: budget.unwrap_or(self.max_sweeps),
            compliance: self.compliance,
            stop: if budget.is_some() { StopRule::Natural } else { self.stop },
            friction: self.friction,
            time_budget_us: self.time_budget_ms.map(|ms| ms * 1e3),
            ..SolveParams::default()
        }
        .with_setting(setting);
        // The oracle solves the same problem with the same solver, only further, to the change
        // rule (see --oracle-tolerance).
        let oracle = SolveParams {
            tolerance: self.oracle_tolerance,
            max_sweeps: self.oracle_max_sweeps,
            stop: StopRule::Change,
            time_budget_us: None,
            ..solve
        };
        let mut p = WorldParams { solve, oracle, ..WorldParams::default() };
        p.position.slop = self.slop;
        p
    }
}

/// The largest sweep budget a step may be given (`--budget K`).
pub const MAX_BUDGET: u32 = msgs::curve::MAX_BUDGET;

/// A sweep budget: 1 to [`MAX_BUDGET`].
pub fn budget(s: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(k) if (1..=MAX_BUDGET).contains(&k) => Ok(k),
        Ok(k) => Err(format!("a budget is from 1 to {MAX_BUDGET} sweeps, got {k}")),
        Err(e) => Err(e.to_string()),
    }
}

/// Seeds 0..29 are the evaluation's: nothing is trained or tuned on them.
pub const EVALUATION_SEEDS: std::ops::Range<u64> = 0..30;

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Both {
        #[command(flatten)]
        scene: SceneArgs,
        #[command(flatten)]
        solve: SolveArgs,
    }

    #[test]
    fn the_groups_parse_the_nodes_spellings() {
        let a = Both::parse_from(["x", "--n", "400", "--seeds", "3..5", "--solver", "pgs", "--slop", "0.001"]);
        assert_eq!(a.scene.seeds().unwrap(), vec![3, 4]);
        assert_eq!(a.scene.scene_config(3).n, 400);
        let p = a.solve.world_params(Some(8));
        assert_eq!((p.solve.max_sweeps, p.solve.stop), (8, StopRule::Natural));
        assert_eq!(p.position.slop, 0.001);
        assert_eq!(p.oracle.stop, StopRule::Change);
        assert!(Both::try_parse_from(["x", "--drum-omega", "nan"]).is_err());
        assert!(Both::try_parse_from(["x", "--slop", "-1"]).is_err());
        assert!(budget("0").is_err() && budget(&(MAX_BUDGET + 1).to_string()).is_err() && budget("8") == Ok(8));
    }

    #[test]
    fn threads_outside_the_range_are_refused_naming_the_flag() {
        for (bad, says) in [("0", "at least 1"), ("1025", "at most 1024"), ("x", "whole number")] {
            let e = Both::try_parse_from(["x", "--threads", bad]).err().unwrap().to_string();
            assert!(e.contains("--threads") && e.contains(says), "{bad}: {e}");
        }
        assert_eq!(Both::parse_from(["x", "--threads", "3"]).solve.threads, 3);
        assert_eq!(Both::parse_from(["x"]).solve.threads, crate::solver::machine_cores());
    }
}
