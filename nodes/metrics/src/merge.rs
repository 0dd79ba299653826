//! One report from the shards of a run (`dc report merge DIR...`): every shard's steps, with the
//! per-sweep residuals, as the one-host run's metrics node would have received them.
//!
//! A shard's folder holds its own report, its manifest (`shard.json`, [`msgs::shard::Manifest`],
//! written by `dc eval --shard`) and every step it received (`records.cbor`, [`RecordsFile`],
//! written by `dc-metrics --records`). The merge trusts nothing it has not checked: every shard of
//! the run present once, each finished, all of one run's settings and build, each holding exactly
//! its own seeds and nothing missing. Any failure refuses the whole merge before anything is
//! written, naming the shard folder, the setting or the seeds.

use crate::aggregate::{Aggregate, StepRecord};
use crate::completeness::Completeness;
use msgs::shard::{format_seeds, gather, FinishedShard, GatherError, MergedSummary};
use msgs::StepStats;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Every step a metrics node received, with what its report said around them: the file a merge
/// rebuilds the report from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordsFile {
    /// [`RecordsFile::FORMAT`].
    pub format: u32,
    /// The report's title as given (before the solvers are added).
    pub title: String,
    /// The solver settings the runs announced.
    pub solvers: Vec<String>,
    /// What the report said was missing (a complete run: nothing).
    pub missing: Vec<String>,
    pub records: Vec<Record>,
}

/// One step's statistics and its residual after each sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Record {
    pub stats: StepStats,
    pub residuals: Vec<f32>,
}

/// What cannot be merged, naming the folder, file, setting or seeds.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error(transparent)]
    Gather(#[from] GatherError),
    #[error("{path}: {why}")]
    Records { path: String, why: String },
    #[error("{0}")]
    Refused(String),
}

impl RecordsFile {
    pub const FORMAT: u32 = 1;
    /// Its name in a report folder.
    pub const FILE: &'static str = "records.cbor";

    /// The file of `aggregate` (every model's records in report order).
    pub fn of(aggregate: &Aggregate, title: &str, solvers: &[String], missing: &[String]) -> RecordsFile {
        let records = aggregate
            .model_order()
            .iter()
            .flat_map(|m| aggregate.records(m))
            .map(|r| Record { stats: r.stats.clone(), residuals: r.residuals.clone() })
            .collect();
        RecordsFile {
            format: Self::FORMAT,
            title: title.to_string(),
            solvers: solvers.to_vec(),
            missing: missing.to_vec(),
            records,
        }
    }

    /// Writes `dir/records.cbor` (never half a file under the name).
    pub fn write(&self, dir: &Path) -> Result<PathBuf, MergeError> {
        let path = dir.join(Self::FILE);
        runtime::files::replace_cbor(&path, self)
            .map_err(|e| MergeError::Records { path: path.display().to_string(), why: e.to_string() })?;
        Ok(path)
    }

    /// Reads `dir/records.cbor` and checks every step as the live path checks a frame (finite
    /// measurements, no step twice, ...). Only a regular file is read.
    pub fn read(dir: &Path) -> Result<RecordsFile, MergeError> {
        let path = dir.join(Self::FILE);
        let failed = |why: String| MergeError::Records { path: path.display().to_string(), why };
        let file = runtime::files::open_regular(&path, "records file").map_err(|e| failed(e.to_string()))?;
        // Lengths inside the file are checked against the bytes present by the decoder, which
        // reserves at most a bounded amount ahead of what it has read.
        let data: RecordsFile = ciborium::from_reader(BufReader::new(file))
            .map_err(|e| failed(format!("not a records file (corrupt or cut short?): {e}")))?;
        if data.format != Self::FORMAT {
            return Err(failed(format!("format {} (this build reads format {})", data.format, Self::FORMAT)));
        }
        if let Some((i, why)) = Completeness::first_implausible(data.records.iter().map(|r| &r.stats)) {
            return Err(failed(format!("record {}: impossible statistics: {why}", i + 1)));
        }
        Ok(data)
    }
}

/// The run the shards make up.
#[derive(Debug)]
pub struct Merged {
    pub aggregate: Aggregate,
    /// The report's title: the run's, with the solvers its runs announced.
    pub title: String,
    /// The shards in index order.
    pub shards: Vec<FinishedShard>,
}

/// A report title with the solvers its runs announced (reports under different solvers must not
/// be read as one).
pub fn titled(title: &str, solvers: &[String]) -> String {
    if solvers.is_empty() {
        title.to_string()
    } else {
        format!("{title} ({})", solvers.join("; "))
    }
}

/// Merges the shard folders `dirs` (any order) into one run; see the module's checks.
pub fn merge(dirs: &[PathBuf]) -> Result<Merged, MergeError> {
    let shards = gather(dirs)?;
    let refused = |why: String| Err(MergeError::Refused(why));
    let mut aggregate = Aggregate::new();
    let mut solvers: Option<(PathBuf, Vec<String>)> = None;
    let mut models: Option<(PathBuf, BTreeSet<String>)> = None;
    for s in &shards {
        let data = RecordsFile::read(&s.dir)?;
        let path = s.dir.join(RecordsFile::FILE).display().to_string();
        let failed = |why: String| Err(MergeError::Records { path: path.clone(), why });
        if let Some(m) = data.missing.first() {
            return failed(format!(
                "shard {}'s report lists missing data ({m}): run the shard again",
                s.manifest.shard
            ));
        }
        match &solvers {
            Some((dir, earlier)) if *earlier != data.solvers => {
                return refused(format!(
                    "shards of different runs: the solvers are `{}` in {} but `{}` in {}",
                    earlier.join("; "),
                    dir.display(),
                    data.solvers.join("; "),
                    s.dir.display()
                ))
            }
            None => solvers = Some((s.dir.clone(), data.solvers.clone())),
            _ => {}
        }
        let own: BTreeSet<u64> = s.manifest.seeds.iter().copied().collect();
        let mut seen: BTreeMap<&str, BTreeSet<u64>> = BTreeMap::new();
        for r in &data.records {
            let seed = r.stats.simulation as u64;
            if !own.contains(&seed) {
                return failed(format!(
                    "a step of simulation {seed}, which is not among shard {}'s seeds {}",
                    s.manifest.shard,
                    format_seeds(&s.manifest.seeds)
                ));
            }
            seen.entry(r.stats.model.as_str()).or_default().insert(seed);
        }
        let shard_models: BTreeSet<String> = seen.keys().map(|m| m.to_string()).collect();
        if let Some((model, seeds)) = seen.iter().find(|(_, seeds)| **seeds != own) {
            let lacking: Vec<u64> = own.difference(seeds).copied().collect();
            return failed(format!("model {model} has no steps of simulations {}", format_seeds(&lacking)));
        }
        match &models {
            Some((dir, earlier)) if *earlier != shard_models => {
                let list = |m: &BTreeSet<String>| m.iter().cloned().collect::<Vec<_>>().join(",");
                return refused(format!(
                    "shards of different runs: the models are {} in {} but {} in {}",
                    list(earlier),
                    dir.display(),
                    list(&shard_models),
                    s.dir.display()
                ));
            }
            None => models = Some((s.dir.clone(), shard_models)),
            _ => {}
        }
        for r in data.records {
            aggregate.add(StepRecord { stats: r.stats, residuals: r.residuals });
        }
    }
    let solvers = solvers.map(|(_, s)| s).unwrap_or_default();
    let title = titled(&shards[0].manifest.title, &solvers);
    Ok(Merged { aggregate, title, shards })
}

impl Merged {
    /// `merged.json`'s content.
    pub fn summary(&self) -> MergedSummary<'_> {
        msgs::shard::summary(&self.shards)
    }
}
