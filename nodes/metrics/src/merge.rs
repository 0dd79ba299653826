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
use msgs::shard::{format_seeds, Manifest, ManifestError, ShardState};
use msgs::StepStats;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufReader, BufWriter};
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
    Manifest(#[from] ManifestError),
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

    /// Writes `dir/records.cbor` (through a temporary file and a rename: never half a file under
    /// the name).
    pub fn write(&self, dir: &Path) -> Result<PathBuf, MergeError> {
        let path = dir.join(Self::FILE);
        let failed = |why: String| MergeError::Records { path: path.display().to_string(), why };
        let partial = dir.join(format!(".{}.partial", Self::FILE));
        let file = std::fs::File::create(&partial).map_err(|e| failed(e.to_string()))?;
        let mut w = BufWriter::new(file);
        ciborium::into_writer(self, &mut w).map_err(|e| failed(e.to_string()))?;
        w.into_inner().map_err(|e| failed(e.to_string()))?.sync_all().map_err(|e| failed(e.to_string()))?;
        std::fs::rename(&partial, &path).map_err(|e| failed(e.to_string()))?;
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

/// One shard as the merge read it.
#[derive(Debug, Clone)]
pub struct ShardInput {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub finished_unix: u64,
}

/// The run the shards make up.
#[derive(Debug)]
pub struct Merged {
    pub aggregate: Aggregate,
    /// The report's title: the run's, with the solvers its runs announced.
    pub title: String,
    /// The shards in index order.
    pub shards: Vec<ShardInput>,
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
    if dirs.is_empty() {
        return Err(MergeError::Refused("no shard folders given".into()));
    }
    let refused = |why: String| Err(MergeError::Refused(why));
    let mut shards = Vec::new();
    for dir in dirs {
        if !dir.join(Manifest::FILE).exists() {
            return refused(format!(
                "{}: no {} here: not the folder of a `dc eval --shard` run (or it never started)",
                dir.display(),
                Manifest::FILE
            ));
        }
        let manifest = Manifest::read(dir)?;
        let finished_unix = match &manifest.state {
            ShardState::Complete { finished_unix } => *finished_unix,
            ShardState::Running => {
                return refused(format!(
                    "{}: shard {} (seeds {}) started on {} and never finished (killed, or still running): run it again",
                    dir.display(),
                    manifest.shard,
                    format_seeds(&manifest.seeds),
                    manifest.host
                ))
            }
            ShardState::Failed { why, .. } => {
                return refused(format!(
                    "{}: shard {} (seeds {}) failed on {}: {why}",
                    dir.display(),
                    manifest.shard,
                    format_seeds(&manifest.seeds),
                    manifest.host
                ))
            }
        };
        shards.push(ShardInput { dir: dir.clone(), manifest, finished_unix });
    }
    for s in &shards[1..] {
        let first = &shards[0];
        let (a, b) = (&first.manifest, &s.manifest);
        let differ = |what: &str, x: &dyn std::fmt::Display, y: &dyn std::fmt::Display| {
            Err(MergeError::Refused(format!(
                "shards of different runs: {what} is {x} in {} but {y} in {}",
                first.dir.display(),
                s.dir.display()
            )))
        };
        if a.command != b.command {
            return differ("the command", &a.command, &b.command);
        }
        if a.shard.count != b.shard.count {
            return differ("the shard count", &a.shard.count, &b.shard.count);
        }
        for (kind, x, y) in [("setting", &a.settings, &b.settings), ("build", &a.build, &b.build)] {
            let names: BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            let none = String::from("(not set)");
            if let Some(name) = names.into_iter().find(|n| x.get(*n) != y.get(*n)) {
                let (vx, vy) = (x.get(name).unwrap_or(&none), y.get(name).unwrap_or(&none));
                return differ(&format!("{kind} `{name}`"), &format!("`{vx}`"), &format!("`{vy}`"));
            }
        }
        if a.all_seeds != b.all_seeds {
            return differ("the seed list", &format_seeds(&a.all_seeds), &format_seeds(&b.all_seeds));
        }
    }
    // Every shard once: a repeat overlaps, a gap is missing seeds.
    shards.sort_by_key(|s| s.manifest.shard.index);
    for w in shards.windows(2) {
        if w[0].manifest.shard == w[1].manifest.shard {
            return refused(format!(
                "shards overlap: {} and {} are both shard {} (seeds {}): give each shard once",
                w[0].dir.display(),
                w[1].dir.display(),
                w[0].manifest.shard,
                format_seeds(&w[0].manifest.seeds)
            ));
        }
    }
    let count = shards[0].manifest.shard.count;
    let present: BTreeSet<u32> = shards.iter().map(|s| s.manifest.shard.index).collect();
    let absent: Vec<u32> = (0..count).filter(|i| !present.contains(i)).collect();
    if !absent.is_empty() {
        let all = &shards[0].manifest.all_seeds;
        let seeds: Vec<u64> =
            absent.iter().flat_map(|&index| msgs::shard::Shard { index, count }.part(all).to_vec()).collect();
        let named: Vec<String> = absent.iter().map(|i| format!("{i}/{count}")).collect();
        return refused(format!(
            "missing shard{} {} of {count}: seeds {} have no results; nothing written",
            if absent.len() == 1 { "" } else { "s" },
            named.join(", "),
            format_seeds(&seeds)
        ));
    }

    let mut aggregate = Aggregate::new();
    let mut solvers: Option<(PathBuf, Vec<String>)> = None;
    let mut models: Option<(PathBuf, BTreeSet<String>)> = None;
    for s in &shards {
        let data = RecordsFile::read(&s.dir)?;
        let path = s.dir.join(RecordsFile::FILE).display().to_string();
        let failed = |why: String| Err(MergeError::Records { path: path.clone(), why });
        if let Some(m) = data.missing.first() {
            return failed(format!("shard {}'s report lists missing data ({m}): run the shard again", s.manifest.shard));
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

/// `merged.json`: which shards made the report, where and how long each took.
#[derive(Debug, Serialize)]
pub struct MergedSummary<'a> {
    pub command: &'a str,
    pub seeds: String,
    pub settings: &'a BTreeMap<String, String>,
    pub build: &'a BTreeMap<String, String>,
    pub shards: Vec<MergedShard>,
    /// From the first shard's start to the last one's end (what the user waited).
    pub wall_seconds: u64,
    /// The sum of the shards' own times (what one host would have taken, about).
    pub shard_seconds: u64,
}

#[derive(Debug, Serialize)]
pub struct MergedShard {
    pub dir: String,
    pub shard: String,
    pub seeds: String,
    pub host: String,
    pub seconds: u64,
}

impl Merged {
    pub fn summary(&self) -> MergedSummary<'_> {
        let m = &self.shards[0].manifest;
        let shards: Vec<MergedShard> = self
            .shards
            .iter()
            .map(|s| MergedShard {
                dir: s.dir.display().to_string(),
                shard: s.manifest.shard.to_string(),
                seeds: format_seeds(&s.manifest.seeds),
                host: s.manifest.host.clone(),
                seconds: s.finished_unix.saturating_sub(s.manifest.started_unix),
            })
            .collect();
        let start = self.shards.iter().map(|s| s.manifest.started_unix).min().unwrap_or(0);
        let end = self.shards.iter().map(|s| s.finished_unix).max().unwrap_or(0);
        MergedSummary {
            command: &m.command,
            seeds: format_seeds(&m.all_seeds),
            settings: &m.settings,
            build: &m.build,
            shard_seconds: shards.iter().map(|s| s.seconds).sum(),
            shards,
            wall_seconds: end.saturating_sub(start),
        }
    }
}
