//! The real-time regime (`dc study budget`): every step solved with a fixed sweep budget,
//! as real-time engines run (Box2D 2.x 8 velocity iterations, rapier 4), stopping earlier only when
//! the natural residual is already below the tolerance. There a warm start decides how *accurate*
//! a step is, so each model is judged by its accuracy after the budget K, placed on builtin's
//! curve of accuracy against budget ("at 8 sweeps as accurate as builtin at N"), in sweeps and in
//! the time on the simulator's critical path (warm start + solve).
//!
//! Accuracy per step: the natural residual after the budget (max and RMS over the rows, impulse
//! units: solver-independent), the overlap the position pass leaves (max and mean over contacts),
//! the pile's kinetic energy, and the pile's centre-of-mass height and spread against a reference
//! run of the same seed solved to a tight tolerance — per phase, as statistics: trajectories
//! diverge, so bodies are never compared one by one. Every run drives its own trajectory (whole
//! runs): at a budget a step's inaccuracy is carried into the next step's warm start, which is
//! part of what a warm start is judged on here.

use crate::compare::phase;
use msgs::curve::figure as num;
pub use msgs::curve::{along, time_ratio, time_ratio_cell, worth, TimeRatio, Worth};
pub use msgs::ErrorSplit;
use msgs::{Accuracy, StepStats};
use sim::error::SimError;
use sim::scene::SceneConfig;
use sim::solver::{SolveParams, SolverSetting, StopRule};
use sim::warm::{ModelFiles, ModelKind, ModelSpec, Served, WarmStarter};
use sim::world::{World, WorldParams};

/// The first steps of the phases after the first (the report's phases: steps 0-99 falling,
/// 100-149 piling up, 150-end settled).
pub const PHASE_STARTS: [u32; 2] = crate::compare::PHASE_STARTS;

/// How far builtin's curve reaches past the largest judged budget: K, 2K, 4K, 8K, 16K.
pub const CURVE_REACH: u32 = 16;

/// The sweep cap of the reference run (it stops at its tolerance long before).
pub const REFERENCE_MAX_SWEEPS: u32 = 10_000;

/// The study: scene, parameters, budgets and models.
#[derive(Debug, Clone)]
pub struct BudgetSpec {
    pub scene: SceneConfig,
    /// The solver and the early-stopping tolerance (natural residual); the cap is each run's budget.
    pub params: WorldParams,
    pub steps: u32,
    /// The budgets each model is judged at (K).
    pub budgets: Vec<u32>,
    /// The models judged at every budget (builtin is always run: it is the curve).
    pub models: Vec<ModelSpec>,
    pub files: ModelFiles,
    /// The reference run's tolerance (natural residual), e.g. 1e-6.
    pub reference_tolerance: f32,
    /// Also split each judged run's warm-start error into its smooth and rough parts
    /// ([`ErrorSplit`]): one more pass per run, with the step's exact solution.
    pub error_split: bool,
    /// How many times each seed's runs (all but the reference) are timed, interleaved: every
    /// step keeps the median of its repeats' warm-start and solve times. The runs are
    /// deterministic, so the repeats take the same steps; only their timings differ.
    pub timing_repeats: u32,
    /// A second curve: builtin's warm start with this solver (the best classical iteration,
    /// say NNCG), so that every model is also placed against it at equal accuracy.
    pub against: Option<SolverSetting>,
}

impl BudgetSpec {
    /// The budgets of builtin's curve: powers of two from 1 to [`CURVE_REACH`] times the largest
    /// judged budget, and every judged budget times 1, 2, 4, 8, 16.
    pub fn curve_budgets(&self) -> Vec<u32> {
        let top = self.budgets.iter().copied().max().unwrap_or(1).saturating_mul(CURVE_REACH);
        let mut out: Vec<u32> =
            std::iter::successors(Some(1u32), |b| b.checked_mul(2)).take_while(|&b| b <= top).collect();
        for &k in &self.budgets {
            out.extend((0..5).map(|i| k.saturating_mul(1 << i)));
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The solve of a run at budget `k`.
    pub fn at_budget(&self, k: u32) -> SolveParams {
        SolveParams { max_sweeps: k, stop: StopRule::Natural, ..self.params.solve }
    }

    /// The reference run's solve: the recommended solver (whatever the study's: at this tolerance
    /// any solver gives the same trajectory statistics, and PGS would take ~3x the sweeps).
    pub fn reference(&self) -> SolveParams {
        SolveParams {
            tolerance: self.reference_tolerance,
            max_sweeps: REFERENCE_MAX_SWEEPS,
            stop: StopRule::Natural,
            time_budget_us: None,
            ..self.params.solve
        }
        .with_setting(sim::SolverSetting::RECOMMENDED)
    }

    /// Checks the budgets and the models (a learned model's file) before anything runs.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |value: String, why: &str| SimError::InvalidParameter { name: "budget", value, why: why.to_string() };
        if self.budgets.is_empty() {
            return Err(bad(String::new(), "at least one budget"));
        }
        if let Some(&k) = self.budgets.iter().find(|&&k| k == 0 || k > MAX_BUDGET) {
            return Err(bad(k.to_string(), &format!("a budget is from 1 to {MAX_BUDGET} sweeps")));
        }
        if let Some((i, k)) = self.budgets.iter().enumerate().find(|(i, k)| self.budgets[..*i].contains(k)) {
            return Err(bad(k.to_string(), &format!("asked for twice (budget {} of the list)", i + 1)));
        }
        if !(self.reference_tolerance.is_finite() && self.reference_tolerance > 0.0) {
            return Err(SimError::InvalidParameter {
                name: "reference-tolerance",
                value: self.reference_tolerance.to_string(),
                why: "must be > 0".into(),
            });
        }
        for (i, m) in self.models.iter().enumerate() {
            if self.models[..i].iter().any(|earlier| earlier.name() == m.name()) {
                // Its runs would be one row of the report.
                return Err(SimError::InvalidParameter {
                    name: "models",
                    value: m.name(),
                    why: format!("asked for twice (model {} of the list)", i + 1),
                });
            }
            if m.served_on().is_some() {
                return Err(SimError::InvalidParameter {
                    name: "models",
                    value: m.name(),
                    why: "is served by another node; the study runs in one process (use `dc eval --budget`)".into(),
                });
            }
            m.build_with(0, Served::default(), &self.files)?;
        }
        WorldParams { solve: self.at_budget(1), ..self.params }.validate()
    }
}

/// The largest budget (the largest judged budget's curve reaches 16 times as far).
pub use sim::cli::MAX_BUDGET;

/// One run of the study (a model at a budget, builtin on the curve, or the reference) over every seed.
#[derive(Debug, Clone, PartialEq)]
pub struct BudgetRun {
    /// `builtin@8`, `gnn@8`, `reference`.
    pub label: String,
    pub model: String,
    /// The budget; 0 for the reference run.
    pub budget: u32,
    /// Every step's statistics, seed by seed (`simulation` is the seed).
    pub steps: Vec<StepStats>,
    /// The warm-start error split into smooth and rough parts (`n == 0`: not measured).
    pub split: ErrorSplit,
    /// `split`'s terms, seed by seed (empty: not measured): what a merge of shards sums in the
    /// same order.
    pub seed_splits: Vec<ErrorSplit>,
}

/// [`run_seed`] again with every warm start split by the world's instrument
/// ([`World::error_split`]): the run's [`ErrorSplit`] on this seed (the same trajectory:
/// measuring changes no warm start).
pub fn split_seed(spec: &BudgetSpec, seed: u64, model: &ModelSpec, solve: SolveParams) -> Result<ErrorSplit, SimError> {
    let mut total = ErrorSplit::default();
    drive(spec, seed, model.build_with(seed, Served::default(), &spec.files)?, solve, Some(&mut total))?;
    Ok(total)
}

/// Runs `model` with `solve` on `seed`: every step's statistics.
pub fn run_seed(
    spec: &BudgetSpec,
    seed: u64,
    model: &ModelSpec,
    solve: SolveParams,
) -> Result<Vec<StepStats>, SimError> {
    drive(spec, seed, model.build_with(seed, Served::default(), &spec.files)?, solve, None)
}

/// Runs the seed's world with `model` (builtin its fallback) and `solve`: every step's
/// statistics. With `split` the world also splits each step's warm-start error, summed into it.
fn drive(
    spec: &BudgetSpec,
    seed: u64,
    model: Box<dyn sim::warm::WarmStartModel>,
    solve: SolveParams,
    mut split: Option<&mut ErrorSplit>,
) -> Result<Vec<StepStats>, SimError> {
    let params = WorldParams { solve, ..spec.params };
    let mut world = World::new(&SceneConfig { seed, ..spec.scene.clone() }, params)?;
    // Simulation ids are u32 (checked by the caller's seed list).
    world.set_ids(0, seed as u32);
    world.error_split(split.is_some());
    let mut warm = WarmStarter::new(model, ModelKind::Builtin.build(seed)?);
    warm.begin_simulation(seed as u32, seed);
    Ok((0..spec.steps)
        .map(|_| {
            let stats = world.step(&mut warm).clone();
            if let (Some(total), Some(s)) = (split.as_deref_mut(), world.last_split()) {
                total.add(s);
            }
            stats
        })
        .collect())
}

/// The whole study: per seed the reference, builtin at every budget of its curve, and every
/// model at every judged budget; `progress` after each seed.
pub fn study(spec: &BudgetSpec, seeds: &[u64], mut progress: impl FnMut(u64)) -> Result<Vec<BudgetRun>, SimError> {
    spec.validate()?;
    let builtin = ModelSpec::of(ModelKind::Builtin);
    let mut runs = vec![BudgetRun {
        label: "reference".into(),
        model: builtin.name(),
        budget: 0,
        steps: Vec::new(),
        split: ErrorSplit::default(),
        seed_splits: Vec::new(),
    }];
    // (model, budget, the solver when not the study's)
    let mut plan: Vec<(ModelSpec, u32, Option<SolverSetting>)> =
        spec.curve_budgets().into_iter().map(|k| (builtin, k, None)).collect();
    if let Some(other) = spec.against {
        plan.extend(spec.curve_budgets().into_iter().map(|k| (builtin, k, Some(other))));
    }
    for &k in &spec.budgets {
        plan.extend(spec.models.iter().filter(|m| m.kind != ModelKind::Builtin).map(|&m| (m, k, None)));
    }
    for (m, k, other) in &plan {
        let model = match other {
            Some(other) => against_model(*other),
            None => m.name(),
        };
        runs.push(BudgetRun {
            label: format!("{model}@{k}"),
            model,
            budget: *k,
            steps: Vec::new(),
            split: ErrorSplit::default(),
            seed_splits: Vec::new(),
        });
    }
    let solve_at = |k: u32, other: Option<SolverSetting>| match other {
        Some(other) => spec.at_budget(k).with_setting(other),
        None => spec.at_budget(k),
    };
    for &seed in seeds {
        runs[0].steps.extend(run_seed(spec, seed, &builtin, spec.reference())?);
        // Every run once, then every run again: a slow spell of the machine falls on all of them.
        let mut repeats: Vec<Vec<Vec<StepStats>>> = vec![Vec::new(); plan.len()];
        for _ in 0..spec.timing_repeats.max(1) {
            for (timed, (m, k, other)) in repeats.iter_mut().zip(&plan) {
                timed.push(run_seed(spec, seed, m, solve_at(*k, *other))?);
            }
        }
        for ((run, (m, k, other)), timed) in runs[1..].iter_mut().zip(&plan).zip(repeats) {
            run.steps.extend(median_timings(&run.label, timed)?);
            if spec.error_split && spec.budgets.contains(k) && other.is_none() {
                let s = split_seed(spec, seed, m, spec.at_budget(*k))?;
                run.split.add(&s);
                run.seed_splits.push(s);
            }
        }
        progress(seed);
    }
    Ok(runs)
}

/// The first repeat's steps, each with the median warm-start and solve time of all repeats;
/// repeats that took different steps (a model that is not deterministic) are an error.
pub fn median_timings(label: &str, mut repeats: Vec<Vec<StepStats>>) -> Result<Vec<StepStats>, SimError> {
    let Some(first) = repeats.first() else { return Ok(Vec::new()) };
    let same = |a: &StepStats, b: &StepStats| {
        (a.step, a.contacts, a.sweeps, a.natural_rms.to_bits())
            == (b.step, b.contacts, b.sweeps, b.natural_rms.to_bits())
    };
    if let Some(other) =
        repeats.iter().find(|r| r.len() != first.len() || r.iter().zip(first).any(|(a, b)| !same(a, b)))
    {
        let step = other.iter().zip(first).position(|(a, b)| !same(a, b)).unwrap_or(other.len().min(first.len()));
        return Err(SimError::BadModel(format!(
            "{label}: timing repeats took different steps (from step {step} on): the run is not deterministic"
        )));
    }
    let n = first.len();
    let median = |values: Vec<f32>| charts::stats::median(&values.iter().map(|&v| v as f64).collect::<Vec<_>>()) as f32;
    let (warm, solve): (Vec<f32>, Vec<f32>) = (0..n)
        .map(|i| {
            (
                median(repeats.iter().map(|r| r[i].warm_start_us).collect()),
                median(repeats.iter().map(|r| r[i].solve_us).collect()),
            )
        })
        .unzip();
    let mut steps = repeats.swap_remove(0);
    for ((s, w), v) in steps.iter_mut().zip(warm).zip(solve) {
        s.warm_start_us = w;
        s.solve_us = v;
    }
    Ok(steps)
}

/// The phases' labels: `0-99`, `100-149`, `150-end`.
pub fn phase_labels() -> Vec<String> {
    let starts: Vec<u32> = std::iter::once(0).chain(PHASE_STARTS).collect();
    starts
        .iter()
        .enumerate()
        .map(|(i, &s)| match starts.get(i + 1) {
            Some(&e) => format!("{s}-{}", e - 1),
            None => format!("{s}-end"),
        })
        .collect()
}

/// One phase of a run against the reference: the pile's kinetic energy, and its centre-of-mass
/// height and spread minus the reference's at the same step and seed (means over the phase's
/// steps and seeds).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseAccuracy {
    pub kinetic_energy: f64,
    pub height_offset: f64,
    pub spread_offset: f64,
}

/// A run's accuracy and cost, over all its steps.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    pub label: String,
    pub model: String,
    pub budget: u32,
    pub mean_sweeps: f64,
    /// The natural residual and penetration (means over the steps with contacts), the late
    /// phase's kinetic energy.
    pub accuracy: Accuracy,
    /// Mean critical path per step (warm start + solve), microseconds.
    pub critical_us: f64,
    /// Its median over the steps with contacts (steady against a busy machine's outliers).
    pub critical_median_us: f64,
    pub fallbacks: usize,
    /// Per phase ([`phase_labels`]).
    pub phases: Vec<PhaseAccuracy>,
    /// The warm-start error's smooth / rough split (`n == 0`: not measured).
    pub split: ErrorSplit,
}

impl RunSummary {
    /// `run` summarised, its pile compared with `reference`'s at the same (seed, step).
    pub fn of(run: &BudgetRun, reference: &BudgetRun) -> RunSummary {
        let at: std::collections::HashMap<(u32, u32), &StepStats> =
            reference.steps.iter().map(|s| ((s.simulation, s.step), s)).collect();
        let mut sums = vec![(PhaseAccuracy::default(), 0usize); PHASE_STARTS.len() + 1];
        for s in &run.steps {
            let Some(r) = at.get(&(s.simulation, s.step)) else { continue };
            let (p, n) = &mut sums[phase(s.step)];
            p.kinetic_energy += s.kinetic_energy as f64;
            p.height_offset += (s.pile_height - r.pile_height) as f64;
            p.spread_offset += (s.pile_spread - r.pile_spread) as f64;
            *n += 1;
        }
        let phases = sums
            .into_iter()
            .map(|(p, n)| {
                let n = n.max(1) as f64;
                PhaseAccuracy {
                    kinetic_energy: p.kinetic_energy / n,
                    height_offset: p.height_offset / n,
                    spread_offset: p.spread_offset / n,
                }
            })
            .collect();
        let steps = &run.steps;
        let all = steps.len().max(1) as f64;
        RunSummary {
            label: run.label.clone(),
            model: run.model.clone(),
            budget: run.budget,
            mean_sweeps: steps.iter().map(|s| s.sweeps as f64).sum::<f64>() / all,
            accuracy: Accuracy::of(steps.iter(), PHASE_STARTS[PHASE_STARTS.len() - 1]),
            critical_us: steps.iter().map(|s| (s.warm_start_us + s.solve_us) as f64).sum::<f64>() / all,
            critical_median_us: charts::stats::median(
                &steps
                    .iter()
                    .filter(|s| s.contacts > 0)
                    .map(|s| (s.warm_start_us + s.solve_us) as f64)
                    .collect::<Vec<_>>(),
            ),
            fallbacks: steps.iter().filter(|s| s.fallback).count(),
            phases,
            split: run.split,
        }
    }
}

/// The study's summaries: the reference first, builtin's curve, then the judged runs.
pub fn summaries(runs: &[BudgetRun]) -> Vec<RunSummary> {
    let Some(reference) = runs.first() else { return Vec::new() };
    runs.iter().map(|r| RunSummary::of(r, reference)).collect()
}

/// Builtin's curve of `f` against budget, from the summaries.
pub fn curve(summaries: &[RunSummary], f: impl Fn(&RunSummary) -> f64) -> Vec<(f64, f64)> {
    curve_of(summaries, "builtin", f)
}

/// The curve of `f` against budget of the runs of `model`.
fn curve_of(summaries: &[RunSummary], model: &str, f: impl Fn(&RunSummary) -> f64) -> Vec<(f64, f64)> {
    summaries.iter().filter(|s| s.model == model && s.budget > 0).map(|s| (s.budget as f64, f(s))).collect()
}

/// What names builtin's runs with another solver (`--against`): `builtin+nncg`.
const AGAINST: &str = "builtin+";

/// The model name of builtin's runs with the solver `other` (`--against`): `builtin+nncg`.
pub fn against_model(other: SolverSetting) -> String {
    format!("{AGAINST}{other}")
}

/// The study's tables as markdown: builtin's curve, each judged budget's models placed on it,
/// and the pile per phase against the reference.
pub fn markdown(summaries: &[RunSummary], budgets: &[u32]) -> String {
    let rms = curve(summaries, |s| s.accuracy.natural_rms);
    let time = curve(summaries, |s| s.critical_us);
    let median_time = curve(summaries, |s| s.critical_median_us);
    // The second curve (--against), if the study ran one.
    let against = summaries.iter().find(|s| s.model.starts_with(AGAINST)).map(|run| {
        let rms = curve_of(summaries, &run.model, |s| s.accuracy.natural_rms);
        let median_time = curve_of(summaries, &run.model, |s| s.critical_median_us);
        (run.model[AGAINST.len()..].to_string(), rms, median_time)
    });
    let mut out = String::from(
        "## Builtin's curve: accuracy after the budget\n\n\"critical path\": warm start + solve, the mean over the steps and the median over the steps with contacts.\n\n| budget | mean sweeps | RMS natural residual | max natural residual | penetration max (m) | penetration mean (m) | kinetic energy, 150-end (J) | critical path (us/step) | critical path, median (us) |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for s in summaries.iter().filter(|s| s.model == "builtin" && s.budget > 0) {
        out += &format!(
            "| {} | {:.2} | {} | {} | {} | {} | {} | {:.1} | {:.1} |\n",
            s.budget,
            s.mean_sweeps,
            num(s.accuracy.natural_rms),
            num(s.accuracy.natural_max),
            num(s.accuracy.penetration_max),
            num(s.accuracy.penetration_mean),
            num(s.accuracy.late_kinetic_energy),
            s.critical_us,
            s.critical_median_us
        );
    }
    if let Some(r) = summaries.first() {
        out += &format!(
            "| reference ({:.1} sweeps) | | {} | {} | {} | {} | {} | {:.1} | {:.1} |\n",
            r.mean_sweeps,
            num(r.accuracy.natural_rms),
            num(r.accuracy.natural_max),
            num(r.accuracy.penetration_max),
            num(r.accuracy.penetration_mean),
            num(r.accuracy.late_kinetic_energy),
            r.critical_us,
            r.critical_median_us
        );
    }
    let (against_head, against_note) = match &against {
        Some((name, _, _)) => (
            format!(" vs {name} at equal accuracy |"),
            format!(" \"vs {name}\": the same ratio against builtin's start solved by {name} (its own curve, run beside builtin's): whether the model also beats the better iteration."),
        ),
        None => (String::new(), String::new()),
    };
    for &k in budgets {
        out += &format!(
            "\n## At {k} sweeps, placed on builtin's curve\n\n\"time at equal accuracy\": what a user buys, the model's critical path (warm start, inference included, and solve; median over the steps with contacts) over builtin's at the budget where builtin is as accurate (\"< r\": builtin is never as accurate on its curve, r at its top; \"-\": less accurate than builtin at one sweep); \"worth\": the budget at which builtin's RMS natural residual equals the model's at {k} (log-log interpolation); \"builtin's time there\": builtin's critical path at that budget (mean, and median over the steps with contacts); \"blend F\": the fraction of builtin's error an oracle blend must remove to leave the same RMS natural residual at {k} (interpolated between the blends run).{against_note}\n\n| model | time at equal accuracy |{against_head} RMS natural residual | worth (sweeps) | critical path (us/step) | builtin's time there (us/step) | critical path, median (us) | builtin's median there (us) | blend F | penetration max (m) | penetration mean (m) | kinetic energy, 150-end (J) | fallbacks |\n|---|---:|{}---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            if against.is_some() { "---:|" } else { "" }
        );
        let blends: Vec<(f64, f64)> = summaries
            .iter()
            .filter(|s| s.budget == k)
            .filter_map(|s| match s.model.as_str() {
                "builtin" => Some((0.0, s.accuracy.natural_rms)),
                m => m.strip_prefix("blend:").and_then(|f| f.parse().ok()).map(|f| (f, s.accuracy.natural_rms)),
            })
            .collect();
        for s in summaries.iter().filter(|s| s.budget == k) {
            let w = worth(&rms, s.accuracy.natural_rms);
            let (there, median_there) = match w {
                Worth::Sweeps(n) => (format!("{:.1}", along(&time, n)), format!("{:.1}", along(&median_time, n))),
                _ => ("-".into(), "-".into()),
            };
            let buys = time_ratio_cell(time_ratio(&rms, &median_time, s.accuracy.natural_rms, s.critical_median_us));
            let buys_against = match &against {
                Some((_, rms, time)) => {
                    format!(
                        " {} |",
                        time_ratio_cell(time_ratio(rms, time, s.accuracy.natural_rms, s.critical_median_us))
                    )
                }
                None => String::new(),
            };
            out += &format!(
                "| {} | {buys} |{buys_against} {} | {w} | {:.1} | {there} | {:.1} | {median_there} | {} | {} | {} | {} | {} |\n",
                s.model,
                num(s.accuracy.natural_rms),
                s.critical_us,
                s.critical_median_us,
                blend_fraction(&blends, s.accuracy.natural_rms),
                num(s.accuracy.penetration_max),
                num(s.accuracy.penetration_mean),
                num(s.accuracy.late_kinetic_energy),
                s.fallbacks
            );
        }
    }
    for &k in budgets {
        let split: Vec<&RunSummary> = summaries.iter().filter(|s| s.budget == k && s.split.n > 0).collect();
        if split.is_empty() {
            continue;
        }
        out += &format!(
            "\n## At {k} sweeps: which part of builtin's error each model removes\n\nEach model's warm-start error against the step's exact solution and builtin's on the same steps (the model's own trajectory), split as the smooth-error / rough-error references split it: the part 4 passes of averaging over the contact graph keep (smooth, pile-wide) and the rest (rough, local); and what {k} sweeps from each start leave of it (the part slow for the solver; the rest they remove); RMS over the contacts, impulse units; and the RMS natural residual those sweeps leave from each start, mean over the steps (solver-independent, blind to which of a jammed pile's many solutions a start heads for: the same-states comparison at the budget).\n\n| model | smooth RMS | rough RMS | builtin's smooth RMS | builtin's rough RMS | smooth removed | rough removed | left after {k} sweeps | builtin's left | natural residual left | builtin's natural residual left |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
        );
        for s in split {
            let ((ms, mr), (bs, br), (fs, fr)) = (s.split.model_rms(), s.split.builtin_rms(), s.split.removed());
            let ((ml, bl), (mn, bn)) = (s.split.left_rms(), s.split.left_natural());
            out += &format!(
                "| {} | {} | {} | {} | {} | {:.0}% | {:.0}% | {} | {} | {} | {} |\n",
                s.model,
                num(ms),
                num(mr),
                num(bs),
                num(br),
                100.0 * fs,
                100.0 * fr,
                num(ml),
                num(bl),
                num(mn),
                num(bn)
            );
        }
    }
    let labels = phase_labels();
    out += "\n## The pile against the reference, per phase\n\nMeans over each phase's steps and the seeds: kinetic energy (J), and the centre-of-mass height and the spread about it minus the reference run's at the same step (m).\n\n| run |";
    for l in &labels {
        out += &format!(" KE {l} | height {l} | spread {l} |");
    }
    out += "\n|---|";
    out += &"---:|".repeat(3 * labels.len());
    out.push('\n');
    for s in summaries {
        out += &format!("| {} |", s.label);
        for p in &s.phases {
            out += &format!(" {} | {} | {} |", num(p.kinetic_energy), num(p.height_offset), num(p.spread_offset));
        }
        out.push('\n');
    }
    out
}

/// The blend F (`builtin + F (oracle - builtin)`) that leaves `value` on `blends`' (F, error)
/// points, linear between the two that bracket it: `0.31`, `< 0` (worse than builtin), `> 0.75`
/// (better than every blend run), `-` without a blend.
pub fn blend_fraction(blends: &[(f64, f64)], value: f64) -> String {
    let mut points = blends.to_vec();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    msgs::curve::blend_place(points.into_iter(), value).map_or_else(|| "-".into(), |p| p.label())
}

/// Every step of every run, one CSV line each.
pub fn csv(runs: &[BudgetRun]) -> String {
    let mut out = String::from(
        "run,model,budget,seed,step,contacts,sweeps,natural_max,natural_rms,penetration_max,penetration_mean,kinetic_energy,pile_height,pile_spread,warm_start_us,solve_us,fallback\n",
    );
    for r in runs {
        for s in &r.steps {
            out += &format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.2},{:.2},{}\n",
                r.label,
                r.model,
                r.budget,
                s.simulation,
                s.step,
                s.contacts,
                s.sweeps,
                s.natural_max,
                s.natural_rms,
                s.penetration_max,
                s.penetration_mean,
                s.kinetic_energy,
                s.pile_height,
                s.pile_spread,
                s.warm_start_us,
                s.solve_us,
                s.fallback as u8
            );
        }
    }
    out
}

/// Accuracy against time: builtin's curve as a line (RMS natural residual against its budget),
/// and every run as a labelled point at its critical-path time, as a PNG at `path`.
pub fn plot(path: &std::path::Path, summaries: &[RunSummary]) -> Result<(), charts::PlotError> {
    let line =
        [charts::Series { name: "builtin".into(), points: curve(summaries, |s| s.accuracy.natural_rms), band: None }];
    let points: Vec<charts::Series> = summaries
        .iter()
        .filter(|s| s.budget > 0)
        .map(|s| charts::Series {
            name: s.label.clone(),
            points: vec![(s.critical_us, s.accuracy.natural_rms)],
            band: None,
        })
        .collect();
    let by_budget = charts::Panel::new(
        charts::Axis::log("budget (sweeps per step)"),
        charts::Axis::log("mean RMS natural residual after the budget"),
        &line,
        charts::Mark::Lines,
    )
    .titled("builtin's accuracy against its budget");
    let by_time = charts::Panel::new(
        charts::Axis::log("critical path per step (warm start + solve, us)"),
        charts::Axis::log("mean RMS natural residual"),
        &points,
        charts::Mark::LabelledPoints,
    )
    .titled("every run: accuracy against time");
    charts::chart(path, "The real-time regime: accuracy after a fixed sweep budget", &[by_budget, by_time])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(solver: &str, budgets: Vec<u32>, steps: u32) -> BudgetSpec {
        let setting: sim::SolverSetting = solver.parse().unwrap();
        let mut params = WorldParams::recommended();
        params.solve = params.solve.with_setting(setting);
        BudgetSpec {
            scene: SceneConfig { n: 40, ..SceneConfig::default() },
            params,
            steps,
            budgets,
            models: vec![ModelSpec::of(ModelKind::None)],
            files: ModelFiles::default(),
            reference_tolerance: 1e-6,
            error_split: false,
            timing_repeats: 1,
            against: None,
        }
    }

    #[test]
    fn a_budget_of_k_runs_exactly_k_sweeps_unless_converged() {
        for solver in ["pgs", "nncg:1.2/down"] {
            let spec = spec(solver, vec![5], 150);
            let tolerance = spec.params.solve.tolerance;
            let steps = run_seed(&spec, 101, &ModelSpec::of(ModelKind::Builtin), spec.at_budget(5)).unwrap();
            let full = steps.iter().filter(|s| s.sweeps == 5).count();
            let early = steps.iter().filter(|s| s.sweeps < 5).count();
            assert_eq!(full + early, steps.len(), "{solver}: a step above its budget");
            // Early stops are exactly the steps already accurate to the tolerance.
            for s in &steps {
                assert!(s.sweeps == 5 || s.natural_max <= tolerance, "{solver}: {s:?}");
                assert!(s.natural_rms <= s.natural_max, "{solver}: {s:?}");
            }
            assert!(full > 20 && early > 0, "{solver}: {full} full budgets, {early} early stops");
            // The pile's accuracy figures are filled in.
            let late = &steps[120];
            assert!(late.contacts > 0 && late.pile_height > 0.0 && late.pile_spread > 0.0, "{late:?}");
        }
    }

    #[test]
    fn builtin_is_worth_its_own_budget_and_more_sweeps_are_more_accurate() {
        let spec = spec("pgs", vec![4], 60);
        let runs = study(&spec, &[101], |_| {}).unwrap();
        let summaries = summaries(&runs);
        assert_eq!(summaries[0].label, "reference");
        let rms = curve(&summaries, |s| s.accuracy.natural_rms);
        assert_eq!(rms.iter().map(|p| p.0).collect::<Vec<_>>(), [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0]);
        assert!(rms.windows(2).all(|w| w[1].1 < w[0].1), "{rms:?}");
        assert!(summaries[0].accuracy.natural_rms < rms.last().unwrap().1, "the reference is the most accurate");
        let at4 = summaries.iter().find(|s| s.label == "builtin@4").unwrap();
        assert_eq!(worth(&rms, at4.accuracy.natural_rms), Worth::Sweeps(4.0));
        assert!(summaries.iter().any(|s| s.label == "none@4"));
        let table = markdown(&summaries, &spec.budgets);
        assert!(table.contains("## At 4 sweeps") && table.contains("| none |"), "{table}");
        // The median critical path is one of the steps with contacts' (an odd count) or between two.
        let run = runs.iter().find(|r| r.label == "builtin@4").unwrap();
        let times: Vec<f64> =
            run.steps.iter().filter(|s| s.contacts > 0).map(|s| (s.warm_start_us + s.solve_us) as f64).collect();
        let (lo, hi) = times.iter().fold((f64::MAX, 0f64), |(lo, hi), t| (lo.min(*t), hi.max(*t)));
        assert!(
            !times.is_empty() && (lo..=hi).contains(&at4.critical_median_us),
            "{} not in {lo}..{hi}",
            at4.critical_median_us
        );
        let row = table.lines().find(|l| l.starts_with("| builtin | ")).unwrap();
        assert_eq!(row.split('|').count(), 15, "{row}");
        // Builtin at its own budget buys nothing: 1.00x builtin's time.
        assert!(row.starts_with("| builtin | 1.00x |"), "{row}");
        assert!(row.contains(&format!("| {:.1} |", at4.critical_median_us)), "{row}");
    }

    #[test]
    fn blend_fractions_interpolate_between_the_blends_run() {
        let blends = [(0.5, 0.05), (0.0, 0.1), (0.25, 0.08)];
        assert_eq!(blend_fraction(&blends, 0.09), "0.13");
        assert_eq!(blend_fraction(&blends, 0.065), "0.38");
        assert_eq!(blend_fraction(&blends, 0.2), "< 0");
        assert_eq!(blend_fraction(&blends, 0.01), "> 0.50");
        assert_eq!(blend_fraction(&blends[1..2], 0.1), "-");
    }

    #[test]
    fn timing_repeats_keep_each_steps_median_time_and_the_same_steps() {
        let step = |i: u32, warm: f32, solve: f32| StepStats {
            step: i,
            contacts: 3,
            sweeps: 8,
            natural_rms: 0.01 * i as f32,
            warm_start_us: warm,
            solve_us: solve,
            ..StepStats::default()
        };
        let repeats = vec![
            vec![step(0, 1.0, 10.0), step(1, 5.0, 30.0)],
            vec![step(0, 9.0, 12.0), step(1, 2.0, 20.0)],
            vec![step(0, 3.0, 11.0), step(1, 4.0, 90.0)],
        ];
        let merged = median_timings("gnn@8", repeats.clone()).unwrap();
        assert_eq!(
            merged.iter().map(|s| (s.warm_start_us, s.solve_us)).collect::<Vec<_>>(),
            [(3.0, 11.0), (4.0, 30.0)]
        );
        assert_eq!(merged[1].natural_rms, repeats[0][1].natural_rms);
        // A repeat that took another step is refused, naming the run and the step.
        let mut diverged = repeats;
        diverged[2][1].sweeps = 7;
        let err = median_timings("gnn@8", diverged).unwrap_err().to_string();
        assert!(err.contains("gnn@8") && err.contains("step 1"), "{err}");
        // Through the study: repeated timing changes no accuracy figure.
        let once = spec("pgs", vec![4], 40);
        let thrice = BudgetSpec { timing_repeats: 3, ..once.clone() };
        let (a, b) = (study(&once, &[7], |_| {}).unwrap(), study(&thrice, &[7], |_| {}).unwrap());
        for (a, b) in summaries(&a).iter().zip(&summaries(&b)) {
            assert_eq!(
                (&a.label, a.accuracy.natural_rms, a.mean_sweeps),
                (&b.label, b.accuracy.natural_rms, b.mean_sweeps)
            );
        }
    }

    #[test]
    fn a_second_curve_places_every_model_against_the_better_iteration_too() {
        let mut spec = spec("pgs", vec![4], 150);
        spec.against = Some("nncg:1.2/down".parse().unwrap());
        let runs = study(&spec, &[7], |_| {}).unwrap();
        let summaries = summaries(&runs);
        let of = |label: &str| summaries.iter().find(|s| s.label == label).unwrap_or_else(|| panic!("{label}"));
        // The second curve is builtin's start solved by NNCG: the same budgets, its own accuracy.
        let (pgs, nncg) = (of("builtin@4"), of("builtin+nncg:1.2/down@4"));
        assert_ne!(pgs.accuracy.natural_rms, nncg.accuracy.natural_rms);
        assert_eq!(
            summaries.iter().filter(|s| s.model == "builtin+nncg:1.2/down").count(),
            summaries.iter().filter(|s| s.model == "builtin" && s.budget > 0).count()
        );
        // PGS's own curve is not mixed with it.
        assert_eq!(curve(&summaries, |s| s.accuracy.natural_rms).len(), spec.curve_budgets().len());
        let table = markdown(&summaries, &spec.budgets);
        assert!(table.contains("| vs nncg:1.2/down at equal accuracy |"), "{table}");
        // Builtin's own row at 4 is 1.00x against its own curve.
        let row = table.lines().find(|l| l.starts_with("| builtin | ")).unwrap();
        assert!(row.starts_with("| builtin | 1.00x |"), "{row}");
    }

    #[test]
    fn the_curve_reaches_sixteen_times_each_budget() {
        let spec = BudgetSpec {
            scene: SceneConfig::default(),
            params: WorldParams::recommended(),
            steps: 1,
            budgets: vec![8, 6],
            models: vec![],
            files: ModelFiles::default(),
            reference_tolerance: 1e-6,
            error_split: false,
            timing_repeats: 1,
            against: None,
        };
        assert_eq!(spec.curve_budgets(), vec![1, 2, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128]);
        assert_eq!(phase_labels(), ["0-99", "100-149", "150-end"]);
    }

    /// The split is linear in the error: a blend that removes half of builtin's error (against
    /// the same exact solution the split uses) removes half of its smooth and half of its rough
    /// part; builtin removes none of either, and its split is builtin's own.
    #[test]
    fn a_blend_removes_its_fraction_of_both_parts_and_builtin_none() {
        let mut spec = spec("pgs", vec![4], 60);
        spec.models = vec!["blend:0.5".parse().unwrap()];
        spec.error_split = true;
        let runs = study(&spec, &[101], |_| {}).unwrap();
        let summaries = summaries(&runs);
        let of = |label: &str| summaries.iter().find(|s| s.label == label).unwrap().split;
        let (blend, builtin) = (of("blend:0.5@4"), of("builtin@4"));
        assert!(blend.n > 150 && builtin.n > 150, "{blend:?} {builtin:?}");
        let (smooth, rough) = blend.removed();
        assert!((smooth - 0.5).abs() < 1e-3 && (rough - 0.5).abs() < 1e-3, "{blend:?}");
        assert_eq!(builtin.removed(), (0.0, 0.0));
        assert_eq!(builtin.model_rms(), builtin.builtin_rms());
        // The budget's sweeps from builtin's own start are builtin's left error, and they leave
        // less than the start had; from half the error, less than from all of it.
        assert_eq!(builtin.left_rms().0, builtin.left_rms().1);
        assert!(builtin.left_rms().1 < builtin.builtin_rms().0.hypot(builtin.builtin_rms().1), "{builtin:?}");
        assert!(blend.left_rms().0 < blend.left_rms().1, "{blend:?}");
        // And so does the natural residual they leave: builtin's own start leaves builtin's.
        assert_eq!(builtin.left_natural().0, builtin.left_natural().1);
        assert!(blend.left_natural().0 < blend.left_natural().1, "{blend:?}");
        // Only the judged budgets are split; the table says so.
        assert_eq!(of("builtin@8").n, 0);
        let table = markdown(&summaries, &spec.budgets);
        assert!(table.contains("which part of builtin's error") && table.contains("| blend:0.5 |"), "{table}");
    }
}
