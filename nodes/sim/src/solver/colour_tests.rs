//! The colour order against its invariants and against the one-thread sweeps. Kept apart from
//! `colour.rs` because they call the solver ([`super::pgs`]), which calls the colour order in turn.

use super::colour::*;
use super::rows::{ContactRow, Impulse, SolverBody};
use super::setting::StopRule;
use super::sweep::{SolveParams, SolveReport};
use crate::solver::rows::fixtures::{ball, floor_row};
use crate::solver::{ContactSolver, RowOrder, SolverSetting};
use rapier2d::math::Vec2;

/// A pile of unit balls on a triangular lattice, `wide` x `high`, on a floor (body 0) and
/// falling at 1 m/s and sliding right: rows to the floor, to the left neighbour and to both below; and one
/// row between the floor and a second static body (no moving body).
fn lattice(wide: usize, high: usize) -> (Vec<SolverBody>, Vec<ContactRow>) {
    let mut bodies = vec![SolverBody::default(), SolverBody::default()];
    let id = |i: usize, j: usize| (2 + j * wide + i) as u32;
    bodies.extend((0..wide * high).map(|_| ball(Vec2::new(0.1, -1.0))));
    let mut rows = Vec::new();
    let row = |a: u32, b: u32, normal: Vec2, height: f32| ContactRow {
        body_a: a,
        body_b: b,
        ra: if a < 2 { Vec2::ZERO } else { normal * 0.5 },
        rb: -normal * 0.5,
        normal,
        friction: 0.5,
        height,
        // The per-step law's fixed bound: a convex problem, which every iteration solves.
        friction_bound: Some(0.2),
    };
    let diagonal = Vec2::new(0.5, 0.75f32.sqrt());
    for j in 0..high {
        let height = j as f32 * 0.87 + 0.5;
        for i in 0..wide {
            if j == 0 {
                rows.push(row(0, id(i, j), Vec2::Y, 0.0));
            } else {
                rows.push(row(id(i, j - 1), id(i, j), diagonal, height - 0.43));
                if i + 1 < wide {
                    rows.push(row(id(i + 1, j - 1), id(i, j), Vec2::new(-diagonal.x, diagonal.y), height - 0.43));
                }
            }
            if i > 0 {
                rows.push(row(id(i - 1, j), id(i, j), Vec2::X, height));
            }
        }
    }
    rows.push(row(0, 1, Vec2::Y, 0.0));
    (bodies, rows)
}

fn params(setting: &str) -> SolveParams {
    SolveParams { tolerance: 1e-4, max_sweeps: 20_000, stop: StopRule::Natural, ..SolveParams::default() }
        .with_setting(setting.parse::<SolverSetting>().unwrap())
}

type Outcome = (SolveReport, Vec<Impulse>, Vec<SolverBody>, Vec<f32>);

fn solve_on(threads: &SweepThreads, bodies: &[SolverBody], rows: &[ContactRow], params: &SolveParams) -> Outcome {
    let mut b = bodies.to_vec();
    let mut s = ContactSolver::with_threads(threads.clone());
    let warm = vec![Impulse::default(); rows.len()];
    let report = s.solve(rows, &mut b, &warm, params);
    (report, s.impulses().to_vec(), b, s.residuals().to_vec())
}

#[test]
fn no_two_rows_of_a_colour_share_a_moving_body_and_each_colour_goes_top_down() {
    let (bodies, rows) = lattice(20, 15);
    let mut visit: Vec<u32> = (0..rows.len() as u32).collect();
    visit.sort_by(|&i, &j| rows[j as usize].height.total_cmp(&rows[i as usize].height));
    let mut colouring = Colouring::default();
    colouring.colour(&rows, &bodies, &mut visit, 1);
    let mut seen = visit.clone();
    seen.sort();
    assert_eq!(seen, (0..rows.len() as u32).collect::<Vec<_>>(), "every row once");
    assert_eq!(colouring.overflow_rows(), 0);
    assert!(colouring.colours() <= 8, "{} colours for a lattice of degree 6", colouring.colours());
    for range in colouring.colour_rows() {
        let mut owner = std::collections::HashMap::new();
        let colour = &visit[range];
        for (k, &i) in colour.iter().enumerate() {
            let r = &rows[i as usize];
            for b in [r.body_a, r.body_b].into_iter().filter(|&b| bodies[b as usize].moves()) {
                assert!(owner.insert(b, i).is_none(), "body {b} in two rows of one colour");
            }
            if k > 0 {
                assert!(rows[colour[k - 1] as usize].height >= r.height, "a colour keeps the top-down order");
            }
        }
    }
    // The row between two static bodies took a colour and moves nothing.
    assert!(visit.contains(&(rows.len() as u32 - 1)));
}

#[test]
fn bands_are_coloured_apart_and_swept_top_to_bottom() {
    let (bodies, rows) = lattice(20, 15);
    let mut visit: Vec<u32> = (0..rows.len() as u32).collect();
    visit.sort_by(|&i, &j| rows[j as usize].height.total_cmp(&rows[i as usize].height));
    let top_down = visit.clone();
    let mut colouring = Colouring::default();
    colouring.colour(&rows, &bodies, &mut visit, 3);
    // Each third of the top-down order stays in its place, coloured within itself.
    let third = rows.len().div_ceil(3);
    for (band, (mine, was)) in visit.chunks(third).zip(top_down.chunks(third)).enumerate() {
        let (mut a, mut b) = (mine.to_vec(), was.to_vec());
        a.sort();
        b.sort();
        assert_eq!(a, b, "band {band}");
    }
    for range in colouring.colour_rows() {
        assert_eq!(range.start / third, (range.end - 1) / third, "a colour within one band");
        let mut owner = std::collections::HashSet::new();
        for &i in &visit[range] {
            let r = &rows[i as usize];
            for b in [r.body_a, r.body_b].into_iter().filter(|&b| bodies[b as usize].moves()) {
                assert!(owner.insert(b), "body {b} in two rows of one colour");
            }
        }
    }
    assert!(colouring.colours() > 6);
}

#[test]
fn the_colour_order_gives_the_same_bits_on_one_two_and_three_threads() {
    let (bodies, rows) = lattice(20, 15);
    assert!(rows.len() >= PARALLEL_FROM_ROWS);
    for setting in ["pgs/colour", "sor:1.3/colour", "nncg:1.2/colour"] {
        let p = params(setting);
        let one = solve_on(&SweepThreads::single(), &bodies, &rows, &p);
        assert!(one.0.converged && one.0.natural.max <= 1e-4, "{setting}: {:?}", one.0);
        for threads in [2, 3] {
            let many = SweepThreads::new(threads).unwrap();
            assert_eq!(solve_on(&many, &bodies, &rows, &p), one, "{setting} on {threads} threads");
            assert_eq!(solve_on(&many, &bodies, &rows, &p), one, "{setting} on {threads} threads, again");
        }
        // The same problem solved top-down: another order, the same solution's accuracy.
        let down = solve_on(&SweepThreads::single(), &bodies, &rows, &params(&setting.replace("colour", "down")));
        assert!(down.0.converged && down.0.sweeps != one.0.sweeps, "{setting}: {:?} {:?}", down.0, one.0);
    }
}

#[test]
fn a_busy_pool_solves_on_the_calling_thread_with_the_same_answer() {
    let (bodies, rows) = lattice(20, 15);
    let threads = SweepThreads::new(2).unwrap();
    let p = params("nncg:1.2/colour");
    let free = solve_on(&threads, &bodies, &rows, &p);
    let held = threads.pool.as_ref().unwrap().lock().unwrap();
    assert_eq!(solve_on(&threads, &bodies, &rows, &p), free);
    drop(held);
}

#[test]
fn rows_past_the_last_colour_go_to_the_overflow_and_still_solve() {
    // One heavy plank (body 2) under 40 balls: every ball's row is on the plank, so 40
    // rows need 40 colours; 8 overflow. The plank rests on the floor.
    let mut bodies = vec![SolverBody::default(), SolverBody::default()];
    bodies.push(SolverBody { v: Vec2::new(0.0, -1.0), w: 0.0, inv_mass: 0.01, inv_inertia: 0.0001 });
    let mut rows = vec![floor_row(2)];
    for k in 0..40 {
        bodies.push(ball(Vec2::new(0.0, -1.0)));
        rows.push(ContactRow {
            body_a: 2,
            body_b: 3 + k,
            ra: Vec2::new(k as f32 - 19.5, 0.5),
            rb: Vec2::new(0.0, -0.5),
            normal: Vec2::Y,
            friction: 0.5,
            height: 1.0,
            friction_bound: None,
        });
    }
    // Enough other rows for the pool to take part: a lattice beside it.
    let (more_bodies, more_rows) = lattice(12, 12);
    let offset = bodies.len() as u32;
    bodies.extend_from_slice(&more_bodies);
    rows.extend(more_rows.iter().map(|r| ContactRow { body_a: r.body_a + offset, body_b: r.body_b + offset, ..*r }));
    let mut visit: Vec<u32> = (0..rows.len() as u32).collect();
    visit.sort_by(|&i, &j| rows[j as usize].height.total_cmp(&rows[i as usize].height));
    let mut colouring = Colouring::default();
    colouring.colour(&rows, &bodies, &mut visit, 1);
    assert_eq!(colouring.overflow_rows(), 41 - MAX_COLOURS);
    let p = params("nncg:1.2/colour");
    let one = solve_on(&SweepThreads::single(), &bodies, &rows, &p);
    assert!(one.0.converged, "{:?}", one.0);
    assert_eq!(solve_on(&SweepThreads::new(2).unwrap(), &bodies, &rows, &p), one);
}

#[test]
fn thread_counts_outside_the_range_are_refused() {
    assert!(matches!(SweepThreads::new(0), Err(ThreadsError::Zero(0))));
    assert!(SweepThreads::new(MAX_THREADS + 1).unwrap_err().to_string().contains("at most"));
    assert_eq!(SweepThreads::new(1).unwrap().threads(), 1);
    assert_eq!(RowOrder::Colour.name(), "colour");
}
