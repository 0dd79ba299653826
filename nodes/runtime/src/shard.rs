//! `--shard I/N` of a batch command (`dc eval`, `dc study`): what a shard's manifest
//! (`shard.json`, [`msgs::shard::Manifest`]) records about the run (its settings by name, the build
//! of every program that computes its results, the host) and the manifest's life: `running`
//! before the work, `complete` or `failed` after it, so a merge can tell a finished shard from one
//! killed half way.

use anyhow::{Context, Result};
use msgs::shard::{Manifest, Shard, ShardState};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

/// The SHA-256 of a file's bytes, in hex.
pub fn file_sha256(path: &Path) -> Result<String> {
    let mut file = std::fs::File::open(path).with_context(|| format!("reading {} to hash it", path.display()))?;
    let mut hasher = Sha256::new();
    let mut buffer = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buffer).with_context(|| format!("reading {} to hash it", path.display()))?;
        if n == 0 {
            break;
        }
        hasher.update(&buffer[..n]);
    }
    Ok(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// The build that runs `programs` (the graph's node binaries): dc's version and a hash of each
/// program, by name. Two shards agree on it only when the same binaries computed them.
pub fn build_of<'a>(programs: impl IntoIterator<Item = &'a Path>) -> Result<BTreeMap<String, String>> {
    let mut build = BTreeMap::from([("version".to_string(), env!("CARGO_PKG_VERSION").to_string())]);
    for program in programs {
        let name = program.file_name().map_or_else(|| program.display().to_string(), |n| n.to_string_lossy().into());
        build.insert(format!("{name} sha256"), file_sha256(program)?);
    }
    Ok(build)
}

/// This machine's host name (what a scheduler's node list shows), or `unknown`.
pub fn host_name() -> String {
    let mut buffer = [0u8; 256];
    // SAFETY: the buffer is valid for its length; gethostname writes at most that many bytes.
    let ok = unsafe { libc::gethostname(buffer.as_mut_ptr().cast(), buffer.len()) } == 0;
    let end = buffer.iter().position(|&b| b == 0).unwrap_or(buffer.len());
    match std::str::from_utf8(&buffer[..end]) {
        Ok(name) if ok && !name.is_empty() => name.to_string(),
        _ => "unknown".to_string(),
    }
}

pub fn now_unix() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0)
}

/// A shard's run: its manifest written `running` into `dir` now, and rewritten when [`finish`]
/// says how the work ended. `results` names the file the merge reads (`records.cbor`,
/// `study.cbor`): an earlier run's is removed at the start, and a run that ends without writing
/// it has failed.
///
/// [`finish`]: RunningShard::finish
pub struct RunningShard<'a> {
    dir: &'a Path,
    results: &'a str,
    manifest: Manifest,
}

impl<'a> RunningShard<'a> {
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        dir: &'a Path,
        command: &str,
        shard: Shard,
        all_seeds: &[u64],
        settings: BTreeMap<String, String>,
        build: BTreeMap<String, String>,
        title: &str,
        arguments: Vec<String>,
        results: &'a str,
    ) -> Result<RunningShard<'a>> {
        // An earlier run's results in the folder must not pass for this run's.
        let earlier = dir.join(results);
        match std::fs::remove_file(&earlier) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("removing the earlier {}", earlier.display()))
            }
            _ => {}
        }
        let manifest = Manifest {
            format: Manifest::FORMAT,
            command: command.to_string(),
            shard,
            seeds: shard.seeds(all_seeds).map_err(anyhow::Error::msg)?,
            all_seeds: all_seeds.to_vec(),
            settings,
            build,
            title: title.to_string(),
            host: host_name(),
            started_unix: now_unix(),
            arguments,
            state: ShardState::Running,
        };
        manifest.write(dir)?;
        Ok(RunningShard { dir, results, manifest })
    }

    /// Records how the shard's work ended and passes its result on.
    pub fn finish<T>(mut self, result: Result<T>) -> Result<T> {
        let path = self.dir.join(self.results);
        let result = result.and_then(|value| {
            anyhow::ensure!(path.is_file(), "{} wrote no {}", self.manifest.command, path.display());
            Ok(value)
        });
        let finished_unix = now_unix();
        self.manifest.state = match &result {
            Ok(_) => ShardState::Complete { finished_unix },
            Err(e) => ShardState::Failed { finished_unix, why: format!("{e:#}") },
        };
        let written = self.manifest.write(self.dir).with_context(|| format!("shard {}", self.manifest.shard));
        let value = result?;
        written?;
        Ok(value)
    }
}
