//! A study in shards (`dc study solvers|budget --shard I/N`) and their merge (`dc report merge`):
//! each shard keeps, beside its own report, what it computed for its seeds (`study.cbor`); the
//! merge joins the shards' results in seed order and writes the report the one-host study writes,
//! table for table.
//!
//! Everything a table is computed from is kept per seed and joined in seed order, so that the
//! merged sums are the one-host run's to the bit (a float sum regrouped by shard would not be).

use crate::budget::BudgetRun;
use crate::compare::{ComparedStep, RunTotals, StepFeatures};
use msgs::shard::format_seeds;
use msgs::ErrorSplit;
use serde::{Deserialize, Serialize};
use sim::world::MenuSolve;
use std::collections::BTreeSet;
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Its name in a shard's folder.
pub const FILE: &str = "study.cbor";
/// [`StudyData`]'s format; another is refused, not guessed at.
pub const FORMAT: u32 = 1;

/// What a shard of a study computed, for the merge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "study", rename_all = "lowercase")]
pub enum StudyData {
    Solvers {
        format: u32,
        steps: Vec<SolverStep>,
        /// Whole runs (`--whole-runs`), by name, in the report's order.
        whole: Vec<(String, WholeTotals)>,
    },
    Budget {
        format: u32,
        runs: Vec<BudgetRunData>,
    },
}

/// [`ComparedStep`] as kept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SolverStep {
    pub seed: u64,
    pub step: u32,
    pub features: Vec<f64>,
    pub features_us: f32,
    pub contacts: u32,
    pub kinetic_energy: f32,
    /// Per setting: sweeps, converged, us, natural max, natural RMS.
    pub solves: Vec<(u32, bool, f32, f32, f32)>,
    /// Per setting: factorisations, symbolic and numeric microseconds (empty in a study kept
    /// before they were).
    #[serde(default)]
    pub factor: Vec<(u32, f32, f32)>,
    /// Per setting: coarse corrections kept and dropped, and their microseconds (empty in a
    /// study kept before they were).
    #[serde(default)]
    pub coarse: Vec<(u32, u32, f32)>,
}

/// [`RunTotals`] as kept.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WholeTotals {
    pub sweeps: u64,
    pub solve_us: f64,
    pub capped: u32,
    pub per_seed: Vec<u64>,
}

/// [`BudgetRun`] as kept, with its error split per seed (summed by the merge in seed order).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BudgetRunData {
    pub label: String,
    pub model: String,
    pub budget: u32,
    pub steps: Vec<msgs::StepStats>,
    pub seed_splits: Vec<ErrorSplit>,
}

/// What cannot be read or joined, naming the file.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {why}")]
pub struct ShardDataError {
    pub path: String,
    pub why: String,
}

impl SolverStep {
    pub fn of(s: &ComparedStep) -> SolverStep {
        SolverStep {
            seed: s.seed,
            step: s.step,
            features: s.features.0.to_vec(),
            features_us: s.features_us,
            contacts: s.contacts,
            kinetic_energy: s.kinetic_energy,
            solves: s.solves.iter().map(|m| (m.sweeps, m.converged, m.us, m.natural_max, m.natural_rms)).collect(),
            factor: s.solves.iter().map(|m| (m.factorisations, m.symbolic_us, m.numeric_us)).collect(),
            coarse: s.solves.iter().map(|m| (m.corrections, m.corrections_dropped, m.coarse_us)).collect(),
        }
    }

    fn compared(&self) -> Option<ComparedStep> {
        Some(ComparedStep {
            seed: self.seed,
            step: self.step,
            features: StepFeatures(self.features.as_slice().try_into().ok()?),
            features_us: self.features_us,
            contacts: self.contacts,
            kinetic_energy: self.kinetic_energy,
            solves: self
                .solves
                .iter()
                .enumerate()
                .map(|(k, &(sweeps, converged, us, natural_max, natural_rms))| {
                    let (factorisations, symbolic_us, numeric_us) = self.factor.get(k).copied().unwrap_or_default();
                    let (corrections, corrections_dropped, coarse_us) = self.coarse.get(k).copied().unwrap_or_default();
                    MenuSolve {
                        sweeps,
                        converged,
                        us,
                        natural_max,
                        natural_rms,
                        factorisations,
                        symbolic_us,
                        numeric_us,
                        corrections,
                        corrections_dropped,
                        coarse_us,
                    }
                })
                .collect(),
        })
    }
}

impl WholeTotals {
    pub fn of(t: &RunTotals) -> WholeTotals {
        WholeTotals { sweeps: t.sweeps, solve_us: t.solve_us, capped: t.capped, per_seed: t.per_seed.clone() }
    }
}

impl BudgetRunData {
    pub fn of(r: &BudgetRun) -> BudgetRunData {
        BudgetRunData {
            label: r.label.clone(),
            model: r.model.clone(),
            budget: r.budget,
            steps: r.steps.clone(),
            seed_splits: r.seed_splits.clone(),
        }
    }
}

impl StudyData {
    /// Writes `dir/study.cbor` (never half a file under the name).
    pub fn write(&self, dir: &Path) -> Result<PathBuf, ShardDataError> {
        let path = dir.join(FILE);
        runtime::files::replace_cbor(&path, self)
            .map_err(|e| ShardDataError { path: path.display().to_string(), why: e.to_string() })?;
        Ok(path)
    }

    /// Reads `dir/study.cbor` (a regular file only; lengths inside are checked by the decoder
    /// against the bytes present).
    pub fn read(dir: &Path) -> Result<StudyData, ShardDataError> {
        let path = dir.join(FILE);
        let failed = |why: String| ShardDataError { path: path.display().to_string(), why };
        let file = runtime::files::open_regular(&path, "study results").map_err(|e| failed(e.to_string()))?;
        let data: StudyData = ciborium::from_reader(BufReader::new(file))
            .map_err(|e| failed(format!("not a study's results (corrupt or cut short?): {e}")))?;
        let format = match &data {
            StudyData::Solvers { format, .. } | StudyData::Budget { format, .. } => *format,
        };
        if format != FORMAT {
            return Err(failed(format!("format {format} (this build reads format {FORMAT})")));
        }
        Ok(data)
    }
}

/// One shard's data with where it came from and the seeds it must hold.
pub struct ShardData {
    pub dir: PathBuf,
    pub seeds: Vec<u64>,
    pub data: StudyData,
}

fn refused(dir: &Path, why: String) -> ShardDataError {
    ShardDataError { path: dir.join(FILE).display().to_string(), why }
}

/// Checks that every seed a shard's results name is one of its own.
fn own_seeds(shard: &ShardData, named: impl IntoIterator<Item = u64>) -> Result<(), ShardDataError> {
    let own: BTreeSet<u64> = shard.seeds.iter().copied().collect();
    if let Some(seed) = named.into_iter().find(|s| !own.contains(s)) {
        return Err(refused(
            &shard.dir,
            format!("results of seed {seed}, which is not among the shard's seeds {}", format_seeds(&shard.seeds)),
        ));
    }
    Ok(())
}

/// A solvers study's compared steps and whole runs' totals, by name.
pub type JoinedSolvers = (Vec<ComparedStep>, Vec<(String, RunTotals)>);

/// The solvers study of the shards (in index order, so seed order): every step, and each whole
/// run's totals joined.
pub fn join_solvers(shards: &[ShardData]) -> Result<JoinedSolvers, ShardDataError> {
    let mut steps = Vec::new();
    let mut whole: Option<Vec<(String, RunTotals)>> = None;
    for shard in shards {
        let StudyData::Solvers { steps: own, whole: own_whole, .. } = &shard.data else {
            return Err(refused(&shard.dir, "the results of a budget study, not a solvers study".into()));
        };
        own_seeds(shard, own.iter().map(|s| s.seed))?;
        for s in own {
            let step = s.compared().ok_or_else(|| {
                refused(
                    &shard.dir,
                    format!(
                        "seed {} step {}: {} features, not {}",
                        s.seed,
                        s.step,
                        s.features.len(),
                        crate::compare::FEATURES
                    ),
                )
            })?;
            steps.push(step);
        }
        match &mut whole {
            None => {
                whole = Some(
                    own_whole
                        .iter()
                        .map(|(name, t)| {
                            let totals = RunTotals {
                                sweeps: t.sweeps,
                                solve_us: t.solve_us,
                                capped: t.capped,
                                per_seed: t.per_seed.clone(),
                            };
                            (name.clone(), totals)
                        })
                        .collect(),
                )
            }
            Some(joined) => {
                let names = |w: &[(String, RunTotals)]| w.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
                let theirs: Vec<String> = own_whole.iter().map(|(n, _)| n.clone()).collect();
                if names(joined) != theirs {
                    return Err(refused(
                        &shard.dir,
                        format!(
                            "whole runs of {} where the first shard has {}",
                            theirs.join(", "),
                            names(joined).join(", ")
                        ),
                    ));
                }
                for ((_, total), (_, t)) in joined.iter_mut().zip(own_whole) {
                    total.sweeps += t.sweeps;
                    total.solve_us += t.solve_us;
                    total.capped += t.capped;
                    total.per_seed.extend(&t.per_seed);
                }
            }
        }
    }
    Ok((steps, whole.unwrap_or_default()))
}

/// The budget study of the shards (in index order): every run's steps joined in seed order, and
/// its error split summed seed by seed from the first, as the one-host study sums it.
pub fn join_budget(shards: &[ShardData]) -> Result<Vec<BudgetRun>, ShardDataError> {
    let mut runs: Vec<BudgetRun> = Vec::new();
    for (i, shard) in shards.iter().enumerate() {
        let StudyData::Budget { runs: own, .. } = &shard.data else {
            return Err(refused(&shard.dir, "the results of a solvers study, not a budget study".into()));
        };
        own_seeds(shard, own.iter().flat_map(|r| r.steps.iter().map(|s| s.simulation as u64)))?;
        if i == 0 {
            runs = own
                .iter()
                .map(|r| BudgetRun {
                    label: r.label.clone(),
                    model: r.model.clone(),
                    budget: r.budget,
                    steps: Vec::new(),
                    split: ErrorSplit::default(),
                    seed_splits: Vec::new(),
                })
                .collect();
        }
        let labels: Vec<&str> = own.iter().map(|r| r.label.as_str()).collect();
        if labels != runs.iter().map(|r| r.label.as_str()).collect::<Vec<_>>() {
            return Err(refused(&shard.dir, format!("runs {} where the first shard has others", labels.join(", "))));
        }
        for (run, r) in runs.iter_mut().zip(own) {
            run.steps.extend(r.steps.iter().cloned());
            for s in &r.seed_splits {
                run.split.add(s);
            }
            run.seed_splits.extend(r.seed_splits.iter().copied());
        }
    }
    Ok(runs)
}
