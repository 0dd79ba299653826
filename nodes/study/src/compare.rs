//! Solvers side by side (`dc study solvers`): every setting of a menu solves the same
//! states from the same warm start (builtin's) to the same stopping rule, the trajectory driven by
//! the menu's first setting; the hindsight ceiling (each step's cheapest setting); a learned
//! per-step choice ([`SolverChooser`]) trained on other seeds and judged on these states; and
//! optionally whole runs, each setting (and the chooser) driving its own trajectory.

use sim::error::SimError;
use sim::scene::SceneConfig;
use sim::solver::SolverSetting;
use sim::warm::ModelKind;
use sim::world::{MenuSolve, World, WorldParams};
use std::time::Instant;

/// What the chooser reads: the state a step starts from, i.e. the previous step's outputs, so
/// that it is known before the step (and the same whichever solver produced it, up to the
/// solution's accuracy).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepFeatures(pub [f64; FEATURES]);

/// How many features a [`StepFeatures`] has.
pub const FEATURES: usize = 8;

/// The features' names, in order (the CSV's columns).
pub const FEATURE_NAMES: [&str; FEATURES] =
    ["ln_contacts", "new_fraction", "pile_height", "mean_load", "max_load", "time", "ln_kinetic_energy", "max_speed"];

impl StepFeatures {
    /// The features of the step `world` is about to take (from its last step's outputs).
    pub fn of(world: &World) -> StepFeatures {
        let stats = world.stats();
        let contacts = world.rows().len();
        let (mut low, mut high) = (f32::INFINITY, f32::NEG_INFINITY);
        for r in world.rows() {
            low = low.min(r.height);
            high = high.max(r.height);
        }
        let (mut sum, mut max) = (0.0f64, 0.0f32);
        for l in world.impulses() {
            sum += l.normal as f64;
            max = max.max(l.normal);
        }
        let n = contacts.max(1) as f64;
        StepFeatures([
            (1.0 + contacts as f64).ln(),
            if contacts == 0 { 0.0 } else { 1.0 - stats.persisting_contacts as f64 / n },
            if contacts == 0 { 0.0 } else { (high - low) as f64 },
            sum / n,
            max as f64,
            world.steps_taken() as f64 * world.params().dt as f64,
            (1e-6 + stats.kinetic_energy as f64).ln(),
            stats.max_speed as f64,
        ])
    }
}

/// One step on the same states: its features and every setting's solve.
#[derive(Debug, Clone, PartialEq)]
pub struct ComparedStep {
    pub seed: u64,
    pub step: u32,
    pub features: StepFeatures,
    /// What extracting the features took, microseconds (a chooser pays it every step).
    pub features_us: f32,
    /// The step's contacts, and the trajectory's kinetic energy after it (J: whether the pile
    /// has settled).
    pub contacts: u32,
    pub kinetic_energy: f32,
    pub solves: Vec<MenuSolve>,
}

/// Which steps the menu solves: every `every`-th from `from` (the trajectory runs every step).
/// A deep pile's slowest solvers are compared on a sample of its steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sampling {
    pub from: u32,
    pub every: u32,
}

impl Sampling {
    pub const EVERY_STEP: Sampling = Sampling { from: 0, every: 1 };

    pub fn includes(&self, step: u32) -> bool {
        step >= self.from && (step - self.from).is_multiple_of(self.every.max(1))
    }

    pub fn is_every_step(&self) -> bool {
        *self == Sampling::EVERY_STEP
    }
}

/// The comparison's scene, parameters and seeds.
#[derive(Debug, Clone)]
pub struct CompareSpec {
    pub scene: SceneConfig,
    /// The stopping rule, tolerance, cap and compliance every setting shares.
    pub params: WorldParams,
    pub steps: u32,
    /// The menu; the first drives the trajectory and is what the others are compared with.
    pub menu: Vec<SolverSetting>,
    /// The steps the menu solves.
    pub sampling: Sampling,
}

impl CompareSpec {
    fn world(&self, seed: u64, setting: SolverSetting) -> Result<World, SimError> {
        let params = WorldParams { solve: self.params.solve.with_setting(setting), ..self.params };
        World::new(&SceneConfig { seed, ..self.scene.clone() }, params)
    }
}

/// Every sampled step of `seeds` solved by every setting of the menu from builtin's warm start,
/// the trajectory driven by the first with builtin's warm start; `progress` after each simulation.
pub fn same_states(
    spec: &CompareSpec,
    seeds: &[u64],
    mut progress: impl FnMut(u64),
) -> Result<Vec<ComparedStep>, SimError> {
    let menu: Vec<_> = spec.menu.iter().map(|&s| spec.params.solve.with_setting(s)).collect();
    let mut out = Vec::with_capacity(seeds.len() * spec.steps as usize);
    for &seed in seeds {
        let mut world = spec.world(seed, spec.menu[0])?;
        world.solver_menu(menu.clone());
        let mut warm = ModelKind::Builtin.starter(seed)?;
        warm.begin_simulation(seed as u32, seed);
        let mut menu_on = true;
        for step in 0..spec.steps {
            // The menu is handed over (or taken away) only where the sampling turns on or off.
            let sampled = spec.sampling.includes(step);
            if sampled != menu_on {
                world.solver_menu(if sampled { menu.clone() } else { Vec::new() });
                menu_on = sampled;
            }
            if !sampled {
                world.step(&mut warm);
                continue;
            }
            let started = Instant::now();
            let features = StepFeatures::of(&world);
            let features_us = started.elapsed().as_secs_f32() * 1e6;
            let stats = world.step(&mut warm);
            let (contacts, kinetic_energy) = (stats.contacts, stats.kinetic_energy);
            out.push(ComparedStep {
                seed,
                step,
                features,
                features_us,
                contacts,
                kinetic_energy,
                solves: world.menu_solves().to_vec(),
            });
        }
        progress(seed);
    }
    Ok(out)
}

/// A whole run's totals: sweeps, solve time, capped steps, per seed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunTotals {
    pub sweeps: u64,
    /// Solve wall time, microseconds (a chooser's inference included).
    pub solve_us: f64,
    pub capped: u32,
    /// Sweeps per seed, in the seeds' order.
    pub per_seed: Vec<u64>,
}

/// Which solver a whole run uses at each step.
#[derive(Debug, Clone, Copy)]
pub enum Choice<'a> {
    /// The same setting every step.
    Fixed(SolverSetting),
    /// The chooser's pick among its settings, from the features of the state each step starts
    /// from; the features and the pick count as solve time.
    Learned(&'a SolverChooser),
}

/// Runs every seed with `choice`, builtin's warm start; `progress` after each simulation.
pub fn whole_run(
    spec: &CompareSpec,
    seeds: &[u64],
    choice: Choice<'_>,
    mut progress: impl FnMut(u64),
) -> Result<RunTotals, SimError> {
    let mut totals = RunTotals::default();
    for &seed in seeds {
        let first = match choice {
            Choice::Fixed(setting) => setting,
            Choice::Learned(_) => spec.menu[0],
        };
        let mut world = spec.world(seed, first)?;
        let mut warm = ModelKind::Builtin.starter(seed)?;
        warm.begin_simulation(seed as u32, seed);
        let mut seed_sweeps = 0;
        for _ in 0..spec.steps {
            let mut choice_us = 0.0;
            if let Choice::Learned(chooser) = choice {
                let started = Instant::now();
                world.set_solver(chooser.settings[chooser.choose(&StepFeatures::of(&world))]);
                choice_us = started.elapsed().as_secs_f64() * 1e6;
            }
            let s = world.step(&mut warm);
            seed_sweeps += s.sweeps as u64;
            totals.solve_us += s.solve_us as f64 + choice_us;
            totals.capped += (!s.converged) as u32;
        }
        totals.sweeps += seed_sweeps;
        totals.per_seed.push(seed_sweeps);
        progress(seed);
    }
    Ok(totals)
}

/// The whole-run table as markdown, ratios against the first row.
pub fn whole_runs_markdown(runs: &[(String, RunTotals)]) -> String {
    let mut out = String::from(
        "| solver | sweeps | vs first | solve time (s) | vs first | capped steps | worst seed |\n|---|---:|---:|---:|---:|---:|---:|\n",
    );
    let Some((_, first)) = runs.first() else { return out };
    for (name, t) in runs {
        let worst =
            t.per_seed.iter().zip(&first.per_seed).map(|(a, b)| *a as f64 / (*b).max(1) as f64).fold(0.0, f64::max);
        out += &format!(
            "| {name} | {} | {:.3}x | {:.2} | {:.3}x | {} | {worst:.3}x |\n",
            t.sweeps,
            t.sweeps as f64 / first.sweeps.max(1) as f64,
            t.solve_us / 1e6,
            t.solve_us / first.solve_us.max(1e-9),
            t.capped
        );
    }
    out
}

/// A per-step choice among a menu of settings: one ridge regression per setting predicting the
/// log of its sweeps from the (standardised) features; the setting predicted cheapest is chosen.
/// Khodak et al.'s "learning to relax" in its simplest form.
#[derive(Debug, Clone, PartialEq)]
pub struct SolverChooser {
    pub settings: Vec<SolverSetting>,
    mean: [f64; FEATURES],
    scale: [f64; FEATURES],
    /// Per setting: the bias, then one weight per feature.
    weights: Vec<[f64; FEATURES + 1]>,
}

/// The ridge penalty of [`SolverChooser::fit`] on standardised features (per sample).
pub const RIDGE: f64 = 1e-3;

impl SolverChooser {
    /// Fits the chooser on `steps` (solved by every setting of `settings`, in that order).
    pub fn fit(settings: &[SolverSetting], steps: &[ComparedStep]) -> Result<SolverChooser, SimError> {
        let bad = |why: String| SimError::InvalidParameter { name: "chooser", value: String::new(), why };
        if steps.len() < 2 * (FEATURES + 1) {
            return Err(bad(format!("{} training steps; at least {} needed", steps.len(), 2 * (FEATURES + 1))));
        }
        let count = steps.len() as f64;
        let mut mean = [0.0; FEATURES];
        let mut scale = [0.0; FEATURES];
        for s in steps {
            for (m, x) in mean.iter_mut().zip(s.features.0) {
                *m += x / count;
            }
        }
        for s in steps {
            for ((v, x), m) in scale.iter_mut().zip(s.features.0).zip(mean) {
                *v += (x - m).powi(2) / count;
            }
        }
        // A constant feature gets scale 1 (it standardises to 0 and the ridge keeps it at 0).
        let scale = scale.map(|v| if v > 1e-12 { v.sqrt() } else { 1.0 });
        let mut chooser = SolverChooser { settings: settings.to_vec(), mean, scale, weights: Vec::new() };
        const K: usize = FEATURES + 1;
        let mut gram = [0.0f64; K * K];
        let rows: Vec<[f64; K]> = steps.iter().map(|s| chooser.design(&s.features)).collect();
        for x in &rows {
            for i in 0..K {
                for j in 0..K {
                    gram[i * K + j] += x[i] * x[j];
                }
            }
        }
        for i in 1..K {
            gram[i * K + i] += RIDGE * count;
        }
        for (k, setting) in settings.iter().enumerate() {
            let mut rhs = [0.0f64; K];
            for (x, s) in rows.iter().zip(steps) {
                let y = (1.0 + s.solves[k].sweeps as f64).ln();
                for i in 0..K {
                    rhs[i] += x[i] * y;
                }
            }
            let mut a = gram;
            let w = sim::warm::probes::coarse::solve_semidefinite(&mut a, &rhs, K)
                .ok_or_else(|| bad(format!("the regression of `{setting}` has no solution")))?;
            chooser.weights.push(std::array::from_fn(|i| w[i]));
        }
        Ok(chooser)
    }

    /// The bias and the standardised features.
    fn design(&self, f: &StepFeatures) -> [f64; FEATURES + 1] {
        std::array::from_fn(|i| if i == 0 { 1.0 } else { (f.0[i - 1] - self.mean[i - 1]) / self.scale[i - 1] })
    }

    /// The median time of one pick over `steps`' features, microseconds (the features'
    /// extraction is each step's own `features_us`).
    pub fn median_pick_us(&self, steps: &[ComparedStep]) -> f64 {
        let mut times: Vec<f64> = steps
            .iter()
            .map(|s| {
                let started = Instant::now();
                std::hint::black_box(self.choose(std::hint::black_box(&s.features)));
                started.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times.get(times.len() / 2).copied().unwrap_or(0.0)
    }

    /// How many of `steps` the chooser gives each of its settings.
    pub fn picks(&self, steps: &[ComparedStep]) -> Vec<u64> {
        let mut picks = vec![0u64; self.settings.len()];
        for s in steps {
            picks[self.choose(&s.features)] += 1;
        }
        picks
    }

    /// The index of the setting predicted cheapest for a step with features `f`.
    pub fn choose(&self, f: &StepFeatures) -> usize {
        let x = self.design(f);
        let predict = |w: &[f64; FEATURES + 1]| w.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>();
        let mut best = (0, f64::INFINITY);
        for (k, w) in self.weights.iter().enumerate() {
            let y = predict(w);
            if y < best.1 {
                best = (k, y);
            }
        }
        best.0
    }
}

/// One row of the side-by-side table: a setting (or the ceiling, or the chooser) on the same
/// states.
#[derive(Debug, Clone, PartialEq)]
pub struct SameStatesRow {
    pub name: String,
    pub sweeps: u64,
    pub solve_us: f64,
    pub capped: u32,
    /// Sweeps per phase (the phases' step ranges).
    pub per_phase: Vec<u64>,
    /// The largest ratio of a seed's sweeps to the first setting's on the same seed.
    pub worst_seed: f64,
    /// The accuracy reached: the steps' RMS natural residual (over rows), mean over the steps
    /// with contacts (what a time budget per step buys).
    pub natural_rms: f64,
}

/// The first steps of the phases after the first (the report's default phases: falling,
/// piling up, settled).
pub const PHASE_STARTS: [u32; 2] = [100, 150];

/// The phase (index into [`PHASE_STARTS`] plus one) of step `step`.
pub fn phase(step: u32) -> usize {
    PHASE_STARTS.iter().filter(|&&s| step >= s).count()
}

/// Sums the same-states cost of picking `pick(step)` at every step.
pub fn same_states_row(
    name: &str,
    steps: &[ComparedStep],
    mut pick: impl FnMut(&ComparedStep) -> (MenuSolve, f64),
) -> SameStatesRow {
    let mut row = SameStatesRow {
        name: name.to_string(),
        sweeps: 0,
        solve_us: 0.0,
        capped: 0,
        per_phase: vec![0; PHASE_STARTS.len() + 1],
        worst_seed: 0.0,
        natural_rms: 0.0,
    };
    let mut seeds: std::collections::BTreeMap<u64, (u64, u64)> = Default::default();
    let mut with_contacts = 0u64;
    for s in steps {
        let (solve, extra_us) = pick(s);
        if s.contacts > 0 {
            row.natural_rms += solve.natural_rms as f64;
            with_contacts += 1;
        }
        row.sweeps += solve.sweeps as u64;
        row.solve_us += solve.us as f64 + extra_us;
        row.capped += (!solve.converged) as u32;
        row.per_phase[phase(s.step)] += solve.sweeps as u64;
        let e = seeds.entry(s.seed).or_default();
        e.0 += solve.sweeps as u64;
        e.1 += s.solves[0].sweeps as u64;
    }
    row.natural_rms /= with_contacts.max(1) as f64;
    row.worst_seed = seeds.values().map(|&(own, first)| own as f64 / first.max(1) as f64).fold(0.0, f64::max);
    row
}

/// The same-states table: every setting, the hindsight ceiling by sweeps, and the chooser if
/// given, charged each step's feature extraction and its median pick time (`pick_us`).
pub fn same_states_table(
    menu: &[SolverSetting],
    steps: &[ComparedStep],
    chooser: Option<(&SolverChooser, f64)>,
) -> Vec<SameStatesRow> {
    let mut rows: Vec<SameStatesRow> =
        menu.iter().enumerate().map(|(k, s)| same_states_row(&s.to_string(), steps, |c| (c.solves[k], 0.0))).collect();
    rows.push(same_states_row("hindsight best (each step's fewest sweeps)", steps, |c| {
        (*c.solves.iter().min_by_key(|m| m.sweeps).expect("a menu"), 0.0)
    }));
    if let Some((chooser, pick_us)) = chooser {
        rows.push(same_states_row("learned choice", steps, |c| {
            (c.solves[chooser.choose(&c.features)], c.features_us as f64 + pick_us)
        }));
    }
    rows
}

/// The table as markdown, ratios against the first row.
pub fn markdown(rows: &[SameStatesRow]) -> String {
    let first = &rows[0];
    let mut out = String::from(
        "| solver | sweeps | vs first | solve time (s) | vs first | capped steps | RMS natural residual | steps 0-99 | 100-149 | 150- | worst seed |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let phases: Vec<String> = r
            .per_phase
            .iter()
            .zip(&first.per_phase)
            .map(|(own, base)| format!("{:.3}x", *own as f64 / (*base).max(1) as f64))
            .collect();
        out += &format!(
            "| {} | {} | {:.3}x | {:.2} | {:.3}x | {} | {:.2e} | {} | {:.3}x |\n",
            r.name,
            r.sweeps,
            r.sweeps as f64 / first.sweeps.max(1) as f64,
            r.solve_us / 1e6,
            r.solve_us / first.solve_us.max(1e-9),
            r.capped,
            r.natural_rms,
            phases.join(" | "),
            r.worst_seed,
        );
    }
    out
}

/// For the settings that factorise (the interior point, Newton): per step, iterations
/// (factorisations) and the symbolic analyses made (against the kept one reused), and where
/// the time goes: the analysis, the numeric factorisations with their solves (also per
/// factorisation: the cost of one iteration), and the rest (assembly, residuals, any finishing
/// sweeps). None when no setting factorised.
pub fn factorisation_markdown(menu: &[SolverSetting], steps: &[ComparedStep]) -> Option<String> {
    let mut out = String::from(
        "| solver | steps | factorisations / step | new analyses | analysis ms / step | ms / factorisation | rest ms / step | solve ms / step |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let mut any = false;
    for (k, setting) in menu.iter().enumerate() {
        let solves: Vec<&MenuSolve> = steps.iter().filter(|s| s.contacts > 0).map(|s| &s.solves[k]).collect();
        let factorisations: u64 = solves.iter().map(|m| m.factorisations as u64).sum();
        if factorisations == 0 {
            continue;
        }
        any = true;
        let n = solves.len().max(1) as f64;
        let analyses = solves.iter().filter(|m| m.symbolic_us > 0.0).count();
        let symbolic: f64 = solves.iter().map(|m| m.symbolic_us as f64).sum();
        let numeric: f64 = solves.iter().map(|m| m.numeric_us as f64).sum();
        let total: f64 = solves.iter().map(|m| m.us as f64).sum();
        out += &format!(
            "| {setting} | {} | {:.1} | {analyses} | {:.3} | {:.3} | {:.3} | {:.3} |\n",
            solves.len(),
            factorisations as f64 / n,
            symbolic / n / 1e3,
            numeric / factorisations as f64 / 1e3,
            (total - symbolic - numeric) / n / 1e3,
            total / n / 1e3,
        );
    }
    any.then_some(out)
}

/// For the settings with a coarse correction: per step, corrections kept and dropped, sweeps,
/// and the correction's share of the solve's time. None when no setting has one.
pub fn coarse_markdown(menu: &[SolverSetting], steps: &[ComparedStep]) -> Option<String> {
    let mut out = String::from(
        "| solver | steps | corrections kept / step | dropped / step | sweeps / step | correction ms / step | solve ms / step | correction's share |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let mut any = false;
    for (k, setting) in menu.iter().enumerate().filter(|(_, s)| s.coarse.is_some()) {
        any = true;
        let solves: Vec<&MenuSolve> = steps.iter().filter(|s| s.contacts > 0).map(|s| &s.solves[k]).collect();
        let n = solves.len().max(1) as f64;
        let sum = |f: fn(&MenuSolve) -> f64| solves.iter().map(|m| f(m)).sum::<f64>();
        let (kept, dropped) = (sum(|m| m.corrections as f64), sum(|m| m.corrections_dropped as f64));
        let (coarse, total) = (sum(|m| m.coarse_us as f64), sum(|m| m.us as f64));
        out += &format!(
            "| {setting} | {} | {:.2} | {:.2} | {:.1} | {:.3} | {:.3} | {:.0}% |\n",
            solves.len(),
            kept / n,
            dropped / n,
            sum(|m| m.sweeps as f64) / n,
            coarse / n / 1e3,
            total / n / 1e3,
            100.0 * coarse / total.max(f64::MIN_POSITIVE),
        );
    }
    any.then_some(out)
}

/// Whether the pile has settled by the end: the trajectory's mean and largest kinetic energy
/// (J) over the compared steps among each seed's last 100, in words.
pub fn settling(steps: &[ComparedStep], total_steps: u32) -> String {
    let late: Vec<f64> =
        steps.iter().filter(|s| s.step + 100 >= total_steps).map(|s| s.kinetic_energy as f64).collect();
    if late.is_empty() {
        return "no compared step among the last 100".to_string();
    }
    let mean = late.iter().sum::<f64>() / late.len() as f64;
    let max = late.iter().copied().fold(0.0, f64::max);
    format!(
        "kinetic energy over the last 100 steps ({} compared steps): mean {mean:.3} J, largest {max:.3} J",
        late.len()
    )
}

/// The per-step CSV: seed, step, the features, then sweeps and microseconds per setting.
pub fn csv(menu: &[SolverSetting], steps: &[ComparedStep]) -> String {
    let mut out = String::from("seed,step");
    for name in FEATURE_NAMES {
        out += &format!(",{name}");
    }
    for s in menu {
        out += &format!(",{s} sweeps,{s} us,{s} converged,{s} natural max,{s} natural rms");
    }
    out += ",kinetic_energy\n";
    for c in steps {
        out += &format!("{},{}", c.seed, c.step);
        for x in c.features.0 {
            out += &format!(",{x}");
        }
        for m in &c.solves {
            out += &format!(",{},{:.2},{},{:e},{:e}", m.sweeps, m.us, m.converged as u8, m.natural_max, m.natural_rms);
        }
        out += &format!(",{}\n", c.kinetic_energy);
    }
    out
}

/// Plots every setting's mean sweeps per step (over the seeds) against the step, the phases'
/// starts marked, as a PNG at `path`.
pub fn plot(path: &std::path::Path, menu: &[SolverSetting], steps: &[ComparedStep]) -> Result<(), charts::PlotError> {
    let last = steps.iter().map(|s| s.step).max().unwrap_or(0) as usize;
    let mut sums = vec![vec![0.0f64; last + 1]; menu.len()];
    let mut counts = vec![0u32; last + 1];
    for s in steps {
        counts[s.step as usize] += 1;
        for (k, m) in s.solves.iter().enumerate() {
            sums[k][s.step as usize] += m.sweeps as f64;
        }
    }
    let series: Vec<charts::Series> = menu
        .iter()
        .zip(&sums)
        .map(|(setting, sum)| charts::Series {
            name: setting.to_string(),
            points: sum
                .iter()
                .zip(&counts)
                .enumerate()
                .filter(|(_, (_, &n))| n > 0)
                .map(|(step, (total, &n))| (step as f64, total / n as f64))
                .collect(),
            band: None,
        })
        .collect();
    let panel = charts::Panel::new(
        charts::Axis::counts("step"),
        charts::Axis::log("mean sweeps per step (same states)"),
        &series,
        charts::Mark::Lines,
    )
    .guides(&PHASE_STARTS.map(f64::from), &[]);
    charts::chart(path, "Sweeps per step by solver, to the same stopping rule", &[panel])
}
