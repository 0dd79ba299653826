//! The Newton solver against the PGS family on the hand-checked cases. Kept apart from
//! `newton.rs` because they call the sweeps ([`super::pgs`]), which call Newton in turn.

use super::newton::*;
use super::rows::{ContactRow, Impulse, SolverBody};
use crate::solver::pgs::{natural_residual, ContactSolver};
use crate::solver::rows::fixtures::{ball, floor_row, lattice, stack};
use crate::solver::rows::relative_velocity;
use crate::solver::sweep::SolveParams;
use crate::solver::{InteriorVariant, Method, SolverSetting, StopRule};
use rapier2d::math::Vec2;

fn params(setting: SolverSetting) -> SolveParams {
    SolveParams { tolerance: 1e-6, max_sweeps: 20_000, stop: StopRule::Natural, ..SolveParams::default() }
        .with_setting(setting)
}

/// The rigid problem of `rows` on `bodies` from `warm`, to 1e-6, no deadline.
fn exact<'a>(rows: &'a [ContactRow], bodies: &'a [SolverBody], warm: &'a [Impulse]) -> NewtonProblem<'a> {
    NewtonProblem { rows, bodies, warm_start: warm, compliance: 0.0, tolerance: 1e-6, deadline: None }
}

/// Both second-order methods.
const METHODS: [SecondOrder; 2] = [SecondOrder::InteriorPoint, SecondOrder::Proximal];

/// Solves with each second-order method alone (no fallback) and returns, per method, the stats,
/// impulses and bodies.
fn newton(
    rows: &[ContactRow],
    bodies: &[SolverBody],
    warm: &[Impulse],
) -> Vec<(NewtonStats, Vec<Impulse>, Vec<SolverBody>)> {
    METHODS
        .iter()
        .map(|&method| {
            let mut solver = NewtonSolver::new();
            let (mut impulses, mut out) = (Vec::new(), bodies.to_vec());
            let problem = exact(rows, bodies, warm);
            let params = NewtonParams { method, ..NewtonParams::default() };
            let stats = solver.solve(&problem, &params, &mut impulses, &mut out).expect("solves");
            (stats, impulses, out)
        })
        .collect()
}

/// Solves with the PGS family's recommended sweeps to 1e-6.
fn sweeps(rows: &[ContactRow], bodies: &[SolverBody], warm: &[Impulse]) -> (Vec<Impulse>, Vec<SolverBody>) {
    let mut out = bodies.to_vec();
    let mut s = ContactSolver::new();
    let rep = s.solve(rows, &mut out, warm, &params(SolverSetting::RECOMMENDED));
    assert!(rep.converged, "{rep:?}");
    (s.impulses().to_vec(), out)
}

fn close(a: &[Impulse], b: &[Impulse], tol: f32) -> bool {
    a.iter().zip(b).all(|(x, y)| (x.normal - y.normal).abs() <= tol && (x.tangent - y.tangent).abs() <= tol)
}

#[test]
fn a_sliding_ball_on_the_floor_stops_falling_and_slides_on_the_cone() {
    let rows = [floor_row(1)];
    let bodies = [SolverBody::default(), ball(Vec2::new(-5.0, -1.0))];
    for (stats, l, out) in newton(&rows, &bodies, &[Impulse::default()]) {
        assert!(stats.converged, "{stats:?}");
        assert!((l[0].normal - 1.0).abs() < 1e-4 && (l[0].tangent.abs() - 0.5 * l[0].normal).abs() < 1e-5, "{l:?}");
        let (vn, _) = relative_velocity(&rows[0], &out);
        assert!(vn.abs() < 1e-4, "vn {vn}");
        let (reference, _) = sweeps(&rows, &bodies, &[Impulse::default()]);
        assert!(close(&l, &reference, 1e-4), "{l:?} vs {reference:?}");
    }
}

#[test]
fn a_stack_of_three_gets_the_sweeps_loads() {
    let (bodies, rows) = stack(3, -0.1);
    for (stats, l, out) in newton(&rows, &bodies, &[Impulse::default(); 3]) {
        assert!(stats.converged && stats.natural_max <= 1e-6, "{stats:?}");
        for (i, li) in l.iter().enumerate() {
            assert!((li.normal - 0.1 * (3 - i) as f32).abs() < 1e-5 && li.tangent.abs() < 1e-6, "row {i}: {li:?}");
        }
        assert!(out[1..].iter().all(|b| b.v.length() < 1e-5), "{out:?}");
        // A chain: the Hessian's pattern is the pile's, and a few iterations do it.
        assert!(stats.iterations <= 10, "{stats:?}");
    }
}

/// A ball driven into the corner of the floor (body 0) and a wall (body 2, at its left).
fn corner() -> (Vec<ContactRow>, Vec<SolverBody>) {
    let rows = vec![
        floor_row(1),
        ContactRow {
            body_a: 2,
            body_b: 1,
            ra: Vec2::ZERO,
            rb: Vec2::new(-0.5, 0.0),
            normal: Vec2::X,
            friction: 0.5,
            height: 0.5,
            friction_bound: None,
        },
    ];
    let bodies = vec![SolverBody::default(), ball(Vec2::new(-2.0, -1.0)), SolverBody::default()];
    (rows, bodies)
}

#[test]
fn a_ball_in_a_corner_with_friction_reaches_the_sweeps_solution() {
    let (rows, bodies) = corner();
    let warm = [Impulse::default(); 2];
    for (stats, l, out) in newton(&rows, &bodies, &warm) {
        assert!(stats.converged, "{stats:?}");
        let (reference, reference_bodies) = sweeps(&rows, &bodies, &warm);
        // Neither contact lets the ball in; friction within its cone.
        for r in &rows {
            assert!(relative_velocity(r, &out).0 > -1e-4);
        }
        for li in &l {
            assert!(li.normal >= 0.0 && li.tangent.abs() <= 0.5 * li.normal + 1e-6, "{li:?}");
        }
        assert!(close(&l, &reference, 1e-4), "{l:?} vs {reference:?}");
        let dv = (out[1].v - reference_bodies[1].v).length() + (out[1].w - reference_bodies[1].w).abs();
        assert!(dv < 1e-4, "{:?} vs {:?}", out[1], reference_bodies[1]);
        assert!(natural_residual(&rows, &out, &l, 0.0).max <= 1e-5);
    }
}

/// A box (unit mass, side 1) resting on the floor at two corners, each contact given twice,
/// under a second box: four redundant rows per interface (rank-deficient `J M^-1 J^T`).
fn jammed() -> (Vec<ContactRow>, Vec<SolverBody>) {
    let body = |v: f32| SolverBody { v: Vec2::new(0.1, v), w: 0.0, inv_mass: 1.0, inv_inertia: 6.0 };
    let bodies = vec![SolverBody::default(), body(-0.2), body(-0.4)];
    let mut rows = Vec::new();
    for (a, b) in [(0u32, 1u32), (1, 2)] {
        for x in [-0.5f32, 0.5, -0.5, 0.5] {
            rows.push(ContactRow {
                body_a: a,
                body_b: b,
                ra: if a == 0 { Vec2::new(x, 0.0) } else { Vec2::new(x, 0.5) },
                rb: Vec2::new(x, -0.5),
                normal: Vec2::Y,
                friction: 0.6,
                height: a as f32,
                friction_bound: None,
            });
        }
    }
    (rows, bodies)
}

#[test]
fn a_jammed_stack_with_redundant_contacts_is_solved_without_a_singular_matrix() {
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    for (stats, l, out) in newton(&rows, &bodies, &warm) {
        assert!(stats.converged, "{stats:?}");
        // The impulses are not unique, the velocities are: both boxes at rest.
        assert!(out[1..].iter().all(|b| b.v.length() < 1e-4 && b.w.abs() < 1e-4), "{out:?}");
        // The floor carries both boxes' momentum, the upper interface the top box's.
        let load = |range: std::ops::Range<usize>| l[range].iter().map(|x| x.normal).sum::<f32>();
        assert!((load(0..4) - 0.6).abs() < 1e-4 && (load(4..8) - 0.4).abs() < 1e-4, "{l:?}");
        assert!(natural_residual(&rows, &out, &l, 0.0).max <= 1e-5);
    }
}

#[test]
fn the_reused_symbolic_factorisation_gives_the_fresh_ones_result() {
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    let problem = exact(&rows, &bodies, &warm);
    for method in METHODS {
        let params = NewtonParams { method, ..NewtonParams::default() };
        let mut kept = NewtonSolver::new();
        let (mut first, mut second) = (Vec::new(), Vec::new());
        let (mut b1, mut b2) = (bodies.clone(), bodies.clone());
        let s1 = kept.solve(&problem, &params, &mut first, &mut b1).unwrap();
        let s2 = kept.solve(&problem, &params, &mut second, &mut b2).unwrap();
        assert!(!s1.symbolic_reused && s2.symbolic_reused, "{s1:?} {s2:?}");
        assert_eq!(first, second);
        assert_eq!(b1, b2);
        // A different pattern (the top box gone) is not mistaken for the kept one.
        let problem = NewtonProblem { rows: &rows[..4], warm_start: &warm[..4], ..problem };
        let s3 = kept.solve(&problem, &params, &mut first, &mut b1.clone()).unwrap();
        assert!(!s3.symbolic_reused && s3.converged, "{s3:?}");
    }
}

#[test]
fn a_row_with_a_non_finite_value_is_refused_naming_it() {
    let (mut rows, bodies) = corner();
    rows[1].normal.x = f32::NAN;
    let zero = [Impulse::default(); 2];
    let problem = exact(&rows, &bodies, &zero);
    let err = NewtonSolver::new()
        .solve(&problem, &NewtonParams::default(), &mut Vec::new(), &mut bodies.clone())
        .unwrap_err();
    assert_eq!(err, NewtonError::NonFiniteRow { row: 1, what: "normal" });
    assert!(err.to_string().contains("contact row 1: normal is not finite"));
    // The solver the simulator calls falls back to its sweeps, which clamp what they can.
    let mut bad_body = bodies.clone();
    bad_body[1].v.y = f32::INFINITY;
    let (good_rows, _) = corner();
    let problem = NewtonProblem { rows: &good_rows, bodies: &bad_body, ..problem };
    let err = NewtonSolver::new()
        .solve(&problem, &NewtonParams::default(), &mut Vec::new(), &mut bad_body.clone())
        .unwrap_err();
    assert_eq!(err, NewtonError::NonFiniteBody { body: 1, what: "velocity" });
    // MPRGP refuses the same rows, naming the same value.
    let (mut rows, bodies) = corner();
    rows[1].normal.x = f32::NAN;
    let problem = exact(&rows, &bodies, &zero);
    let err =
        crate::solver::KrylovSolver::new().solve(&problem, 100, &mut Vec::new(), &mut bodies.clone()).unwrap_err();
    assert_eq!(err, NewtonError::NonFiniteRow { row: 1, what: "normal" });
}

#[test]
fn the_per_step_bound_caps_friction_whatever_the_normal_impulse() {
    // Sliding fast on the floor, the per-step bound 0.1 (the Box2D law would allow 0.5).
    let mut rows = [floor_row(1)];
    rows[0].friction_bound = Some(0.1);
    let bodies = [SolverBody::default(), ball(Vec2::new(-5.0, -1.0))];
    for (stats, l, _) in newton(&rows, &bodies, &[Impulse::default()]) {
        assert!(stats.converged, "{stats:?}");
        assert!((l[0].tangent.abs() - 0.1).abs() < 1e-5, "{l:?}");
        let (reference, _) = sweeps(&rows, &bodies, &[Impulse::default()]);
        assert!(close(&l, &reference, 1e-4), "{l:?} vs {reference:?}");
    }
}

#[test]
fn the_contact_solver_runs_newton_and_counts_its_factorisations() {
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    for setting in [SolverSetting::NEWTON, SolverSetting::INTERIOR_POINT] {
        let mut out = bodies.clone();
        let mut s = ContactSolver::new();
        let rep = s.solve(&rows, &mut out, &warm, &params(setting));
        assert!(rep.converged && rep.factorisations > 0 && rep.factorisations == rep.sweeps, "{setting}: {rep:?}");
        assert_eq!(rep.natural, natural_residual(&rows, &out, s.impulses(), 0.0));
    }
}

#[test]
fn a_second_order_solve_short_of_the_tolerance_is_finished_by_the_sweeps() {
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    let mut out = bodies.clone();
    let mut s = ContactSolver::new();
    // Two iterations cannot reach 1e-6 from zero; the sweeps take over from its impulses.
    let capped = SolveParams { max_sweeps: 2, ..params(SolverSetting::INTERIOR_POINT) };
    let rep = s.solve(&rows, &mut out, &warm, &capped);
    assert_eq!(rep.factorisations, 2, "{rep:?}");
    assert!(rep.sweeps > rep.factorisations, "{rep:?}");
    assert_eq!(rep.natural, natural_residual(&rows, &out, s.impulses(), 0.0));
    // With room, the sweeps finish what it started.
    let mut out = bodies.clone();
    let room = SolveParams { max_sweeps: 20_000, ..capped };
    let mut handed = NewtonSolver::new();
    let mut start = Vec::new();
    let problem = exact(&rows, &bodies, &warm);
    let few = NewtonParams { max_iterations: 2, ..NewtonParams::default() };
    assert!(!handed.solve(&problem, &few, &mut start, &mut bodies.clone()).unwrap().converged);
    let rep = s.solve(&rows, &mut out, &start, &room.with_setting(SolverSetting::RECOMMENDED));
    assert!(rep.converged, "{rep:?}");
}

#[test]
fn auto_solves_with_the_fastest_measured_method_the_sweeps_so_far() {
    // No size where the interior point wins is measured yet (AUTO_NEWTON_FROM), so `auto` is
    // the recommended sweeps, step for step.
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    let solve = |setting: SolverSetting| {
        let mut out = bodies.clone();
        let mut s = ContactSolver::new();
        let rep = s.solve(&rows, &mut out, &warm, &params(setting));
        (rep.factorisations, rep.sweeps, s.impulses().to_vec())
    };
    let (factorisations, sweeps, impulses) = solve(SolverSetting::AUTO);
    assert_eq!(factorisations, 0);
    assert_eq!((sweeps, impulses), {
        let (_, sweeps, impulses) = solve(SolverSetting::RECOMMENDED);
        (sweeps, impulses)
    });
}

/// MPRGP alone (no sweeps to finish) on `rows` from `warm`, to `tolerance`.
fn mprgp(
    rows: &[ContactRow],
    bodies: &[SolverBody],
    warm: &[Impulse],
    tolerance: f32,
) -> (crate::solver::KrylovStats, Vec<Impulse>, Vec<SolverBody>) {
    let problem = NewtonProblem { tolerance, ..exact(rows, bodies, warm) };
    let (mut impulses, mut out) = (Vec::new(), bodies.to_vec());
    let stats =
        crate::solver::KrylovSolver::new().solve(&problem, 5_000, &mut impulses, &mut out).expect("finite rows");
    (stats, impulses, out)
}

#[test]
fn mprgp_reaches_the_sweeps_solution_on_the_hand_checked_cases() {
    // The stack of three: unique loads, every ball at rest.
    let (bodies, rows) = stack(3, -0.1);
    let (stats, l, out) = mprgp(&rows, &bodies, &[Impulse::default(); 3], 1e-6);
    assert!(stats.converged, "{stats:?}");
    let (swept, _) = sweeps(&rows, &bodies, &[Impulse::default(); 3]);
    assert!(close(&l, &swept, 1e-5), "{l:?} vs {swept:?}");
    assert!(out[1..].iter().all(|b| b.v.length() < 1e-5));
    // The ball in a corner with friction (impulses not unique: the ball at rest, within the cone).
    let wall = ContactRow { ra: Vec2::ZERO, rb: Vec2::new(-0.5, 0.0), normal: Vec2::X, height: 0.5, ..floor_row(1) };
    let corner = [floor_row(1), wall];
    let bodies = [SolverBody::default(), ball(Vec2::new(-2.0, -1.0))];
    let (stats, l, out) = mprgp(&corner, &bodies, &[Impulse::default(); 2], 1e-6);
    assert!(stats.converged && out[1].v.length() < 1e-5 && out[1].w.abs() < 1e-5, "{stats:?} {out:?}");
    assert!(l.iter().all(|x| x.normal > 0.0 && x.tangent.abs() <= 0.5 * x.normal + 1e-6), "{l:?}");
    assert!(natural_residual(&corner, &out, &l, 0.0).max <= 1e-6);
    // The sliding ball on the floor: friction at its bound, Box2D's law through the bound passes.
    let bodies = [SolverBody::default(), ball(Vec2::new(3.0, -1.0))];
    let (stats, l, out) = mprgp(&[floor_row(1)], &bodies, &[Impulse::default()], 1e-6);
    let (swept, swept_bodies) = sweeps(&[floor_row(1)], &bodies, &[Impulse::default()]);
    assert!(stats.converged && close(&l, &swept, 1e-5), "{stats:?} {l:?} vs {swept:?}");
    assert!((out[1].v - swept_bodies[1].v).length() < 1e-5);
}

#[test]
fn mprgp_solves_a_jammed_stack_and_leaves_zero_bound_friction_alone() {
    // Redundant rows (rank-deficient operator): converges, both boxes at rest, the same loads.
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    let (stats, l, out) = mprgp(&rows, &bodies, &warm, 1e-6);
    assert!(stats.converged, "{stats:?}");
    assert!(out[1..].iter().all(|b| b.v.length() < 1e-4 && b.w.abs() < 1e-4), "{out:?}");
    let load = |range: std::ops::Range<usize>| l[range].iter().map(|x| x.normal).sum::<f32>();
    assert!((load(0..4) - 0.6).abs() < 1e-4 && (load(4..8) - 0.4).abs() < 1e-4, "{l:?}");
    // The per-step law with a zero bound on the lower interface (no load there last step): its
    // tangents stay at zero and the rest still converges (a fixed part is never "released").
    let frozen: Vec<ContactRow> = rows
        .iter()
        .enumerate()
        .map(|(i, r)| ContactRow { friction_bound: Some(if i < 4 { 0.0 } else { 0.3 }), ..*r })
        .collect();
    let (stats, l, out) = mprgp(&frozen, &bodies, &warm, 1e-6);
    assert!(stats.converged && stats.proportionings < 100, "{stats:?}");
    assert!(l[..4].iter().all(|x| x.tangent == 0.0), "{l:?}");
    assert!(natural_residual(&frozen, &out, &l, 0.0).max <= 1e-5);
}

#[test]
fn mprgp_refuses_nothing_silently_and_reports_where_it_stood() {
    // Capped at 2 iterations on the jammed stack: not converged, and the residual it reports is
    // the natural residual of the impulses and velocities it returns.
    let (rows, bodies) = jammed();
    let warm = vec![Impulse::default(); rows.len()];
    let problem = NewtonProblem { tolerance: 1e-9, ..exact(&rows, &bodies, &warm) };
    let (mut l, mut out) = (Vec::new(), bodies.clone());
    let stats = crate::solver::KrylovSolver::new().solve(&problem, 2, &mut l, &mut out).unwrap();
    assert!(!stats.converged && stats.iterations == 2, "{stats:?}");
    let measured = natural_residual(&rows, &out, &l, 0.0).max as f64;
    assert!((measured - stats.natural_max).abs() <= 1e-5 * (1.0 + measured), "{measured} vs {stats:?}");
}

fn interior(ordering: Ordering) -> NewtonParams {
    NewtonParams { method: SecondOrder::InteriorPoint, ordering, ..NewtonParams::default() }
}

#[test]
fn nested_dissection_solves_a_pile_as_minimum_degree_does_with_little_fill() {
    let (bodies, rows) = lattice(30, 20);
    let warm = vec![Impulse::default(); rows.len()];
    let problem = NewtonProblem { tolerance: 1e-5, ..exact(&rows, &bodies, &warm) };
    let mut answers = Vec::new();
    for ordering in [Ordering::MinimumDegree, Ordering::Dissection] {
        let (mut l, mut out) = (Vec::new(), bodies.clone());
        let stats = NewtonSolver::new().solve(&problem, &interior(ordering), &mut l, &mut out).unwrap();
        assert!(stats.converged && stats.natural_max <= 1e-5, "{ordering:?}: {stats:?}");
        assert!(natural_residual(&rows, &out, &l, 0.0).max <= 2e-5, "{ordering:?}");
        assert!(stats.symbolic_seconds > 0.0 && stats.numeric_seconds > 0.0, "{stats:?}");
        answers.push((stats, out));
    }
    let (amd, nd) = (&answers[0], &answers[1]);
    // The same velocities (the solution's, unique); nested dissection's factor no larger than
    // 1.5x minimum degree's (an inverted order would fill several times more).
    for (a, b) in amd.1.iter().zip(&nd.1) {
        assert!((a.v - b.v).length() < 1e-3 && (a.w - b.w).abs() < 1e-3, "{a:?} vs {b:?}");
    }
    assert!(
        nd.0.factor_entries as f64 <= 1.5 * amd.0.factor_entries as f64,
        "fill: nested dissection {} against minimum degree {}",
        nd.0.factor_entries,
        amd.0.factor_entries
    );
}

#[test]
fn nested_dissection_keeps_its_analysis_while_the_pairs_stay_among_the_kept_ones() {
    let (bodies, rows) = lattice(12, 8);
    let warm = vec![Impulse::default(); rows.len()];
    let full = NewtonProblem { tolerance: 1e-5, ..exact(&rows, &bodies, &warm) };
    // Contacts lost: every 5th row dropped (the body pairs a subset of the full lattice's).
    let fewer: Vec<ContactRow> = rows.iter().enumerate().filter(|(k, _)| k % 5 != 2).map(|(_, r)| *r).collect();
    let fewer_warm = vec![Impulse::default(); fewer.len()];
    let subset = NewtonProblem { rows: &fewer, warm_start: &fewer_warm, ..full };
    let solve = |solver: &mut NewtonSolver, problem: &NewtonProblem<'_>, ordering| {
        let (mut l, mut out) = (Vec::new(), bodies.clone());
        let stats = solver.solve(problem, &interior(ordering), &mut l, &mut out).unwrap();
        (stats, l, out)
    };
    for ordering in [Ordering::Dissection, Ordering::MinimumDegree] {
        let mut kept = NewtonSolver::new();
        let (first, ..) = solve(&mut kept, &full, ordering);
        let (second, l, out) = solve(&mut kept, &subset, ordering);
        assert!(!first.symbolic_reused && first.converged);
        // Only nested dissection keeps a superset pattern; minimum degree needs the same pairs.
        assert_eq!(second.symbolic_reused, ordering == Ordering::Dissection, "{ordering:?}: {second:?}");
        assert!(second.converged, "{ordering:?}: {second:?}");
        if second.symbolic_reused {
            assert_eq!(second.symbolic_seconds, 0.0);
        }
        // The kept pattern's zeros change nothing but round-off: a fresh solver's answer.
        let (_, fresh_l, fresh_out) = solve(&mut NewtonSolver::new(), &subset, ordering);
        assert!(close(&l, &fresh_l, 1e-3), "{ordering:?}");
        for (a, b) in out.iter().zip(&fresh_out) {
            assert!((a.v - b.v).length() < 1e-4, "{a:?} vs {b:?}");
        }
        // A pair the kept pattern lacks (a diagonal neighbour) needs a new analysis.
        let mut more = rows.clone();
        more.push(ContactRow { body_a: 1, body_b: 14, ..rows[1] });
        let more_warm = vec![Impulse::default(); more.len()];
        let grown = NewtonProblem { rows: &more, warm_start: &more_warm, ..full };
        let (third, ..) = solve(&mut kept, &grown, ordering);
        assert!(!third.symbolic_reused, "{ordering:?}: {third:?}");
    }
}

#[test]
fn the_contact_solver_spells_and_runs_nested_dissection_from_the_centred_start() {
    let (mut bodies, rows) = lattice(10, 6);
    let setting: SolverSetting = "ipm:nd+warm".parse().unwrap();
    assert_eq!(setting.method, Method::InteriorPoint(InteriorVariant { dissection: true, centred_start: true }));
    assert_eq!(setting.to_string(), "ipm:nd+warm");
    let mut solver = ContactSolver::new();
    let report = solver.solve(&rows, &mut bodies, &vec![Impulse::default(); rows.len()], &params(setting));
    assert!(report.converged && report.factorisations > 0, "{report:?}");
    let stats = solver.newton_stats().expect("it factorised");
    assert!(stats.factor_entries > 0 && !stats.symbolic_reused, "{stats:?}");
    // The sweeps factorise nothing.
    solver.solve(&rows, &mut bodies, &vec![Impulse::default(); rows.len()], &params(SolverSetting::RECOMMENDED));
    assert!(solver.newton_stats().is_none());
}

#[test]
fn the_centred_start_reaches_the_same_solution_and_uses_a_good_warm_start() {
    let (bodies, rows) = lattice(16, 10);
    let zero = vec![Impulse::default(); rows.len()];
    let solve = |warm: &[Impulse], centred: Option<f64>| {
        let problem = NewtonProblem { tolerance: 1e-5, ..exact(&rows, &bodies, warm) };
        let (mut l, mut out) = (Vec::new(), bodies.clone());
        let params = NewtonParams { centred_start: centred, ..interior(Ordering::Dissection) };
        let stats = NewtonSolver::new().solve(&problem, &params, &mut l, &mut out).unwrap();
        assert!(stats.converged, "{centred:?}: {stats:?}");
        (stats, l, out)
    };
    let (_, solution, reference) = solve(&zero, None);
    let (cold, _, out) = solve(&zero, Some(crate::solver::CENTRED_START));
    for (a, b) in out.iter().zip(&reference) {
        assert!((a.v - b.v).length() < 1e-3, "{a:?} vs {b:?}");
    }
    // From a warm start near the solution (the solution, a little off), the centred start needs
    // fewer iterations than from nothing, and no more than the fixed push inside.
    let near: Vec<Impulse> =
        solution.iter().map(|l| Impulse { normal: 1.01 * l.normal, tangent: 0.99 * l.tangent }).collect();
    let (fixed, ..) = solve(&near, None);
    let (centred, ..) = solve(&near, Some(crate::solver::CENTRED_START));
    assert!(centred.iterations < cold.iterations, "warm {centred:?} cold {cold:?}");
    assert!(centred.iterations <= fixed.iterations, "centred {centred:?} fixed {fixed:?}");
}
