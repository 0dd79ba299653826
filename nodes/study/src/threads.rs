//! The thread study (`dc study threads`): what the colour order's threads buy, on the same
//! states. Each seed's trajectory (its `--solver`) is run and its step problems captured on the
//! sampled steps; each captured problem is then solved from builtin's warm start by every
//! setting on every thread count, `repeats` times (the median kept), and the answers of one
//! setting compared across thread counts bit for bit (a difference is an error, not a figure).

use sim::problem::{bodies_of, builtin_warm_start, rows_of, Problem};
use sim::solver::{ContactSolver, Impulse, SolveReport, SolverBody, SweepThreads, ThreadsError};
use sim::{ModelKind, SceneConfig, SimError, SolverSetting, World, WorldParams};
use std::time::Instant;

/// What the study runs.
#[derive(Debug, Clone)]
pub struct ThreadsSpec {
    pub scene: SceneConfig,
    pub params: WorldParams,
    pub steps: u32,
    pub settings: Vec<SolverSetting>,
    /// Thread counts, the first the reference of each setting's speed-up.
    pub counts: Vec<usize>,
    /// Compared steps: every `every`-th from `from`.
    pub from: u32,
    pub every: u32,
    pub repeats: u32,
}

/// Why the study stopped.
#[derive(Debug, thiserror::Error)]
pub enum ThreadsStudyError {
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(transparent)]
    Threads(#[from] ThreadsError),
    #[error("{setting} on {threads} threads gave another answer than on {first} (seed {seed}, step {step}): the colour order must not depend on the thread count")]
    Differs { setting: String, threads: usize, first: usize, seed: u64, step: u32 },
}

/// One setting on one thread count, summed over the compared problems.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ThreadsRow {
    pub setting: String,
    pub threads: usize,
    pub problems: usize,
    pub rows: usize,
    pub sweeps: u64,
    pub capped: usize,
    /// The sum over problems of each problem's median solve time, seconds.
    pub seconds: f64,
}

type Answer = (SolveReport, Vec<Impulse>, Vec<SolverBody>);

/// Runs the study over `seeds`; `progress` is told after each seed.
pub fn run(
    spec: &ThreadsSpec,
    seeds: &[u64],
    mut progress: impl FnMut(),
) -> Result<Vec<ThreadsRow>, ThreadsStudyError> {
    let pools: Vec<SweepThreads> = spec.counts.iter().map(|&c| SweepThreads::new(c)).collect::<Result<_, _>>()?;
    let mut table: Vec<ThreadsRow> = spec
        .settings
        .iter()
        .flat_map(|s| {
            spec.counts.iter().map(move |&c| ThreadsRow { setting: s.to_string(), threads: c, ..Default::default() })
        })
        .collect();
    for &seed in seeds {
        for problem in captured(spec, seed)? {
            let rows = rows_of(&problem.contacts, spec.params.solve.friction);
            let start = builtin_warm_start(&problem.contacts);
            for (s, setting) in spec.settings.iter().enumerate() {
                let params = spec.params.solve.with_setting(*setting);
                let mut first: Option<Answer> = None;
                for (c, pool) in pools.iter().enumerate() {
                    let mut times = Vec::with_capacity(spec.repeats as usize);
                    let mut answer = None;
                    // One solver per count, as a simulation keeps one: its buffers warm.
                    let mut solver = ContactSolver::with_threads(pool.clone());
                    for _ in 0..spec.repeats {
                        let mut bodies = bodies_of(&problem.bodies);
                        let t = Instant::now();
                        let report = solver.solve(&rows, &mut bodies, &start, &params);
                        times.push(t.elapsed().as_secs_f64());
                        answer = Some((report, solver.impulses().to_vec(), bodies));
                    }
                    let answer = answer.expect("at least one repeat");
                    match &first {
                        None => first = Some(answer.clone()),
                        Some(reference) if *reference != answer => {
                            return Err(ThreadsStudyError::Differs {
                                setting: setting.to_string(),
                                threads: pool.threads(),
                                first: pools[0].threads(),
                                seed,
                                step: problem.header.step.step,
                            })
                        }
                        Some(_) => {}
                    }
                    times.sort_by(f64::total_cmp);
                    let row = &mut table[s * pools.len() + c];
                    row.problems += 1;
                    row.rows += rows.len();
                    row.sweeps += answer.0.sweeps as u64;
                    row.capped += (!answer.0.converged) as usize;
                    row.seconds += times[times.len() / 2];
                }
            }
        }
        progress();
    }
    Ok(table)
}

/// Seed `seed`'s problems on the compared steps of its trajectory (with contacts).
fn captured(spec: &ThreadsSpec, seed: u64) -> Result<Vec<Problem>, SimError> {
    let mut world = World::new(&SceneConfig { seed, ..spec.scene.clone() }, spec.params)?;
    let mut warm = ModelKind::Builtin.starter(0)?;
    warm.begin_simulation(0, seed);
    world.capture_problems(None);
    let mut problems = Vec::new();
    for step in 0..spec.steps {
        world.step(&mut warm);
        let compared = step >= spec.from && (step - spec.from).is_multiple_of(spec.every.max(1));
        if let Some(p) = world.problem().filter(|p| compared && !p.contacts.is_empty()) {
            problems.push(p.clone());
        }
    }
    Ok(problems)
}

/// The table in markdown: per setting and thread count, the median time of a solve summed over
/// the problems, its speed-up over the setting's first count, and its time against the first
/// row (the first setting on the first count).
pub fn markdown(table: &[ThreadsRow]) -> String {
    let mut out = String::from(
        "| solver | threads | problems | rows / problem | sweeps | capped | solve time (s) | speed-up over its first count | vs first row |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let reference = table.first().map(|r| r.seconds).unwrap_or(0.0);
    for row in table {
        let own = table.iter().find(|r| r.setting == row.setting).map(|r| r.seconds).unwrap_or(0.0);
        let ratio = |a: f64, b: f64| if b > 0.0 { format!("{:.2}x", a / b) } else { "-".into() };
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {:.3} | {} | {} |\n",
            row.setting,
            row.threads,
            row.problems,
            row.rows / row.problems.max(1),
            row.sweeps,
            row.capped,
            row.seconds,
            ratio(own, row.seconds),
            ratio(row.seconds, reference),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::SolveParams;

    #[test]
    fn every_setting_is_timed_on_every_count_with_the_same_answer() {
        let spec = ThreadsSpec {
            scene: SceneConfig { n: 60, ..SceneConfig::default() },
            params: WorldParams {
                solve: SolveParams { stop: sim::StopRule::Natural, ..SolveParams::default() },
                ..WorldParams::default()
            },
            steps: 80,
            settings: vec!["nncg:1.2/colour".parse().unwrap(), "pgs/down".parse().unwrap()],
            counts: vec![1, 2],
            from: 60,
            every: 10,
            repeats: 2,
        };
        let mut seeds_done = 0;
        let table = run(&spec, &[2000], || seeds_done += 1).unwrap();
        assert_eq!(seeds_done, 1);
        assert_eq!(table.len(), 4);
        for pair in table.chunks(2) {
            assert_eq!(pair[0].sweeps, pair[1].sweeps, "{pair:?}");
            assert!(pair[0].problems == 2 && pair[0].sweeps > 0 && pair[0].seconds > 0.0, "{pair:?}");
        }
        let md = markdown(&table);
        assert!(md.contains("| nncg:1.2/colour | 2 |") && md.contains("1.00x"), "{md}");
    }
}
