//! `dc-gnn-train`: the first training of the contact-graph network. The message-passing layers
//! keep their seeded random weights (a fixed random feature map of each contact's neighbourhood);
//! the readout is fitted in closed form (ridge regression), each step weighted by its sweeps (the
//! sweeps are in the jammed late steps), with one of two losses:
//!
//! - `mse`: the correction of builtin that the recorded reference solution makes, in velocity
//!   units (pre-training in the terms: a jammed pile's impulses are not unique, so this
//!   fits one solution among many);
//! - `residual` (default): the step's own velocity-level residual at the prediction, linearised:
//!   after builtin's impulses plus the correction, the normal velocity of every contact the
//!   reference holds closed and the tangent velocity of every contact it holds sticking should be
//!   zero. Any correction in the problem's null space costs nothing, so the model is not asked
//!   to guess where the solver happened to stop. The reference decides only the active set.
//!
//! The ridge strength (and the untrained readout, which is builtin exactly) is chosen by what
//! counts: the total sweeps of re-solving the validation problems from the model's warm start.
//!
//! Training and validation recordings come from `dc-sim --publish-problem --label-tolerance`
//! on seeds that the evaluation (0..29) never uses.
//!
//! The shipped model (`models/gnn.dcg`) is trained end to end (`--method backprop --loss
//! residual`). The closed-form readout fit (`--method readout`, still the default so that earlier
//! commands mean what they meant) and the solver-in-the-loop loss (`--loss unrolled`, `gnn::unroll`)
//! are research methods that no shipped model uses; they stay here because they share the data
//! loading, the validation re-solve and the training loop, and `--help` says which is which.

mod backprop;
mod twin;

use anyhow::{bail, Context, Result};
use gnn::net::{Linear, Net, NetConfig, Scratch};
use gnn::{features, ModelFile, Predictor};
use std::path::{Path, PathBuf};

#[derive(clap::Parser, Debug)]
#[command(
    name = "dc-gnn-train",
    about = "Train the contact-graph network on labelled recorded problems (readout fit or end to end)",
    long_about = "Train the contact-graph network on labelled recorded problems.\n\nThe shipped model is trained \
        end to end: `--method backprop --loss residual`. `--method readout` and `--loss unrolled` are research \
        methods (no shipped model uses them; kept to reproduce the README's findings)."
)]
struct Args {
    /// Training recordings (files or folders) with labelled problems: several (`--data a b`, or the
    /// flag repeated) are one data set, as the recordings of several hosts or shards.
    #[arg(long, required = true, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Validation recordings: the ridge strength is chosen by their re-solved sweeps.
    #[arg(long)]
    validation: PathBuf,
    /// Where the model goes (`.dcg`).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    net: NetConfig,
    /// Seed of the message-passing weights.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// With `readout` (research): ridge strengths tried (relative to each input's own scale; each
    /// above 0, at most 1e6).
    #[arg(long, value_delimiter = ',', default_value = "1e-4,1e-3,1e-2,1e-1,1",
          value_parser = msgs::flags::f64_above(0.0, 1e6))]
    ridge: Vec<f64>,
    /// What is minimised: `residual` (the step's velocity residual at the warm start; with
    /// compliant contacts in `backprop` the compliant one; the shipped model's), `mse` (the
    /// distance to the reference solution: a well-posed target only where it is unique, i.e.
    /// compliant contacts) or `unrolled` (research: the residual after --sweeps PGS sweeps from
    /// the warm start; backprop only).
    #[arg(long, default_value = "residual", value_parser = ["residual", "mse", "unrolled"])]
    loss: String,
    /// Research, with `--loss unrolled`: the PGS sweeps unrolled before the residual is taken (0: per step,
    /// one less than builtin took on it, at most 400; given, at most 1000).
    #[arg(long, default_value_t = 10,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(0..=1000))]
    sweeps: usize,
    /// Research, with `--loss unrolled`: the power of each change's energy in the loss (2: the energy;
    /// larger: the largest changes, which decide when PGS stops, weigh more; above 0, at most 16).
    #[arg(long, default_value_t = 2.0, value_parser = msgs::flags::f64_above(0.0, 16.0))]
    power: f64,
    /// With `--loss unrolled`: the weight of a normal row's last-sweep change that adds impulse
    /// (a contact still approaching after the sweeps: too little push, which accumulates as
    /// penetration at a fixed budget) against 1 for every other change (above 0, at most 1e6).
    #[arg(long, default_value_t = 1.0, value_parser = msgs::flags::f64_above(0.0, 1e6))]
    approach_weight: f64,
    /// `readout` (research; no shipped model uses it): the closed-form ridge fit of the readout
    /// alone; `backprop`: the whole network end to end (burn, Adam), how the shipped model is
    /// trained.
    #[arg(long, default_value = "readout", value_parser = ["readout", "backprop"])]
    method: String,
    /// With `backprop`: passes over the training steps (at most 100000), and Adam's learning rate
    /// (above 0, at most 10).
    #[arg(long, default_value_t = 2,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(0..=100_000))]
    epochs: usize,
    #[arg(long, default_value_t = 1e-3, value_parser = msgs::flags::f64_above(0.0, 10.0))]
    lr: f64,
    /// Also write every candidate beside --out, whichever wins on validation: each epoch's
    /// network (`backprop`: `<out>.epoch<N>.dcg`) or each ridge's fit (`readout`:
    /// `<out>.ridge<R>.dcg`) — e.g. to use one as a direction (`gnn-subspace`), where its size is
    /// the step's to choose and its warm-start sweeps say little.
    #[arg(long)]
    save_candidates: bool,
}

/// The labelled steps of a recording: (problem, builtin's sweeps).
fn labelled_steps(path: &Path) -> Result<Vec<(sim::problem::Problem, u32)>> {
    let mut out = Vec::new();
    for step in recorder::Steps::open(path).with_context(|| format!("opening {}", path.display()))? {
        let step = step.with_context(|| format!("reading {}", path.display()))?;
        let (Some(stats), Some((bodies, contacts))) = (step.stats, step.problem) else { continue };
        if contacts.header.reference_tolerance <= 0.0 {
            bail!("{}: problems without a reference solution (record with --label-tolerance)", path.display());
        }
        let problem = sim::problem::Problem { header: contacts.header, bodies: bodies.items, contacts: contacts.items };
        out.push((problem, stats.header.sweeps));
    }
    if out.is_empty() {
        bail!("{}: no labelled problems (record with dc-sim --publish-problem --label-tolerance)", path.display());
    }
    Ok(out)
}

/// Normal equations of the weighted least squares `readout input -> correction`.
struct Normal {
    width: usize,
    a: Vec<f64>,
    b: Vec<f64>,
    rows: u64,
}

impl Normal {
    fn new(width: usize) -> Normal {
        Normal { width, a: vec![0.0; width * width], b: vec![0.0; width * 2], rows: 0 }
    }

    /// One scalar row `z . theta = y` (all parameters in one vector, `[2][width/2]` layout).
    fn add_row(&mut self, z: &[f64], y: f64, w: f64) {
        self.add(z, [y, 0.0], w);
    }

    /// One row `z . W = y` of both outputs, weight `w`.
    fn add(&mut self, z: &[f64], y: [f64; 2], w: f64) {
        let d = self.width;
        for (i, (a_row, &zi)) in self.a.chunks_exact_mut(d).zip(z).enumerate() {
            let wz = w * zi;
            if wz == 0.0 {
                continue;
            }
            for (a, &zj) in a_row.iter_mut().zip(z) {
                *a += wz * zj;
            }
            self.b[i * 2] += wz * y[0];
            self.b[i * 2 + 1] += wz * y[1];
        }
        self.rows += 1;
    }

    /// The weights `[2][width]` of `(A + ridge diag(A)) W = B` (Cholesky); the last input is the
    /// constant 1, not penalised.
    fn solve(&self, ridge: f64) -> Result<Vec<f64>> {
        let d = self.width;
        let mut m = self.a.clone();
        for i in 0..d - 1 {
            m[i * d + i] += ridge * self.a[i * d + i].max(1e-12);
        }
        m[(d - 1) * d + d - 1] += 1e-9;
        // Cholesky: m = L L^T.
        let mut l = vec![0.0; d * d];
        for i in 0..d {
            for j in 0..=i {
                let s: f64 = (0..j).map(|k| l[i * d + k] * l[j * d + k]).sum();
                if i == j {
                    let v = m[i * d + i] - s;
                    if v <= 0.0 {
                        bail!("the normal equations are not positive definite (ridge {ridge})");
                    }
                    l[i * d + i] = v.sqrt();
                } else {
                    l[i * d + j] = (m[i * d + j] - s) / l[j * d + j];
                }
            }
        }
        let mut w = vec![0.0; 2 * d];
        for out in 0..2 {
            let mut y: Vec<f64> = (0..d).map(|i| self.b[i * 2 + out]).collect();
            for i in 0..d {
                let s: f64 = (0..i).map(|k| l[i * d + k] * y[k]).sum();
                y[i] = (y[i] - s) / l[i * d + i];
            }
            for i in (0..d).rev() {
                let s: f64 = (i + 1..d).map(|k| l[k * d + i] * y[k]).sum();
                y[i] = (y[i] - s) / l[i * d + i];
            }
            w[out * d..(out + 1) * d].copy_from_slice(&y);
        }
        Ok(w)
    }
}

/// The linearised velocity residual's normal equations: per step, the readout's effect on every
/// residual row through the problem's Delassus operator.
struct Residual {
    normal: Normal,
    p: Vec<[f64; 2]>,
    columns: Vec<Vec<[f64; 2]>>,
}

impl Residual {
    fn new(width: usize) -> Residual {
        Residual { normal: Normal::new(2 * width), p: Vec::new(), columns: Vec::new() }
    }

    /// Rows of one step: `x` its contact features (velocities after builtin at 9 and 10), `z` the
    /// readout inputs (`readout` each, the constant 1 appended here), `w` its weight.
    fn add_step(
        &mut self,
        problem: &sim::problem::Problem,
        x: &[f32],
        masses: &[[f32; 2]],
        z: &[f32],
        readout: usize,
        w: f64,
    ) {
        let d = readout + 1;
        let n = problem.contacts.len();
        let operator = gnn::unroll::Unrolled::new(&problem.bodies, &problem.contacts);
        // Column (out, i): the velocities caused by the impulses that parameter puts on every contact.
        self.columns.resize(2 * d, Vec::new());
        for out in 0..2 {
            for i in 0..d {
                self.p.clear();
                self.p.extend((0..n).map(|c| {
                    let zi = if i == readout { 1.0 } else { z[c * readout + i] as f64 };
                    let mut imp = [0.0; 2];
                    imp[out] = masses[c][out] as f64 * zi;
                    imp
                }));
                self.columns[out * d + i] = operator.delassus(&self.p);
            }
        }
        let mut row = vec![0.0; 2 * d];
        for (c, contact) in problem.contacts.iter().enumerate() {
            let [rn, rt] = contact.reference;
            if rn.is_nan() || rn <= 1e-6 || masses[c][0] <= 0.0 {
                continue; // open at the solution (or fixed): no velocity to cancel
            }
            let sticking = rt.abs() < 0.999 * contact.friction * rn;
            let base = &x[c * gnn::features::CONTACT_FEATURES..];
            for (component, v0) in [(0usize, base[9]), (1, base[10])] {
                if component == 1 && !sticking {
                    continue;
                }
                for (k, col) in self.columns.iter().enumerate() {
                    row[k] = col[c][component];
                }
                self.normal.add_row(&row, -(v0 as f64), w);
            }
        }
    }
}

/// `--method backprop`: the whole network, end to end; the best epoch on validation sweeps (or
/// the untrained network, builtin) is saved.
fn train_end_to_end(
    args: &Args,
    net: &Net,
    train: &[(sim::problem::Problem, u32)],
    validation: &[(sim::problem::Problem, u32)],
) -> Result<()> {
    let mean_sweeps = train.iter().map(|(_, s)| *s as f64).sum::<f64>() / train.len() as f64;
    let data: Vec<backprop::StepData> = train
        .iter()
        .enumerate()
        .filter_map(|(i, (p, s))| backprop::StepData::new(p, i, (*s as f64 / mean_sweeps) as f32))
        .collect();
    let objective = match args.loss.as_str() {
        "residual" => backprop::Objective::Residual,
        "unrolled" => backprop::Objective::Unrolled {
            sweeps: args.sweeps,
            weights: backprop::LossWeights { power: args.power, approach: args.approach_weight },
        },
        "mse" => {
            if train.iter().any(|(p, _)| p.header.compliance == 0.0) {
                tracing::warn!(
                    "--loss mse on rigid problems: their reference is one of many solutions (record with --compliance)"
                );
            }
            backprop::Objective::Mse
        }
        other => bail!("unknown --loss {other}"),
    };
    let builtin: u64 = validation.iter().map(|(_, s)| *s as u64).sum();
    let untrained = validation_sweeps(net, validation);
    println!(
        "backprop on the {} loss: {} steps with contacts; validation sweeps: builtin {builtin}, untrained {untrained}",
        args.loss,
        data.len()
    );
    // The loss on the validation steps too (weighted by the training steps' mean sweeps), so a
    // loss that falls can be told from one that generalises.
    let validation_data: Vec<backprop::StepData> = validation
        .iter()
        .enumerate()
        .filter_map(|(i, (p, s))| backprop::StepData::new(p, i, (*s as f64 / mean_sweeps) as f32))
        .collect();
    let validation_loss = |n: &Net| backprop::mean_loss(n, &validation_data, validation, objective);
    let shown = |l: Option<f64>| l.map_or(String::new(), |l| format!(" (validation {l:.4e})"));
    if let Some(loss) = backprop::mean_loss(net, &data, train, objective) {
        println!("  untrained: mean loss {loss:.4e}{}", shown(validation_loss(net)));
    }
    // Which epoch is kept: the fewest validation sweeps to tolerance, or, for a warm start
    // trained for a fixed budget (`--loss unrolled --sweeps K`), the smallest validation loss —
    // the residual after K sweeps, what the budget is judged on (problems recorded at a budget
    // are re-solved to it, so their sweeps are all K and choose nothing).
    let by_loss = matches!(objective, backprop::Objective::Unrolled { sweeps, .. } if sweeps > 0);
    let key = |sweeps: u64, n: &Net| if by_loss { validation_loss(n).unwrap_or(f64::INFINITY) } else { sweeps as f64 };
    let mut best = (key(untrained, net), untrained, 0usize, net.clone());
    let started = std::time::Instant::now();
    // Epochs with the time left, on a terminal only (stderr; hidden otherwise).
    let bar = indicatif::ProgressBar::new(args.epochs as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("train [{bar:30}] {pos}/{len} epochs ({elapsed}, ~{eta} left)")
            .expect("valid template")
            .progress_chars("=> "),
    );
    backprop::train(net, &data, train, objective, args.epochs, args.lr, args.seed, |epoch, candidate, loss| {
        let sweeps = validation_sweeps(candidate, validation);
        bar.suspend(|| {
            println!(
                "  epoch {}: mean loss {loss:.4e}{}, validation {sweeps} sweeps ({:.3}x builtin), {:.0} s",
                epoch + 1,
                shown(validation_loss(candidate)),
                sweeps as f64 / builtin as f64,
                started.elapsed().as_secs_f64()
            )
        });
        bar.inc(1);
        if args.save_candidates {
            let how = format!("epoch {} of end to end training on the {} loss (lr {})", epoch + 1, args.loss, args.lr);
            save_candidate(args, &format!("epoch{}", epoch + 1), candidate, &how, sweeps);
        }
        let k = key(sweeps, candidate);
        if k < best.0 {
            best = (k, sweeps, epoch + 1, candidate.clone());
        }
    });
    bar.finish_and_clear();
    let (_, sweeps, epoch, model) = best;
    let how = format!(
        "end to end on the {} loss{} (Adam, lr {}, {} epochs, best epoch {epoch} by validation {}; 0 = untrained, builtin) on {} steps",
        args.loss,
        match (args.loss.as_str(), args.sweeps) {
            ("unrolled", 0) => format!(" after builtin's sweeps less one (power {})", args.power),
            ("unrolled", k) => format!(" after {k} sweeps (power {}, approach weight {})", args.power, args.approach_weight),
            _ => String::new(),
        },
        args.lr,
        args.epochs,
        if by_loss { "loss" } else { "sweeps" },
        data.len()
    );
    save(args, model, &how, sweeps, builtin, validation.len())
}

/// The decoder of the fitted weights (`[2][width]`, the last column the bias).
fn decoder(w: &[f64], readout: usize) -> Linear {
    let d = readout + 1;
    let mut lin = Linear::zeros(readout, 2);
    for out in 0..2 {
        for i in 0..readout {
            lin.weight[out * readout + i] = w[out * d + i] as f32;
        }
        lin.bias[out] = w[out * d + readout] as f32;
    }
    lin
}

/// Total sweeps of re-solving `steps` from `net`'s warm start.
fn validation_sweeps(net: &Net, steps: &[(sim::problem::Problem, u32)]) -> u64 {
    let mut p = Predictor::new(net.clone());
    let mut warm = Vec::new();
    steps
        .iter()
        .map(|(problem, _)| {
            warm.clear();
            warm.resize(problem.contacts.len(), [0.0; 2]);
            if p.warm_start(&problem.bodies, &problem.contacts, &mut warm).is_err() {
                // Overflowed: the simulator would fall back to builtin's start, so count that.
                warm.iter_mut().zip(&problem.contacts).for_each(|(w, c)| *w = c.previous);
            }
            let start: Vec<sim::Impulse> = warm.iter().map(|w| sim::Impulse { normal: w[0], tangent: w[1] }).collect();
            problem.solve(&start).0.sweeps as u64
        })
        .sum()
}

fn main() -> std::process::ExitCode {
    runtime::exit(try_main())
}

fn try_main() -> Result<()> {
    let Some(args) = runtime::parse_args::<Args>() else { return Ok(()) };
    runtime::init_logging();
    let mut train = Vec::new();
    for data in &args.data {
        train.extend(labelled_steps(data)?);
    }
    let validation = labelled_steps(&args.validation)?;
    let net = Net::new(args.net, args.seed);
    let readout = net.readout_width();
    println!(
        "dc-gnn-train: {} training steps, {} validation steps, readout width {readout}",
        train.len(),
        validation.len()
    );

    if args.method == "backprop" {
        return train_end_to_end(&args, &net, &train, &validation);
    }
    let mut normal = Normal::new(readout + 1);
    let mut residual = Residual::new(readout + 1);
    let (mut xc, mut xb, mut masses, mut pairs, mut z) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut scratch = Scratch::default();
    let mean_sweeps = train.iter().map(|(_, s)| *s as f64).sum::<f64>() / train.len() as f64;
    for (problem, sweeps) in &train {
        features::features(&problem.bodies, &problem.contacts, &mut xc, &mut xb, &mut masses);
        pairs.clear();
        pairs.extend(problem.contacts.iter().map(|c| (c.body_a, c.body_b)));
        net.readout_inputs(&xc, &xb, &pairs, &mut scratch, &mut z);
        // Each step weighs what it costs builtin; its contacts share that weight.
        let w = *sweeps as f64 / mean_sweeps / problem.contacts.len().max(1) as f64;
        if args.loss == "residual" {
            residual.add_step(problem, &xc, &masses, &z, readout, w);
            continue;
        }
        let mut row = vec![0.0f64; readout + 1];
        for ((c, k), zc) in problem.contacts.iter().zip(&masses).zip(z.chunks_exact(readout)) {
            if k[0] <= 0.0 || k[1] <= 0.0 || !c.reference.iter().all(|r| r.is_finite()) {
                continue;
            }
            let y =
                [((c.reference[0] - c.previous[0]) / k[0]) as f64, ((c.reference[1] - c.previous[1]) / k[1]) as f64];
            for (r, v) in row.iter_mut().zip(zc) {
                *r = *v as f64;
            }
            row[readout] = 1.0;
            normal.add(&row, y, w);
        }
    }
    let fitted = if args.loss == "residual" { &residual.normal } else { &normal };
    println!("loss {}: fitted on {} rows", args.loss, fitted.rows);

    let builtin: u64 = validation.iter().map(|(_, s)| *s as u64).sum();
    let untrained = validation_sweeps(&net, &validation);
    println!("validation sweeps: builtin (recorded) {builtin}, untrained network (re-solved) {untrained}");
    // The untrained readout (builtin itself) is a candidate too: a fit that does not beat it on
    // validation is not shipped.
    let mut best: Option<(u64, f64, Net)> = Some((untrained, f64::INFINITY, net.clone()));
    for &ridge in &args.ridge {
        let mut candidate = net.clone();
        // The residual fit solves for both outputs' weights in one vector: its first block.
        let w = fitted.solve(ridge)?;
        candidate.decode = decoder(&w[..2 * (readout + 1)], readout);
        let sweeps = validation_sweeps(&candidate, &validation);
        println!("  ridge {ridge:e}: {sweeps} sweeps ({:.3}x builtin)", sweeps as f64 / builtin as f64);
        if args.save_candidates {
            let how = format!("readout fit on the {} loss, ridge {ridge:e}", args.loss);
            save_candidate(&args, &format!("ridge{ridge:e}"), &candidate, &how, sweeps);
        }
        if best.as_ref().is_none_or(|(s, _, _)| sweeps < *s) {
            best = Some((sweeps, ridge, candidate));
        }
    }
    let (sweeps, ridge, model) = best.context("no ridge strength given")?;
    let how = format!(
        "readout ridge-fitted to the {} loss (strength {ridge:e}; inf = untrained, builtin) on {} steps",
        args.loss,
        train.len()
    );
    save(&args, model, &how, sweeps, builtin, validation.len())
}

/// Writes the model with its provenance: how it was made, and what it did on validation.
/// Writes a candidate that may not win beside --out (`<out>.<tag>.dcg`); a failure is said, not fatal.
fn save_candidate(args: &Args, tag: &str, model: &Net, how: &str, sweeps: u64) {
    let path = args.out.with_extension(format!("{tag}.dcg"));
    let provenance = format!("dc-gnn-train: {how}; validation {sweeps} sweeps re-solved");
    match ModelFile::new(model.clone(), &provenance).save(&path) {
        Ok(()) => println!("  wrote {}", path.display()),
        Err(e) => eprintln!("  could not write {}: {e}", path.display()),
    }
}

fn save(args: &Args, model: Net, how: &str, sweeps: u64, builtin: u64, validation_steps: usize) -> Result<()> {
    let provenance = format!(
        "dc-gnn-train: {how} of {}, hidden {}, {} rounds, seed {}; validation {validation_steps} steps of {}: {sweeps} sweeps re-solved = {:.3}x builtin",
        args.data.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(" + "),
        args.net.hidden,
        args.net.rounds,
        args.seed,
        args.validation.display(),
        sweeps as f64 / builtin as f64
    );
    ModelFile::new(model, &provenance).save(&args.out)?;
    println!("wrote {} ({provenance})", args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::{ProblemBody, ProblemContact, ProblemHeader};

    /// The unrolled sweeps (`gnn::unroll`, which the crate keeps free of the simulator) are the
    /// simulator's: its solver's converged impulses leave nothing for one more sweep to change.
    #[test]
    fn the_simulators_solution_leaves_no_unrolled_residual() {
        // A column of three balls on the floor (body 0), each pushed down, the top one sliding.
        let bodies: Vec<ProblemBody> = std::iter::once(ProblemBody::default())
            .chain((1..4).map(|i| ProblemBody {
                v: [0.02 * i as f32, -0.1 * i as f32],
                w: 0.0,
                inv_mass: 1.0 / i as f32,
                inv_inertia: 2.0,
            }))
            .collect();
        let contacts: Vec<ProblemContact> = (0..3u32)
            .map(|i| ProblemContact {
                body_a: i,
                body_b: i + 1,
                normal: [0.0, 1.0],
                ra: [0.0, if i == 0 { 0.0 } else { 0.5 }],
                rb: [0.0, -0.5],
                friction: 0.3,
                ..Default::default()
            })
            .collect();
        let params = sim::SolveParams { tolerance: 1e-9, max_sweeps: 100_000, ..Default::default() };
        let (_, solved) =
            sim::problem::solve(&bodies, &contacts, &vec![sim::Impulse::default(); contacts.len()], &params);
        let warm: Vec<[f64; 2]> = solved.iter().map(|s| [s.normal as f64, s.tangent as f64]).collect();
        assert!(warm.iter().any(|w| w[0] > 1e-3), "the pile pushes: {warm:?}");
        let (loss, _) = gnn::unroll::Unrolled::new(&bodies, &contacts).loss_and_gradient(&warm, 0);
        assert!(loss < 1e-12, "{loss}");
        // From no impulse at all, the same sweep has a lot to change.
        let (from_zero, _) =
            gnn::unroll::Unrolled::new(&bodies, &contacts).loss_and_gradient(&vec![[0.0; 2]; contacts.len()], 0);
        assert!(from_zero > 1e-6, "{from_zero}");
    }

    #[test]
    fn least_squares_recovers_known_weights() {
        // y = 2 z0 - z1 + 0.5 (bias), second output = z1; exact rows, tiny ridge.
        let mut n = Normal::new(3);
        let mut rng = 3u64;
        let mut unit = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..200 {
            let (z0, z1) = (unit(), unit());
            n.add(&[z0, z1, 1.0], [2.0 * z0 - z1 + 0.5, z1], 1.0);
        }
        let w = n.solve(1e-9).unwrap();
        for (got, want) in w.iter().zip([2.0, -1.0, 0.5, 0.0, 1.0, 0.0]) {
            assert!((got - want).abs() < 1e-5, "{w:?}");
        }
    }

    #[test]
    fn the_delassus_response_is_symmetric() {
        // p . G q == q . G p for any impulses: what makes the residual fit a least-squares problem.
        let body = |m: f32| ProblemBody { v: [0.0; 2], w: 0.0, inv_mass: m, inv_inertia: 3.0 * m };
        let contact = |a: u32, b: u32, angle: f32| ProblemContact {
            body_a: a,
            body_b: b,
            normal: [angle.cos(), angle.sin()],
            ra: [0.2, -0.1],
            rb: [-0.3, 0.25],
            friction: 0.5,
            ..Default::default()
        };
        let problem = sim::problem::Problem {
            header: ProblemHeader::default(),
            bodies: vec![body(0.0), body(1.0), body(0.5), body(2.0)],
            contacts: vec![contact(0, 1, 1.2), contact(1, 2, 0.3), contact(2, 3, -0.7), contact(1, 3, 2.0)],
        };
        let p = [[0.3, -0.1], [1.0, 0.2], [0.0, 0.5], [-0.4, 0.1]];
        let q = [[0.1, 0.1], [-0.2, 0.3], [0.7, 0.0], [0.2, -0.6]];
        let operator = gnn::unroll::Unrolled::new(&problem.bodies, &problem.contacts);
        let (gp, gq) = (operator.delassus(&p), operator.delassus(&q));
        let dot = |a: &[[f64; 2]], b: &[[f64; 2]]| a.iter().zip(b).map(|(x, y)| x[0] * y[0] + x[1] * y[1]).sum::<f64>();
        assert!((dot(&p, &gq) - dot(&q, &gp)).abs() < 1e-12);
        assert!(dot(&p, &gp) > 0.0, "positive definite on moving bodies");
    }
}
