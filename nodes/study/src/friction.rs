//! The friction-law study (`dc study friction`): what the per-step law costs in physics against
//! the Box2D law, judged against how much the Box2D law itself varies between seeds.
//!
//! Every seed runs twice with the same solver and stopping rule, once under each law (whole runs:
//! a law changes the trajectory). Each run is summed up in physical costs: where the pile ends
//! (height and spread of its centre of mass), how deep bodies sink into each other (the largest
//! penetration of the run, the mean over its last steps), how much it still moves (kinetic energy
//! and mean body speed over its last steps), and what its solves cost. A cost is **within**
//! the Box2D law's own variation when the per-step law's mean over the seeds differs from the
//! Box2D law's mean by no more than the Box2D law's largest deviation of one seed from its own
//! mean: the per-step law then lands where another seed of the Box2D law would.

use sim::scene::BodyKind;
use sim::solver::FrictionModel;
use sim::{ModelKind, SceneConfig, SimError, World, WorldParams};

/// What the study runs.
#[derive(Debug, Clone)]
pub struct FrictionSpec {
    pub scene: SceneConfig,
    /// The solver, stopping rule and cap both laws share (its `friction` is overridden).
    pub params: WorldParams,
    pub steps: u32,
    /// The late window (the last this many steps) over which the late costs are averaged.
    pub late: u32,
}

/// The physical costs.
pub const COSTS: [&str; 6] = [
    "pile height (m)",
    "pile spread (m)",
    "largest penetration (m)",
    "late mean penetration (m)",
    "late kinetic energy (J)",
    "late mean body speed (m/s)",
];

/// One run's costs, and what its solves took.
#[derive(Debug, Clone, PartialEq)]
pub struct RunCosts {
    pub seed: u64,
    pub law: FrictionModel,
    /// In the order of [`COSTS`].
    pub costs: [f64; 6],
    pub sweeps: u64,
    pub capped: u32,
    pub solve_seconds: f64,
}

/// One cost compared between the laws.
#[derive(Debug, Clone, PartialEq)]
pub struct CostVerdict {
    pub cost: &'static str,
    pub box_mean: f64,
    /// The Box2D law's largest deviation of a seed from its mean.
    pub box_variation: f64,
    pub per_step_mean: f64,
    pub within: bool,
}

/// Runs `seed` under `law` and sums it up.
pub fn run(spec: &FrictionSpec, seed: u64, law: FrictionModel) -> Result<RunCosts, SimError> {
    let mut params = spec.params;
    params.solve.friction = law;
    let mut world = World::new(&SceneConfig { seed, ..spec.scene.clone() }, params)?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    warm.begin_simulation(0, seed);
    let late_from = spec.steps.saturating_sub(spec.late.max(1));
    let (mut late_steps, mut penetration_max) = (0u32, 0f64);
    let mut late = [0f64; 6];
    let (mut sweeps, mut capped, mut solve_us) = (0u64, 0u32, 0f64);
    for step in 0..spec.steps {
        let stats = world.step(&mut warm).clone();
        sweeps += stats.sweeps as u64;
        capped += (!stats.converged && stats.contacts > 0) as u32;
        solve_us += stats.solve_us as f64;
        penetration_max = penetration_max.max(stats.penetration_max as f64);
        if step >= late_from {
            late_steps += 1;
            let (speed_sum, dynamic) = world
                .bodies()
                .iter()
                .filter(|b| b.kind == BodyKind::Dynamic)
                .fold((0f64, 0usize), |(s, n), b| (s + b.v.length() as f64, n + 1));
            late[0] += stats.pile_height as f64;
            late[1] += stats.pile_spread as f64;
            late[3] += stats.penetration_mean as f64;
            late[4] += stats.kinetic_energy as f64;
            late[5] += speed_sum / dynamic.max(1) as f64;
        }
    }
    let mean = |x: f64| x / late_steps.max(1) as f64;
    Ok(RunCosts {
        seed,
        law,
        costs: [mean(late[0]), mean(late[1]), penetration_max, mean(late[3]), mean(late[4]), mean(late[5])],
        sweeps,
        capped,
        solve_seconds: solve_us / 1e6,
    })
}

/// Each cost's verdict from the runs of both laws (each seed under each).
pub fn verdicts(runs: &[RunCosts]) -> Vec<CostVerdict> {
    let of = |law| runs.iter().filter(move |r| r.law == law);
    COSTS
        .iter()
        .enumerate()
        .map(|(k, &cost)| {
            let boxed: Vec<f64> = of(FrictionModel::Box).map(|r| r.costs[k]).collect();
            let per_step: Vec<f64> = of(FrictionModel::PerStep).map(|r| r.costs[k]).collect();
            let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
            let box_mean = mean(&boxed);
            let box_variation = boxed.iter().map(|x| (x - box_mean).abs()).fold(0.0, f64::max);
            let per_step_mean = mean(&per_step);
            CostVerdict {
                cost,
                box_mean,
                box_variation,
                per_step_mean,
                within: (per_step_mean - box_mean).abs() <= box_variation,
            }
        })
        .collect()
}

/// The verdicts and the solves' costs as markdown.
pub fn markdown(runs: &[RunCosts]) -> String {
    let mut out = String::from(
        "| cost | Box2D law: mean | its largest seed deviation | per-step law: mean | difference | within? |\n|---|---:|---:|---:|---:|---|\n",
    );
    for v in verdicts(runs) {
        let difference = v.per_step_mean - v.box_mean;
        out += &format!(
            "| {} | {} | {} | {} | {}{} | {} |\n",
            v.cost,
            figure(v.box_mean),
            figure(v.box_variation),
            figure(v.per_step_mean),
            if difference >= 0.0 { "+" } else { "-" },
            figure(difference.abs()),
            if v.within { "yes" } else { "**no**" }
        );
    }
    out += "\n| law | sweeps | capped steps | solve time (s) | vs Box2D law |\n|---|---:|---:|---:|---:|\n";
    let total = |law| {
        runs.iter()
            .filter(|r| r.law == law)
            .fold((0u64, 0u32, 0f64), |(s, c, t), r| (s + r.sweeps, c + r.capped, t + r.solve_seconds))
    };
    let reference = total(FrictionModel::Box).2;
    for law in [FrictionModel::Box, FrictionModel::PerStep] {
        let (sweeps, capped, seconds) = total(law);
        out += &format!("| {law} | {sweeps} | {capped} | {seconds:.2} | {:.2}x |\n", seconds / reference.max(1e-12));
    }
    out
}

/// A figure to four decimals, or to four significant digits below 0.01 (penetrations, energies
/// of a settled pile).
fn figure(x: f64) -> String {
    if x == 0.0 || x.abs() >= 0.01 {
        format!("{x:.4}")
    } else {
        format!("{x:.3e}")
    }
}

/// Every run's costs as CSV (seed, law, the costs, sweeps, capped, solve seconds).
pub fn csv(runs: &[RunCosts]) -> String {
    let mut out = String::from("seed,law");
    for c in COSTS {
        out += &format!(",{c}");
    }
    out += ",sweeps,capped,solve_s\n";
    for r in runs {
        out += &format!("{},{}", r.seed, r.law);
        for x in r.costs {
            out += &format!(",{x:e}");
        }
        out += &format!(",{},{},{:.4}\n", r.sweeps, r.capped, r.solve_seconds);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::SolveParams;

    fn costs(seed: u64, law: FrictionModel, height: f64) -> RunCosts {
        RunCosts { seed, law, costs: [height, 1.0, 0.1, 0.01, 0.5, 0.2], sweeps: 10, capped: 0, solve_seconds: 1.0 }
    }

    #[test]
    fn a_cost_is_within_when_the_laws_differ_less_than_the_box_law_between_seeds() {
        let runs = [
            costs(0, FrictionModel::Box, 6.0),
            costs(1, FrictionModel::Box, 6.2),
            costs(0, FrictionModel::PerStep, 6.15),
            costs(1, FrictionModel::PerStep, 6.15),
        ];
        let v = verdicts(&runs);
        // Height: Box2D mean 6.1, seeds 0.1 off it; the per-step law 0.05 above: within.
        assert!((v[0].box_mean - 6.1).abs() < 1e-12 && (v[0].box_variation - 0.1).abs() < 1e-12);
        assert!(v[0].within);
        // Both laws identical elsewhere: every other cost within (a zero variation admits zero).
        assert!(v.iter().all(|c| c.within));
        let lower = [costs(0, FrictionModel::PerStep, 5.9), costs(1, FrictionModel::PerStep, 5.9)];
        let runs: Vec<RunCosts> = runs[..2].iter().cloned().chain(lower).collect();
        let v = verdicts(&runs);
        assert!(!v[0].within, "{v:?}");
        let md = markdown(&runs);
        assert!(md.contains("| pile height (m) | 6.1000 | 0.1000 | 5.9000 | -0.2000 | **no** |"), "{md}");
        assert!(csv(&runs).lines().count() == 5);
    }

    #[test]
    fn both_laws_run_the_same_seed_and_sum_up_a_settling_pile() {
        let spec = FrictionSpec {
            scene: SceneConfig { n: 30, ..SceneConfig::default() },
            params: WorldParams {
                solve: SolveParams { stop: sim::StopRule::Natural, ..SolveParams::default() },
                ..WorldParams::default()
            },
            steps: 150,
            late: 30,
        };
        let boxed = run(&spec, 2000, FrictionModel::Box).unwrap();
        let per_step = run(&spec, 2000, FrictionModel::PerStep).unwrap();
        for r in [&boxed, &per_step] {
            // A pile on the floor of a 15 m box: above the floor, below the drop height, spread
            // over the box, sunk in by millimetres, and moving slower than a falling body.
            let [height, spread, deepest, late_depth, energy, speed] = r.costs;
            assert!(height > 0.0 && height < 15.0 && spread > 0.5 && spread < 15.0, "{r:?}");
            assert!(deepest >= late_depth && (0.0..0.05).contains(&late_depth), "{r:?}");
            assert!(energy >= 0.0 && (0.0..5.0).contains(&speed), "{r:?}");
            assert!(r.sweeps > 0 && r.solve_seconds > 0.0);
        }
        // The laws are really different runs, and each is deterministic.
        assert_ne!(boxed.costs, per_step.costs);
        assert_eq!(run(&spec, 2000, FrictionModel::PerStep).unwrap().costs, per_step.costs);
    }
}
