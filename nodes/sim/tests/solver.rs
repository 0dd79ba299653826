//! The contact solver checked independently of itself: complementarity at convergence, the
//! oracle warm start, and the ordering of warm-start models by total sweeps.

use sim::solver::{natural_residual, relative_velocity, row_masses};
use sim::{ModelKind, SceneConfig, SolveParams, StopRule, WarmStarter, World, WorldParams};

/// The ball-box world of `seed` with `params`, and `model`'s warm starter begun on it.
fn started(seed: u64, params: WorldParams, model: ModelKind) -> (World, WarmStarter) {
    let world = World::new(&SceneConfig { seed, ..Default::default() }, params).unwrap();
    let mut warm = model.starter(0).unwrap();
    warm.begin_simulation(0, seed);
    (world, warm)
}

/// Checks the velocity-level LCP of the last step to tolerance; returns the number of contacts checked.
///
/// Tolerances: the solve stops when no row changes its impulse by more than `tol`, so a row's
/// remaining violation, in impulse units (velocity times the row's effective mass), is a small
/// multiple of `tol` (the later rows of the last sweep move it by at most their own changes).
fn check_complementarity(world: &World, tol: f32) -> usize {
    let rows = world.rows();
    let bodies = world.solver_bodies();
    let impulses = world.impulses();
    let k = 4.0 * tol; // impulse units
    for (i, (row, l)) in rows.iter().zip(impulses).enumerate() {
        let (vn, vt) = relative_velocity(row, bodies);
        let (mn, mt) = row_masses(row, bodies);
        let mu = row.friction;
        let ctx = || format!("step {}, contact {i}: {l:?}, vn {vn}, vt {vt}, mu {mu}", world.stats().step);
        // lambda_n >= 0 (exact: the projection clamps at 0).
        assert!(l.normal >= 0.0, "negative normal impulse, {}", ctx());
        // Non-penetrating relative velocity.
        assert!(vn * mn >= -k, "approaching contact, {}", ctx());
        // Complementarity: a pushing contact does not separate.
        assert!((l.normal * vn * mn).abs() <= k * l.normal.max(k), "lambda_n * v_n not ~ 0, {}", ctx());
        // Friction inside the cone (up to the normal's last change).
        assert!(l.tangent.abs() <= mu * l.normal + mu * k + 1e-6, "outside the friction cone, {}", ctx());
        // Sliding contacts sit on the cone boundary, opposing the slip.
        if vt.abs() * mt > k {
            assert!(
                (l.tangent.abs() - mu * l.normal).abs() <= mu * k + 1e-5 && l.tangent * vt <= 0.0,
                "sliding contact inside the cone, {}",
                ctx()
            );
        }
    }
    rows.len()
}

#[test]
fn complementarity_conditions_hold_at_convergence_for_every_contact() {
    for (seed, model) in [(1u64, ModelKind::None), (2, ModelKind::Builtin), (3, ModelKind::Random)] {
        let params = WorldParams::default();
        let (mut world, mut warm) = started(seed, params, model);
        let mut checked = 0;
        for _ in 0..250 {
            let s = world.step(&mut warm).clone();
            if s.converged {
                checked += check_complementarity(&world, params.solve.tolerance);
            }
        }
        assert!(checked > 10_000, "seed {seed}: only {checked} contacts checked");
    }
}

#[test]
fn over_relaxed_solves_satisfy_the_same_complementarity_conditions() {
    // Projected SOR has the same fixed points as projected Gauss-Seidel: what it converges to
    // solves the same problem (and a converged solve stops on a small change either way).
    let solve = SolveParams { relaxation: 1.4, ..Default::default() };
    let params = WorldParams { solve, ..Default::default() };
    let (mut world, mut warm) = started(4, params, ModelKind::Builtin);
    let (mut checked, mut converged) = (0, 0);
    for _ in 0..250 {
        let s = world.step(&mut warm).clone();
        if s.converged {
            converged += 1;
            checked += check_complementarity(&world, solve.tolerance);
        }
    }
    assert!(converged > 200 && checked > 10_000, "{converged} steps converged, {checked} contacts checked");
}

/// The oracle: restarting from the converged solution converges at once. Checked without
/// friction, where projected Gauss-Seidel converges monotonically. With Coulomb friction (mu 0.5)
/// the problem is non-symmetric and PGS can hover around the tolerance in a settled pile, so a
/// solve that stopped on a dip below the tolerance may continue for long from its own solution;
/// see `copy_with_friction_restarts_from_a_converged_solution_cheaply` for what holds there.
#[test]
fn copy_warm_start_converges_in_two_sweeps() {
    let config = SceneConfig { seed: 4, friction: 0.0, ..Default::default() };
    let mut world = World::new(&config, WorldParams::default()).unwrap();
    let mut warm = ModelKind::Copy.starter(0).unwrap();
    let mut checked = 0;
    for _ in 0..250 {
        let s = world.step(&mut warm).clone();
        let oracle = world.oracle_report().expect("copy runs the oracle every step");
        if s.contacts > 0 && oracle.converged {
            checked += 1;
            assert!(s.sweeps <= 2, "step {}: {} sweeps from the solution", s.step, s.sweeps);
            assert!(s.converged);
            assert!(s.warm_error_normal_max <= 1e-3, "step {}: {}", s.step, s.warm_error_normal_max);
        }
    }
    assert!(checked > 200, "{checked}");
}

/// With friction: from the oracle's solution (solved from builtin's warm start to 2e-6, far below
/// the run's tolerance) the restart converges within a few sweeps (re-applying the impulses rounds
/// differently from the oracle's accumulated updates); overall, copy needs a small fraction of the
/// oracle's own sweeps.
#[test]
fn copy_with_friction_restarts_from_a_converged_solution_cheaply() {
    let mut world = World::new(&SceneConfig { seed: 4, ..Default::default() }, WorldParams::default()).unwrap();
    let mut warm = ModelKind::Copy.starter(0).unwrap();
    let (mut restart_sweeps, mut oracle_sweeps, mut margin_steps) = (0u64, 0u64, 0);
    for _ in 0..250 {
        let s = world.step(&mut warm).clone();
        let oracle = world.oracle_report().unwrap();
        restart_sweeps += s.sweeps as u64;
        oracle_sweeps += oracle.sweeps as u64;
        if s.contacts > 0 && oracle.converged && oracle.final_residual <= 0.5 * world.params().solve.tolerance {
            margin_steps += 1;
            assert!(s.sweeps <= 5, "step {}: {} sweeps (oracle {oracle:?})", s.step, s.sweeps);
        }
    }
    assert!(margin_steps >= 10, "{margin_steps}");
    assert!(restart_sweeps * 2 < oracle_sweeps, "copy {restart_sweeps} vs oracle {oracle_sweeps}");
}

#[test]
fn unconverged_solves_are_reported_as_such() {
    let params = WorldParams {
        solve: SolveParams { tolerance: 1e-7, max_sweeps: 3, ..Default::default() },
        ..Default::default()
    };
    let mut world = World::new(&SceneConfig { seed: 4, ..Default::default() }, params).unwrap();
    let mut warm = ModelKind::None.starter(0).unwrap();
    let mut capped = 0;
    for _ in 0..150 {
        let s = world.step(&mut warm);
        if s.contacts > 20 {
            assert_eq!(s.sweeps, 3);
            capped += (!s.converged) as u32;
        }
    }
    assert!(capped > 0);
    assert_eq!(world.residuals().len(), 3);
}

/// Total sweeps of `model` over seeds 0..10, 250 steps each (the thesis scene).
fn total_sweeps(model: ModelKind) -> u64 {
    let mut total = 0;
    for seed in 0..10u64 {
        let mut world = World::new(&SceneConfig { seed, ..Default::default() }, WorldParams::default()).unwrap();
        let mut warm = model.starter(0).unwrap();
        warm.begin_simulation(seed as u32, seed);
        for _ in 0..250 {
            total += world.step(&mut warm).sweeps as u64;
        }
    }
    total
}

#[test]
fn total_sweeps_order_bad_none_builtin_copy2_copy() {
    let models = [ModelKind::Bad, ModelKind::None, ModelKind::Builtin, ModelKind::Copy2, ModelKind::Copy];
    let totals: Vec<u64> = models.iter().map(|&m| total_sweeps(m)).collect();
    for (m, t) in models.iter().zip(&totals) {
        eprintln!("ball-box seeds 0..10, 250 steps: {:<8} {t} sweeps", m.name());
    }
    for (w, m) in totals.windows(2).zip(models.windows(2)) {
        assert!(w[0] > w[1], "{} ({}) should need more sweeps than {} ({})", m[0].name(), w[0], m[1].name(), w[1]);
    }
}

/// Params with `setting` stopping on the natural residual at `tolerance`.
fn natural(setting: &str, tolerance: f32) -> WorldParams {
    let solve = SolveParams { tolerance, stop: StopRule::Natural, ..Default::default() };
    WorldParams { solve: solve.with_setting(setting.parse().unwrap()), ..Default::default() }
}

/// A step's sweeps, convergence, stopping residual and natural residual.
type StepOutcome = (u32, bool, f32, f32);

/// Every step's outcome and the final body states of a 150-step run.
fn trajectory(params: WorldParams, seed: u64) -> (Vec<StepOutcome>, Vec<sim::world::BodyState>) {
    let (mut world, mut warm) = started(seed, params, ModelKind::Builtin);
    let stats = (0..150)
        .map(|_| {
            let s = world.step(&mut warm);
            (s.sweeps, s.converged, s.final_residual, s.natural_max)
        })
        .collect();
    (stats, world.bodies().to_vec())
}

#[test]
fn every_solver_meets_the_natural_residual_and_the_lcp_at_convergence() {
    for setting in ["pgs", "sor:1.4", "nncg", "sor:1.4/down", "nncg:1.2/colour"] {
        let params = natural(setting, 1e-4);
        let (mut world, mut warm) = started(6, params, ModelKind::Builtin);
        let (mut checked, mut converged) = (0, 0);
        for _ in 0..200 {
            let s = world.step(&mut warm).clone();
            if s.converged {
                converged += 1;
                assert!(s.natural_max <= 1e-4 && s.final_residual == s.natural_max, "{setting}: {s:?}");
                // Measured from outside on the world's own rows, velocities and impulses.
                let measured = natural_residual(world.rows(), world.solver_bodies(), world.impulses(), 0.0);
                assert_eq!(measured.max, s.natural_max, "{setting}, step {}", s.step);
                checked += check_complementarity(&world, 1e-4);
            }
        }
        assert!(converged > 150 && checked > 10_000, "{setting}: {converged} steps, {checked} contacts");
    }
}

#[test]
fn nncg_that_always_restarts_is_pgs_bit_for_bit_on_a_pile() {
    let pgs = trajectory(natural("pgs", 1e-4), 3);
    assert_eq!(trajectory(natural("nncg:0", 1e-4), 3), pgs);
    assert_ne!(trajectory(natural("nncg", 1e-4), 3).0, pgs.0, "real NNCG takes other steps");
}

#[test]
fn the_top_down_order_is_deterministic_and_changes_the_sweeps() {
    let down = trajectory(natural("sor:1.4/down", 1e-4), 5);
    assert_eq!(trajectory(natural("sor:1.4/down", 1e-4), 5), down);
    assert_ne!(trajectory(natural("sor:1.4", 1e-4), 5).0, down.0);
}

#[test]
fn the_relative_rule_holds_every_model_to_builtins_scale() {
    // A model that starts from zero would keep the absolute tolerance if it set its own scale;
    // the world scales by builtin's start, so a loaded pile's steps stop above 1e-4 while a
    // step's scale (builtin's RMS impulse) stays that of a 100-ball pile's loads.
    let solve = SolveParams { tolerance: 1e-4, stop: StopRule::Relative, max_sweeps: 5_000, ..Default::default() };
    let params = WorldParams { solve: solve.with_setting("nncg:1.2/down".parse().unwrap()), ..Default::default() };
    let (mut world, mut warm) = started(6, params, ModelKind::None);
    let (mut above, mut converged) = (0, 0);
    for _ in 0..200 {
        let s = world.step(&mut warm).clone();
        if s.converged {
            converged += 1;
            above += (s.natural_max > 1e-4) as u32;
            assert!(s.natural_max <= 1e-4 * 20.0, "{s:?}");
        }
    }
    assert!(converged > 150 && above > 50, "{converged} converged, {above} above the absolute 1e-4");
}

#[test]
fn the_colour_order_solves_a_falling_pile_to_the_same_bits_on_any_thread_count() {
    // A 400-body pile (about 1,000 rows: the threads take part) at three steps of its fall,
    // under both friction laws: each captured problem solved in the colour order on 1 to 4
    // threads gives the same impulses, velocities, sweeps and residuals, bit for bit.
    use sim::problem::{bodies_of, builtin_warm_start, rows_of};
    use sim::solver::{ContactSolver, FrictionModel, SweepThreads};
    for friction in [FrictionModel::Box, FrictionModel::PerStep] {
        let mut params = natural("nncg:1.2/down", 1e-4);
        params.solve.friction = friction;
        let mut world = World::new(&SceneConfig { seed: 2000, n: 400, ..Default::default() }, params).unwrap();
        let mut warm = ModelKind::Builtin.starter(0).unwrap();
        warm.begin_simulation(0, 2000);
        world.capture_problems(None);
        let mut problems = Vec::new();
        for step in 0..240 {
            world.step(&mut warm);
            if [160, 200, 239].contains(&step) {
                problems.push(world.problem().unwrap().clone());
            }
        }
        for problem in &problems {
            let rows = rows_of(&problem.contacts, friction);
            let start = builtin_warm_start(&problem.contacts);
            assert!(rows.len() > 500, "{} rows", rows.len());
            for setting in ["pgs/colour", "nncg:1.2/colour"] {
                let solve =
                    SolveParams { max_sweeps: 3_000, friction, ..params.solve }.with_setting(setting.parse().unwrap());
                let on = |threads: usize| {
                    let mut s = ContactSolver::with_threads(SweepThreads::new(threads).unwrap());
                    let mut bodies = bodies_of(&problem.bodies);
                    let report = s.solve(&rows, &mut bodies, &start, &solve);
                    (report, s.impulses().to_vec(), bodies, s.residuals().to_vec())
                };
                let one = on(1);
                // PGS may cap under the Box2D law (it does on a tenth of such steps); the sweeps
                // it made are still the same on every thread count.
                assert!(one.0.converged || setting.starts_with("pgs"), "{friction} {setting}: {:?}", one.0);
                let measured = natural_residual(&rows, &one.2, &one.1, 0.0);
                assert_eq!(measured.max, one.0.natural.max, "{friction} {setting}: measured from outside");
                for threads in [2, 3, 4] {
                    assert!(on(threads) == one, "{friction} {setting}: {threads} threads differ from one");
                }
            }
        }
    }
}
