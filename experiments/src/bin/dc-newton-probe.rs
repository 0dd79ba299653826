//! `dc-newton-probe`: the Newton solver's convergence on recorded step problems of one ball-box
//! simulation, for several tunings side by side: per sampled step, its Newton iterations, outer
//! iterations and final natural residual, and (with `--trace`) the residual after each outer
//! iteration. Backs the choice of `NewtonParams`' defaults in docs/research/solver-study.md.
//! Hand-run, e.g. `cargo run -p experiments --bin dc-newton-probe -- --n 400 --steps 300`.

use anyhow::Result;
use clap::Parser;
use sim::problem::{bodies_of, builtin_warm_start, rows_of};
use sim::solver::{FrictionModel, KrylovSolver, NewtonParams, NewtonProblem, NewtonSolver, SecondOrder, SolveParams};
use sim::{ModelKind, SceneConfig, World, WorldParams};

#[derive(Parser, Debug)]
#[command(name = "dc-newton-probe", about = "The Newton solver's convergence on one simulation's step problems")]
struct Args {
    #[arg(long, default_value_t = 2000)]
    seed: u64,
    #[arg(long, default_value_t = 100)]
    n: usize,
    #[arg(long, default_value_t = 250)]
    steps: u32,
    /// Probe steps from this one, every `--every`.
    #[arg(long, default_value_t = 150)]
    from: u32,
    #[arg(long, default_value_t = 10)]
    every: u32,
    /// Friction law: box or per-step.
    #[arg(long, default_value = "box")]
    friction: String,
    /// Tunings `rho/max_inner/inner_tolerance[/rho_start/rho_growth]` (the proximal method) or
    /// `ipm` (the interior-point method; `ipm:warm=K` from the centred start, target K), or `mprgp` (conjugate gradients on the QP), comma
    /// separated.
    #[arg(long, default_value = "1e4/8/0.01")]
    tunings: String,
    #[arg(long, default_value_t = 100)]
    max_iterations: u32,
    /// Start every method from builtin's warm start after this many `nncg:1.2/down` sweeps.
    #[arg(long, default_value_t = 0)]
    pre_sweeps: u32,
    /// Print the residual after each outer iteration.
    #[arg(long)]
    trace: bool,
}

fn main() -> std::process::ExitCode {
    runtime::exit(probe(Args::parse()))
}

fn probe(args: Args) -> Result<()> {
    let friction: FrictionModel = args.friction.parse().map_err(anyhow::Error::msg)?;
    let with_mprgp = args.tunings.split(',').any(|t| t == "mprgp");
    let tunings: Vec<NewtonParams> = args
        .tunings
        .split(',')
        .filter(|t| *t != "mprgp")
        .map(|t| {
            // `ipm:warm=K`: the centred start with target K (NewtonParams::centred_start).
            let (t, centred) = match t.split_once(":warm=") {
                Some((head, k)) => (head, Some(k.parse::<f64>().expect("a number after warm="))),
                None => (t, None),
            };
            let p: Vec<f64> = t
                .trim_start_matches("ipm")
                .split('/')
                .filter(|x| !x.is_empty())
                .map(|x| x.parse().expect("a number"))
                .collect();
            let p = if p.is_empty() { vec![1e4, 8.0, 0.01] } else { p };
            NewtonParams {
                method: if t.starts_with("ipm") { SecondOrder::InteriorPoint } else { SecondOrder::Proximal },
                rho: p[0],
                max_inner: p[1] as u32,
                inner_tolerance: p[2],
                rho_start: p.get(3).copied().unwrap_or(p[0]),
                rho_growth: p.get(4).copied().unwrap_or(1.0),
                max_iterations: args.max_iterations,
                centred_start: centred,
                ..NewtonParams::default()
            }
        })
        .collect();
    let params =
        WorldParams { solve: SolveParams { friction, ..WorldParams::default().solve }, ..WorldParams::default() };
    let mut world = World::new(&SceneConfig { seed: args.seed, n: args.n, ..Default::default() }, params)?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    warm.begin_simulation(args.seed as u32, args.seed);
    world.capture_problems(None);
    let mut solvers: Vec<NewtonSolver> = tunings.iter().map(|_| NewtonSolver::new()).collect();
    let mut totals = vec![(0u32, 0u32, 0u32, 0.0f64); tunings.len()];
    let (mut krylov, mut krylov_total) = (KrylovSolver::new(), (0u32, 0u32, 0u32, 0.0f64));
    for _ in 0..args.steps {
        let report = world.step(&mut warm).clone();
        let step = report.step;
        if step < args.from || !(step - args.from).is_multiple_of(args.every) {
            continue;
        }
        let problem = world.problem().expect("capturing");
        let rows = rows_of(&problem.contacts, friction);
        let bodies = bodies_of(&problem.bodies);
        let mut warm_start = builtin_warm_start(&problem.contacts);
        if args.pre_sweeps > 0 {
            // The second-order methods start where this many sweeps of the default solver left.
            let (mut swept, mut sweeps) = (bodies.clone(), sim::ContactSolver::new());
            let pre = SolveParams { max_sweeps: args.pre_sweeps, tolerance: 0.0, friction, ..SolveParams::default() };
            sweeps.solve(&rows, &mut swept, &warm_start, &pre.with_setting(sim::SolverSetting::RECOMMENDED));
            warm_start = sweeps.impulses().to_vec();
        }
        let np = NewtonProblem {
            rows: &rows,
            bodies: &bodies,
            warm_start: &warm_start,
            compliance: problem.header.compliance,
            tolerance: problem.header.tolerance,
            deadline: None,
        };
        // The default solver from builtin's start to the step's tolerance, for scale.
        let nncg = {
            let (mut swept, mut sweeps) = (bodies.clone(), sim::ContactSolver::new());
            let to_tolerance = SolveParams {
                max_sweeps: 10_000,
                tolerance: problem.header.tolerance,
                stop: sim::StopRule::Natural,
                friction,
                ..SolveParams::default()
            };
            let start = builtin_warm_start(&problem.contacts);
            sweeps.solve(&rows, &mut swept, &start, &to_tolerance.with_setting(sim::SolverSetting::RECOMMENDED)).sweeps
        };
        print!("step {step:3} rows {:4} sweeps {:5} nncg from builtin {nncg:5}", rows.len(), report.sweeps);
        for ((t, solver), total) in tunings.iter().zip(&mut solvers).zip(&mut totals) {
            let (mut impulses, mut out) = (Vec::new(), bodies.clone());
            let clock = std::time::Instant::now();
            let stats = solver.solve(&np, t, &mut impulses, &mut out)?;
            total.3 += clock.elapsed().as_secs_f64();
            print!(" | it {:3} outer {:3} res {:.1e}", stats.iterations, stats.outer, stats.natural_max);
            total.0 += stats.iterations;
            total.1 += stats.converged as u32;
            total.2 += 1;
            if args.trace {
                let r: Vec<String> = solver.residuals().iter().map(|x| format!("{x:.1e}")).collect();
                print!("\n    {}", r.join(" "));
            }
        }
        if with_mprgp {
            let (mut impulses, mut out) = (Vec::new(), bodies.clone());
            let clock = std::time::Instant::now();
            let stats = krylov.solve(&np, 20 * args.max_iterations, &mut impulses, &mut out)?;
            krylov_total.3 += clock.elapsed().as_secs_f64();
            krylov_total.0 += stats.iterations;
            krylov_total.1 += stats.converged as u32;
            krylov_total.2 += 1;
            print!(
                " | mprgp it {:4} exp {:4} prop {:4} passes {:3} products {:4} res {:.1e}",
                stats.iterations,
                stats.expansions,
                stats.proportionings,
                stats.bound_passes,
                stats.products,
                stats.natural_max
            );
            if args.trace {
                let r: Vec<String> = krylov.residuals().iter().step_by(10).map(|x| format!("{x:.1e}")).collect();
                print!("\n    {}", r.join(" "));
            }
        }
        println!();
    }
    if with_mprgp {
        let (it, conv, n, seconds) = krylov_total;
        println!(
            "mprgp: {conv}/{n} converged, {:.1} iterations per step, {:.3} ms per step",
            it as f64 / n as f64,
            1e3 * seconds / n as f64
        );
    }
    for (t, (it, conv, n, seconds)) in tunings.iter().zip(&totals) {
        println!(
            "{t:?}: {conv}/{n} converged, {:.1} iterations per step, {:.3} ms per step, {:.1} us per iteration",
            *it as f64 / *n as f64,
            1e3 * seconds / *n as f64,
            1e6 * seconds / *it as f64
        );
    }
    Ok(())
}
