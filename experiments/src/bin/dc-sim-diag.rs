//! `dc-sim-diag`: diagnostics of the settled-pile convergence, printed step by step for one
//! ball-box simulation: why the late steps of a pile still take hundreds of sweeps. They back the
//! finding that steps 150-249 are not at rest (bodies still move, contacts open and close and
//! change load), where a pile really at rest converges from builtin in one sweep. Hand-run, e.g.
//! `cargo run -p experiments --bin dc-sim-diag -- ball-box --seed 3` (subcommands `ball-box`,
//! `motion`, `rows`, `pair`; `--help` lists each one's options).

use anyhow::Result;
use clap::Parser;
use sim::solver::{tangent_of, ContactRow, SolverBody};
use sim::{Impulse, ModelKind, SceneConfig, World, WorldParams};
use std::collections::HashMap;

#[derive(Parser, Debug)]
#[command(name = "dc-sim-diag", about = "Diagnostics of the settled-pile convergence (one ball-box simulation)")]
struct Args {
    #[command(subcommand)]
    diag: Diag,
}

/// The diagnostics.
#[derive(clap::Subcommand, Debug)]
enum Diag {
    /// Per step: contacts added and removed, sweeps, largest impulse change, kinetic energy,
    /// deepest penetration, the residual's tail and the oracle; for the first two unconverged
    /// steps after --dump-after, the residual curve and the same problem re-solved in f64 from zero.
    BallBox {
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Warm-start model.
        #[arg(long, value_enum, default_value = "builtin")]
        model: DiagModel,
        #[arg(long, default_value_t = 250)]
        steps: u32,
        /// Unconverged steps after this one are dumped (two at most).
        #[arg(long, default_value_t = 150)]
        dump_after: u32,
        /// Print the f64 re-solve's largest change every 100 sweeps.
        #[arg(long)]
        trace: bool,
    },
    /// Steps 150..249: the three bodies with the most kinetic energy and the deepest contact.
    Motion {
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// After 160 steps: the balls of the three lowest layers, their positions and gaps.
    Rows {
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// Every third step from 100: two bodies' states and their contacts' impulses and warm starts.
    Pair {
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value_t = 40)]
        a: u32,
        #[arg(long, default_value_t = 51)]
        b: u32,
    },
}

/// The warm-start models the ball-box diagnostic compares.
#[derive(clap::ValueEnum, Debug, Clone, Copy)]
enum DiagModel {
    Builtin,
    Copy,
    None,
}

impl From<DiagModel> for ModelKind {
    fn from(m: DiagModel) -> ModelKind {
        match m {
            DiagModel::Builtin => ModelKind::Builtin,
            DiagModel::Copy => ModelKind::Copy,
            DiagModel::None => ModelKind::None,
        }
    }
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    runtime::exit(match args.diag {
        Diag::BallBox { seed, model, steps, dump_after, trace } => {
            diagnose_ball_box(seed, model.into(), steps, dump_after, trace)
        }
        Diag::Motion { seed } => diagnose_motion(seed),
        Diag::Rows { seed } => diagnose_rows(seed),
        Diag::Pair { seed, a, b } => diagnose_pair(seed, a, b),
    })
}

/// Pre-solve velocities reconstructed from the post-solve ones and the impulses.
fn pre_solve(rows: &[ContactRow], post: &[SolverBody], imp: &[Impulse]) -> Vec<[f64; 3]> {
    let mut v: Vec<[f64; 3]> = post.iter().map(|b| [b.v.x as f64, b.v.y as f64, b.w as f64]).collect();
    for (r, l) in rows.iter().zip(imp) {
        let t = tangent_of(r.normal);
        let p = r.normal * l.normal + t * l.tangent;
        let (px, py) = (p.x as f64, p.y as f64);
        let a = &post[r.body_a as usize];
        let b = &post[r.body_b as usize];
        let ca = r.ra.x as f64 * py - r.ra.y as f64 * px;
        let cb = r.rb.x as f64 * py - r.rb.y as f64 * px;
        let va = &mut v[r.body_a as usize];
        va[0] += px * a.inv_mass as f64;
        va[1] += py * a.inv_mass as f64;
        va[2] += ca * a.inv_inertia as f64;
        let vb = &mut v[r.body_b as usize];
        vb[0] -= px * b.inv_mass as f64;
        vb[1] -= py * b.inv_mass as f64;
        vb[2] -= cb * b.inv_inertia as f64;
    }
    v
}

/// f64 PGS from zero on the same rows; returns residual per sweep.
fn pgs64(
    rows: &[ContactRow],
    bodies: &[SolverBody],
    v0: &[[f64; 3]],
    sweeps: usize,
    mu_override: Option<f64>,
    trace: bool,
) -> Vec<f64> {
    let mut v = v0.to_vec();
    let mut lam = vec![[0.0f64; 2]; rows.len()];
    let im: Vec<(f64, f64)> = bodies.iter().map(|b| (b.inv_mass as f64, b.inv_inertia as f64)).collect();
    let pr: Vec<_> = rows
        .iter()
        .map(|r| {
            let n = [r.normal.x as f64, r.normal.y as f64];
            let t = [n[1], -n[0]];
            let ra = [r.ra.x as f64, r.ra.y as f64];
            let rb = [r.rb.x as f64, r.rb.y as f64];
            let (a, b) = (r.body_a as usize, r.body_b as usize);
            let k = |d: [f64; 2]| {
                let rda = ra[0] * d[1] - ra[1] * d[0];
                let rdb = rb[0] * d[1] - rb[1] * d[0];
                1.0 / (im[a].0 + im[b].0 + im[a].1 * rda * rda + im[b].1 * rdb * rdb)
            };
            (a, b, n, t, ra, rb, k(n), k(t), mu_override.unwrap_or(r.friction as f64))
        })
        .collect();
    let mut res = Vec::new();
    for sweep in 0..sweeps {
        let mut r = 0.0f64;
        let mut arg = (0usize, 0usize, 0.0f64);
        for (i, &(a, b, n, t, ra, rb, mn, mt, mu)) in pr.iter().enumerate() {
            for dir in 0..2 {
                let d = if dir == 0 { t } else { n };
                let dv = [
                    v[b][0] - v[b][2] * rb[1] - v[a][0] + v[a][2] * ra[1],
                    v[b][1] + v[b][2] * rb[0] - v[a][1] - v[a][2] * ra[0],
                ];
                let vd = dv[0] * d[0] + dv[1] * d[1];
                let old = lam[i][1 - dir];
                let new = if dir == 0 {
                    let m = mu * lam[i][0];
                    (old - mt * vd).clamp(-m, m)
                } else {
                    (old - mn * vd).max(0.0)
                };
                let dl = new - old;
                lam[i][1 - dir] = new;
                let p = [d[0] * dl, d[1] * dl];
                v[a][0] -= p[0] * im[a].0;
                v[a][1] -= p[1] * im[a].0;
                v[a][2] -= im[a].1 * (ra[0] * p[1] - ra[1] * p[0]);
                v[b][0] += p[0] * im[b].0;
                v[b][1] += p[1] * im[b].0;
                v[b][2] += im[b].1 * (rb[0] * p[1] - rb[1] * p[0]);
                if dl.abs() > r {
                    arg = (i, dir, dl);
                }
                r = r.max(dl.abs());
            }
        }
        if trace && (sweep % 100 == 99) {
            let (i, dir, dl) = arg;
            let (a, b, n, ..) = pr[i];
            println!(
                "    sweep {sweep} res {r:.2e} row {i} dir {dir} dl {dl:.2e} bodies ({a},{b}) n ({:.3},{:.3}) lam ({:.4e},{:.4e}) nrows {}",
                n[0], n[1], lam[i][0], lam[i][1], pr.len()
            );
        }
        res.push(r);
    }
    res
}

fn diagnose_ball_box(seed: u64, model: ModelKind, steps: u32, dump_after: u32, trace: bool) -> Result<()> {
    let mut world = World::new(&SceneConfig { seed, ..Default::default() }, WorldParams::default())?;
    let mut warm = model.starter(0)?;
    warm.begin_simulation(seed as u32, seed);
    let mut prev: HashMap<_, Impulse> = HashMap::new();
    let mut dumped = 0;
    for _ in 0..steps {
        let s = world.step(&mut warm).clone();
        let keys: HashMap<_, Impulse> =
            world.contacts().iter().map(|c| c.key).zip(world.impulses().iter().copied()).collect();
        let added = keys.keys().filter(|k| !prev.contains_key(*k)).count();
        let removed = prev.keys().filter(|k| !keys.contains_key(*k)).count();
        let removed_loaded = prev.iter().filter(|(k, l)| !keys.contains_key(*k) && l.normal > 1e-3).count();
        let mut dmax = 0.0f32;
        for (k, l) in &keys {
            if let Some(p) = prev.get(k) {
                dmax = dmax.max((l.normal - p.normal).abs()).max((l.tangent - p.tangent).abs());
            }
        }
        let ke: f32 = world.bodies().iter().map(|b| 0.5 * b.mass * b.v.length_squared()).sum();
        let maxpen = world.contacts().iter().map(|c| c.penetration).fold(0.0f32, f32::max);
        let res = world.residuals();
        let tail = &res[res.len().saturating_sub(200)..];
        let (tmin, tmax) = tail.iter().fold((f32::MAX, 0.0f32), |(a, b), &r| (a.min(r), b.max(r)));
        let oracle = world.oracle_report().map(|o| format!(" oracle {} {}", o.sweeps, o.converged)).unwrap_or_default();
        println!(
            "step {:3} c {:3} +{:2} -{:2} (-loaded {:2}) sweeps {:4} conv {} dmax {:.2e} ke {:.2e} maxpen {:.2e} tail[{:.1e},{:.1e}] minsep {:.2e}{}",
            s.step, s.contacts, added, removed, removed_loaded, s.sweeps, s.converged as u8, dmax, ke, maxpen,
            tmin, tmax, world.min_separation(), oracle
        );
        if !s.converged && s.step > dump_after && dumped < 2 {
            dumped += 1;
            let r: Vec<String> = res.iter().step_by(25).map(|x| format!("{x:.1e}")).collect();
            println!("  residual curve (every 25): {}", r.join(" "));
            let last: Vec<String> = res[res.len() - 20..].iter().map(|x| format!("{x:.2e}")).collect();
            println!("  last 20: {}", last.join(" "));
            // Same problem in f64 from zero, with and without friction.
            let v0 = pre_solve(world.rows(), world.solver_bodies(), world.impulses());
            for mu in [None, Some(0.0)] {
                let r64 = pgs64(world.rows(), world.solver_bodies(), &v0, 3000, mu, trace);
                let pts: Vec<String> = [1, 10, 50, 100, 200, 400, 700, 1000, 1500, 2000, 3000]
                    .iter()
                    .map(|&i| format!("{i}:{:.1e}", r64[i - 1]))
                    .collect();
                println!("  f64 from zero mu {:?}: {}", mu, pts.join(" "));
            }
            // Largest impulses and which rows change most in the last sweep: count rows with big impulses.
            let maxn = world.impulses().iter().map(|l| l.normal).fold(0.0f32, f32::max);
            println!(
                "  max normal impulse {maxn:.3e}, mass*g*dt of a ball {:.3e}",
                world.bodies()[0].mass * 9.81 * 0.01
            );
        }
        prev = keys;
    }
    Ok(())
}

fn diagnose_motion(seed: u64) -> Result<()> {
    let mut world = World::new(&SceneConfig { seed, ..Default::default() }, WorldParams::default())?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    warm.begin_simulation(seed as u32, seed);
    for _ in 0..250 {
        let s = world.step(&mut warm).clone();
        if s.step < 150 {
            continue;
        }
        let mut ke: Vec<(f32, usize)> = world
            .bodies()
            .iter()
            .enumerate()
            .map(|(i, b)| (0.5 * b.mass * b.v.length_squared() + 0.5 * b.inertia * b.w * b.w, i))
            .collect();
        ke.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap());
        let total: f32 = ke.iter().map(|k| k.0).sum();
        let mut line = format!("step {} sweeps {:4} ke {:.2e}:", s.step, s.sweeps, total);
        for &(k, i) in &ke[..3] {
            let b = &world.bodies()[i];
            let nc = world.contacts().iter().filter(|c| c.key.body_a == i as u32 || c.key.body_b == i as u32).count();
            line += &format!(
                " [#{i} ke {k:.2e} x ({:.2},{:.2}) v ({:.2},{:.2}) w {:.2} nc {nc}]",
                b.x.x, b.x.y, b.v.x, b.v.y, b.w
            );
        }
        let deep = world.contacts().iter().max_by(|a, b| a.penetration.partial_cmp(&b.penetration).unwrap()).unwrap();
        line += &format!(
            " deepest {:?} pen {:.2e} n ({:.2},{:.2})",
            (deep.key.body_a, deep.key.body_b, deep.key.feature),
            deep.penetration,
            deep.normal.x,
            deep.normal.y
        );
        println!("{line}");
    }
    Ok(())
}

fn diagnose_rows(seed: u64) -> Result<()> {
    let mut world = World::new(&SceneConfig { seed, ..Default::default() }, WorldParams::default())?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    for _ in 0..160 {
        world.step(&mut warm);
    }
    for row in 0..3 {
        let lo = 0.5 + row as f32 * 0.866 - 0.2;
        let mut xs: Vec<(f32, f32, usize)> = world
            .bodies()
            .iter()
            .enumerate()
            .filter(|(_, b)| b.mass > 0.0 && b.x.y > lo && b.x.y < lo + 0.4)
            .map(|(i, b)| (b.x.x, b.x.y, i))
            .collect();
        xs.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
        let gaps: Vec<String> = xs.windows(2).map(|w| format!("{:.4}", (w[1].0 - w[0].0) - 1.0)).collect();
        println!("layer {row}: {} balls, ids {:?}", xs.len(), xs.iter().map(|x| x.2).collect::<Vec<_>>());
        println!("  x {:?}", xs.iter().map(|x| format!("{:.4}", x.0)).collect::<Vec<_>>());
        println!("  y {:?}", xs.iter().map(|x| format!("{:.4}", x.1)).collect::<Vec<_>>());
        println!("  gaps {:?}", gaps);
    }
    Ok(())
}

fn diagnose_pair(seed: u64, a: u32, b: u32) -> Result<()> {
    let mut world = World::new(&SceneConfig { seed, ..Default::default() }, WorldParams::default())?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    for _ in 0..260 {
        let s = world.step(&mut warm).clone();
        if s.step < 100 || !s.step.is_multiple_of(3) {
            continue;
        }
        let (ba, bb) = (&world.bodies()[a as usize], &world.bodies()[b as usize]);
        let sep = (ba.x - bb.x).length() - 1.0;
        let mut line = format!(
            "step {} sweeps {:4} a ({:.4},{:.4}) va ({:.3},{:.3}) wa {:.2} b ({:.4},{:.4}) vb ({:.3},{:.3}) sep_after {:.2e}",
            s.step, s.sweeps, ba.x.x, ba.x.y, ba.v.x, ba.v.y, ba.w, bb.x.x, bb.x.y, bb.v.x, bb.v.y, sep
        );
        for (c, (l, w)) in world.contacts().iter().zip(world.impulses().iter().zip(world.warm_start_used())) {
            if c.key.body_a == a || c.key.body_b == a || c.key.body_a == b || c.key.body_b == b {
                line += &format!(
                    "\n    ({},{}) pen {:.2e} n ({:.3},{:.3}) l ({:.3},{:.3}) warm ({:.3},{:.3})",
                    c.key.body_a,
                    c.key.body_b,
                    c.penetration,
                    c.normal.x,
                    c.normal.y,
                    l.normal,
                    l.tangent,
                    w.normal,
                    w.tangent
                );
            }
        }
        println!("{line}");
    }
    Ok(())
}
