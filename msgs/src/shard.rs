//! Shards of a batch: `--shard I/N` runs the I-th of N deterministic parts of a seed list, and
//! the manifest (`shard.json`) a shard's folder carries, which says what a merge needs to trust
//! it: the whole run's settings and build, its own seeds, and whether it finished.
//!
//! Parts are contiguous blocks of the sorted seed list whose sizes differ by at most one, so the
//! same list and count always give the same parts on every host (a scheduler's array index is
//! all a task needs), and a part is written back as short ranges (`0..8,12`).

use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Most shards of one run: far more than any array job of seeds needs, few enough that a
/// manifest's list of them stays small.
pub const MAX_SHARDS: u32 = 10_000;

/// The I-th (from 0, as SLURM's `SLURM_ARRAY_TASK_ID` and Kubernetes' `JOB_COMPLETION_INDEX`
/// count) of N parts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    /// The whole run as one shard.
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// This shard's block of `items` (sizes differ by at most one, earlier blocks the smaller).
    pub fn part<'a, T>(&self, items: &'a [T]) -> &'a [T] {
        let bound = |i: u32| (i as usize * items.len()) / self.count as usize;
        &items[bound(self.index)..bound(self.index + 1)]
    }

    /// This shard's seeds of `seeds`; an error when it has none (more shards than seeds).
    pub fn seeds(&self, seeds: &[u64]) -> Result<Vec<u64>, String> {
        let part = self.part(seeds);
        if part.is_empty() {
            return Err(format!(
                "shard {self} of {} seeds has no seeds: use at most {} shards",
                seeds.len(),
                seeds.len()
            ));
        }
        Ok(part.to_vec())
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = String;

    fn from_str(s: &str) -> Result<Shard, String> {
        let (i, n) = s.split_once('/').ok_or_else(|| format!("`{s}`: expected I/N (shard I of N, I from 0)"))?;
        let number = |t: &str, what: &str| {
            t.trim().parse::<u32>().map_err(|_| format!("`{s}`: the {what} `{t}` is not a whole number"))
        };
        let (index, count) = (number(i, "index")?, number(n, "count")?);
        if count == 0 {
            return Err(format!("`{s}`: the count must be at least 1"));
        }
        if count > MAX_SHARDS {
            return Err(format!("`{s}`: more than {MAX_SHARDS} shards"));
        }
        if index >= count {
            return Err(format!(
                "`{s}`: index {index} is not below the count {count} (shards are numbered 0..{})",
                count - 1
            ));
        }
        Ok(Shard { index, count })
    }
}

/// A sorted seed list written as ranges (`0..8,12`): what `msgs::parse_seeds` reads back.
pub fn format_seeds(seeds: &[u64]) -> String {
    let mut out = Vec::new();
    let mut i = 0;
    while i < seeds.len() {
        let mut j = i;
        while j + 1 < seeds.len() && seeds[j + 1] == seeds[j] + 1 {
            j += 1;
        }
        out.push(if j == i { seeds[i].to_string() } else { format!("{}..{}", seeds[i], seeds[j] + 1) });
        i = j + 1;
    }
    out.join(",")
}

/// Where a shard stands: written `Running` before its work starts and rewritten at its end, so a
/// shard killed half way (a scheduler's time limit, a lost node) still says so.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "lowercase")]
pub enum ShardState {
    Running,
    Complete { finished_unix: u64 },
    Failed { finished_unix: u64, why: String },
}

/// A shard folder's `shard.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`Manifest::FORMAT`]; a manifest of another format is refused, not guessed at.
    pub format: u32,
    /// What made it (`dc eval`).
    pub command: String,
    pub shard: Shard,
    /// Every seed of the run, and this shard's part of them.
    pub all_seeds: Vec<u64>,
    pub seeds: Vec<u64>,
    /// The run's settings by name (what changes results or timings; not where it writes).
    pub settings: BTreeMap<String, String>,
    /// What ran it by name: the version, and a hash of each program that computes results.
    pub build: BTreeMap<String, String>,
    /// The whole run's report title.
    pub title: String,
    pub host: String,
    pub started_unix: u64,
    /// The command's own arguments (without `--shard` and `--out`), for a merge that computes
    /// its report as the command does (a study's); empty where the records say all.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub arguments: Vec<String>,
    #[serde(flatten)]
    pub state: ShardState,
}

/// A manifest that cannot be read or trusted, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a shard manifest: {why}")]
    Invalid { path: String, why: String },
}

impl Manifest {
    pub const FORMAT: u32 = 1;
    /// The manifest's name in a shard's folder.
    pub const FILE: &'static str = "shard.json";
    /// Larger than any manifest of [`MAX_SHARDS`]' worth of seeds: a bigger file is refused unread.
    pub const MAX_BYTES: u64 = 16 << 20;

    /// Reads `dir`'s manifest and checks that it is self-consistent: its seeds are its shard's
    /// part of all seeds.
    pub fn read(dir: &Path) -> Result<Manifest, ManifestError> {
        let path = dir.join(Self::FILE);
        let name = path.display().to_string();
        let io = |source| ManifestError::Io { path: name.clone(), source };
        let invalid = |why: String| ManifestError::Invalid { path: name.clone(), why };
        let size = std::fs::metadata(&path).map_err(io)?.len();
        if size > Self::MAX_BYTES {
            return Err(invalid(format!("{size} bytes, more than a manifest's {}", Self::MAX_BYTES)));
        }
        let text = std::fs::read_to_string(&path).map_err(io)?;
        let m: Manifest = serde_json::from_str(&text).map_err(|e| invalid(e.to_string()))?;
        if m.format != Self::FORMAT {
            return Err(invalid(format!("format {} (this build reads format {})", m.format, Self::FORMAT)));
        }
        if m.shard.count == 0 || m.shard.index >= m.shard.count {
            return Err(invalid(format!("shard {} is not a shard", m.shard)));
        }
        if !m.all_seeds.windows(2).all(|w| w[0] < w[1]) {
            return Err(invalid("all_seeds is not a sorted list without repeats".into()));
        }
        if m.shard.part(&m.all_seeds) != m.seeds.as_slice() {
            return Err(invalid(format!(
                "its seeds {} are not shard {}'s part of {}",
                format_seeds(&m.seeds),
                m.shard,
                format_seeds(&m.all_seeds)
            )));
        }
        Ok(m)
    }

    /// Writes the manifest into `dir` (through a temporary file and a rename: a reader never
    /// sees half a manifest).
    pub fn write(&self, dir: &Path) -> Result<(), ManifestError> {
        let path = dir.join(Self::FILE);
        let io = |source| ManifestError::Io { path: path.display().to_string(), source };
        let text = serde_json::to_string_pretty(self).expect("a manifest serialises");
        let partial = dir.join(format!(".{}.partial", Self::FILE));
        std::fs::write(&partial, text + "\n").map_err(io)?;
        std::fs::rename(&partial, &path).map_err(io)
    }
}

/// One finished shard of a run, as [`gather`] read it.
#[derive(Debug, Clone)]
pub struct FinishedShard {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub finished_unix: u64,
}

/// Why shards' folders do not make one run.
#[derive(Debug, thiserror::Error)]
pub enum GatherError {
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error("{0}")]
    Refused(String),
}

/// The shards of one run from their folders (any order), in index order, once each was checked:
/// every folder a shard's, each finished, all of one command, count, seed list, settings and
/// build, no shard twice and none missing. What the shards' own results hold is the merge's to
/// check. Any failure names the folder, the setting (both values) or the missing seeds.
pub fn gather(dirs: &[PathBuf]) -> Result<Vec<FinishedShard>, GatherError> {
    if dirs.is_empty() {
        return Err(GatherError::Refused("no shard folders given".into()));
    }
    let refused = |why: String| Err(GatherError::Refused(why));
    let mut shards = Vec::new();
    for dir in dirs {
        if !dir.join(Manifest::FILE).exists() {
            return refused(format!(
                "{}: no {} here: not the folder of a shard (`--shard I/N`), or it never started",
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
        shards.push(FinishedShard { dir: dir.clone(), manifest, finished_unix });
    }
    for s in &shards[1..] {
        let first = &shards[0];
        let (a, b) = (&first.manifest, &s.manifest);
        let differ = |what: &str, x: &dyn std::fmt::Display, y: &dyn std::fmt::Display| {
            Err(GatherError::Refused(format!(
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
        let seeds: Vec<u64> = absent.iter().flat_map(|&index| Shard { index, count }.part(all).to_vec()).collect();
        let named: Vec<String> = absent.iter().map(|i| format!("{i}/{count}")).collect();
        return refused(format!(
            "missing shard{} {} of {count}: seeds {} have no results; nothing written",
            if absent.len() == 1 { "" } else { "s" },
            named.join(", "),
            format_seeds(&seeds)
        ));
    }

    Ok(shards)
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

/// `merged.json` of `shards` (as [`gather`] returns them: at least one).
pub fn summary(shards: &[FinishedShard]) -> MergedSummary<'_> {
    let m = &shards[0].manifest;
    let list: Vec<MergedShard> = shards
        .iter()
        .map(|s| MergedShard {
            dir: s.dir.display().to_string(),
            shard: s.manifest.shard.to_string(),
            seeds: format_seeds(&s.manifest.seeds),
            host: s.manifest.host.clone(),
            seconds: s.finished_unix.saturating_sub(s.manifest.started_unix),
        })
        .collect();
    let start = shards.iter().map(|s| s.manifest.started_unix).min().unwrap_or(0);
    let end = shards.iter().map(|s| s.finished_unix).max().unwrap_or(0);
    MergedSummary {
        command: &m.command,
        seeds: format_seeds(&m.all_seeds),
        settings: &m.settings,
        build: &m.build,
        shard_seconds: list.iter().map(|s| s.seconds).sum(),
        shards: list,
        wall_seconds: end.saturating_sub(start),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_cover_the_list_once_in_order_with_sizes_one_apart() {
        let seeds: Vec<u64> = (0..30).collect();
        for count in 1..=30u32 {
            let parts: Vec<&[u64]> = (0..count).map(|index| Shard { index, count }.part(&seeds)).collect();
            assert_eq!(parts.concat(), seeds, "{count} shards");
            let sizes: Vec<usize> = parts.iter().map(|p| p.len()).collect();
            assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1, "{sizes:?}");
        }
        assert_eq!(Shard { index: 1, count: 4 }.part(&seeds), &seeds[7..15]);
        assert!(Shard { index: 0, count: 5 }.seeds(&[1, 2]).unwrap_err().contains("has no seeds"));
    }

    #[test]
    fn shard_text_round_trips_and_bad_text_is_named() {
        assert_eq!("2/4".parse::<Shard>(), Ok(Shard { index: 2, count: 4 }));
        assert_eq!(Shard { index: 2, count: 4 }.to_string(), "2/4");
        for (bad, says) in [
            ("3/2", "not below the count 2"),
            ("2/2", "not below"),
            ("0/0", "at least 1"),
            ("1", "expected I/N"),
            ("a/2", "index `a`"),
            ("1/-3", "count `-3`"),
            ("0/20000", "more than"),
        ] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn seeds_are_written_as_ranges_that_parse_back() {
        for seeds in [vec![0u64], vec![0, 1, 2, 3], vec![3, 5, 6, 7, 10], (7..15).collect()] {
            let text = format_seeds(&seeds);
            assert_eq!(crate::parse_seeds(&text).unwrap(), seeds, "{text}");
        }
        assert_eq!(format_seeds(&[0, 1, 2, 5, 7, 8]), "0..3,5,7..9");
    }

    #[test]
    fn a_manifest_round_trips_and_an_inconsistent_one_is_refused_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("dc-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let all: Vec<u64> = (0..10).collect();
        let shard = Shard { index: 1, count: 3 };
        let mut m = Manifest {
            format: Manifest::FORMAT,
            command: "dc eval".into(),
            shard,
            seeds: shard.seeds(&all).unwrap(),
            all_seeds: all,
            settings: BTreeMap::from([("n".into(), "100".into())]),
            build: BTreeMap::from([("version".into(), "0.1.0".into())]),
            title: "t".into(),
            host: "h".into(),
            started_unix: 1,
            arguments: vec!["solvers".into(), "--n".into(), "100".into()],
            state: ShardState::Complete { finished_unix: 2 },
        };
        m.write(&dir).unwrap();
        assert_eq!(Manifest::read(&dir).unwrap(), m);
        m.seeds = vec![0, 1, 2];
        m.write(&dir).unwrap();
        let e = Manifest::read(&dir).unwrap_err().to_string();
        assert!(e.contains("shard.json") && e.contains("not shard 1/3's part"), "{e}");
        std::fs::write(dir.join(Manifest::FILE), "{\"format\": 1").unwrap();
        let e = Manifest::read(&dir).unwrap_err().to_string();
        assert!(e.contains("shard.json") && e.contains("not a shard manifest"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
