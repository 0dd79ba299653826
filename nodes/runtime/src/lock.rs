//! A graph's hold on its bus namespace on one host, so that two graphs (or a graph and a
//! `dc play`) never share topics unasked: the launcher takes it for its graph, `dc play` for the
//! recording it publishes.

/// Why a namespace could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another graph (or player) holds the namespace on this host.
    #[error("namespace `{namespace}` is in use on host `{host}` by {holder}")]
    InUse { namespace: String, host: String, holder: String },
    #[error("namespace lock {path}: {what}")]
    Io { path: String, what: String },
}

/// One node of a running graph, as its launcher lists it beside its namespace lock.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NodeEntry {
    pub name: String,
    pub program: String,
    pub pid: u32,
    /// `running`, `done`, or how it exited (`exit status: 1`).
    pub state: String,
    pub restarts: u32,
}

/// The nodes one launcher runs: what `dc node list` shows.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GraphNodes {
    pub namespace: String,
    pub host: String,
    pub graph: String,
    pub launcher_pid: u32,
    pub nodes: Vec<NodeEntry>,
}

/// A graph's hold on its namespace on one host: an advisory lock (`flock`) on a file named after
/// both, held while the launcher runs and released by the kernel when it exits, however it exits.
/// A second graph on the same namespace and host is refused instead of sharing the first's
/// topics (its recorder would record both graphs' runs). The file goes when the lock is dropped
/// (the launcher ends, normally or on an error); one left by a killed launcher is locked by no
/// one, and the next launcher removes it.
pub struct NamespaceLock {
    _file: std::fs::File,
    path: std::path::PathBuf,
}

impl Drop for NamespaceLock {
    fn drop(&mut self) {
        // Removed while still locked: a launcher that opened it meanwhile finds, once it has the
        // lock, that the path no longer names its file, and takes a new one.
        let _ = std::fs::remove_file(self.path.with_extension("nodes"));
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Whether `file` (open) is the file at `path` now: a lock file may be removed between the
/// open and the lock, and a lock on a removed file holds nothing.
fn is_file_at(file: &std::fs::File, path: &std::path::Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(open), Ok(named)) => open.dev() == named.dev() && open.ino() == named.ino(),
        _ => false,
    }
}

/// Takes the advisory lock on `file` without waiting: Ok(false) when another process holds it.
fn try_flock(file: &std::fs::File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a descriptor `file` owns; no memory is involved.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

/// Removes the lock files in `folder` no process holds (their launcher died without removing
/// them); returns how many. A file some launcher holds is left alone.
fn remove_stale_locks(folder: &std::path::Path) -> usize {
    let Ok(entries) = std::fs::read_dir(folder) else { return 0 };
    let mut removed = 0;
    for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
        if path.extension().is_none_or(|e| e != "lock") {
            continue;
        }
        let Ok(file) = std::fs::OpenOptions::new().read(true).open(&path) else { continue };
        // Held by no one, and still the file at that path: its launcher is gone.
        if try_flock(&file).unwrap_or(false) && is_file_at(&file, &path) && std::fs::remove_file(&path).is_ok() {
            let _ = std::fs::remove_file(path.with_extension("nodes"));
            removed += 1;
        }
    }
    removed
}

/// The host name under which `dc play` holds a namespace (no graph's host is named so).
pub const PLAYER_HOST: &str = "dc-play";

/// The name a lock file takes after its namespace and host.
fn lock_file_name(namespace: &str, host: &str) -> String {
    let safe = |s: &str| {
        s.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).collect::<String>()
    };
    format!("{}@{}.lock", safe(namespace), safe(host))
}

impl NamespaceLock {
    /// Who holds `namespace` on this machine, per host: (host, what the holder said), for the
    /// hosts whose lock is held now.
    pub fn holders(namespace: &str) -> Vec<(String, String)> {
        use std::io::Read;
        let prefix = lock_file_name(namespace, "");
        let prefix = prefix.trim_end_matches(".lock");
        let Ok(entries) = std::fs::read_dir(Self::folder()) else { return Vec::new() };
        let mut held = Vec::new();
        for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
            let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
            let Some(host) = name.strip_prefix(prefix).and_then(|h| h.strip_suffix(".lock")) else { continue };
            let Ok(mut file) = std::fs::OpenOptions::new().read(true).open(&path) else { continue };
            if try_flock(&file).unwrap_or(true) {
                continue; // nobody holds it (we just did, and drop it with the file)
            }
            let mut said = String::new();
            let _ = file.read_to_string(&mut said);
            held.push((host.to_string(), said.trim().to_string()));
        }
        held.sort();
        held
    }

    /// Says which nodes this holder runs: `<lock>.nodes` beside the lock file (JSON, replaced
    /// whole, never seen half written), removed with the lock.
    pub fn list_nodes(&self, nodes: &GraphNodes) -> std::io::Result<()> {
        let json = serde_json::to_vec_pretty(nodes).map_err(std::io::Error::other)?;
        crate::files::replace_file(&self.path.with_extension("nodes"), &json)
    }

    /// The node lists of the graphs holding a namespace on this machine now (all, or those of
    /// `namespace`), sorted by namespace and host. A list whose lock no process holds (its
    /// launcher is gone) is not shown; one that does not parse is skipped.
    pub fn running_graphs(namespace: Option<&str>) -> Vec<GraphNodes> {
        let Ok(entries) = std::fs::read_dir(Self::folder()) else { return Vec::new() };
        let mut graphs = Vec::new();
        for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
            if path.extension().is_none_or(|e| e != "nodes") {
                continue;
            }
            let Ok(lock) = std::fs::OpenOptions::new().read(true).open(path.with_extension("lock")) else { continue };
            if try_flock(&lock).unwrap_or(true) {
                continue; // held by no one: its launcher is gone
            }
            // A list is small; a foreign file there is read to a bound, never whole.
            let Ok(bytes) = crate::files::read_bounded(&path, "node list", 1 << 20) else { continue };
            let Ok(graph) = serde_json::from_slice::<GraphNodes>(&bytes) else { continue };
            if namespace.is_none_or(|ns| ns == graph.namespace) {
                graphs.push(graph);
            }
        }
        graphs.sort_by(|a, b| (&a.namespace, &a.host).cmp(&(&b.namespace, &b.host)));
        graphs
    }

    /// The folder of the lock files.
    pub fn folder() -> std::path::PathBuf {
        std::env::temp_dir().join("dc-graphs")
    }

    /// Takes the namespace on `host` for this process (`holder` says who: "graph `eval`",
    /// "dc play"), or says who holds it; first removes the lock files of holders that are gone.
    pub fn acquire(namespace: &str, host: &str, holder: &str) -> Result<NamespaceLock, LockError> {
        use std::io::{Read, Seek, Write};
        let path = Self::folder().join(lock_file_name(namespace, host));
        let err = |what: String| LockError::Io { path: path.display().to_string(), what };
        std::fs::create_dir_all(Self::folder()).map_err(|e| err(e.to_string()))?;
        match remove_stale_locks(&Self::folder()) {
            0 => {}
            n => tracing::debug!("removed {n} lock files of graphs that are gone"),
        }
        // A few tries: the file may be removed (its graph ended, or it was stale) between our
        // open and our lock.
        let mut tries = 0;
        let (mut file, locked) = loop {
            tries += 1;
            let file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| err(e.to_string()))?;
            let locked = try_flock(&file).map_err(|e| err(e.to_string()))?;
            // Held by someone who has not said who: another process's scan of the folder (stale
            // files, holders) tests each lock for a moment, or a holder is about to write its
            // name. Either way it is gone in a moment: try again before calling it in use.
            if !locked && tries < 100 && file.metadata().is_ok_and(|m| m.len() == 0) {
                std::thread::sleep(std::time::Duration::from_millis(5));
                continue;
            }
            if !locked || is_file_at(&file, &path) {
                break (file, locked);
            }
            if tries >= 100 {
                return Err(err("removed again and again while being locked".into()));
            }
        };
        if !locked {
            let mut held_by = String::new();
            let _ = file.read_to_string(&mut held_by);
            let holder = if held_by.trim().is_empty() {
                "a process that has not said which".to_string()
            } else {
                held_by.trim().to_string()
            };
            return Err(LockError::InUse { namespace: namespace.to_string(), host: host.to_string(), holder });
        }
        let said = format!("{holder}, pid {}", std::process::id());
        let wrote = file.set_len(0).and_then(|_| file.rewind()).and_then(|_| file.write_all(said.as_bytes()));
        wrote.map_err(|e| err(e.to_string()))?;
        let lock = NamespaceLock { _file: file, path };
        // A recording played into a namespace (`dc play`) shares it with no graph, and a graph
        // none with a player: their runs would mix. Checked once our own lock is held, so two
        // that start together cannot both miss each other.
        let crossing = Self::holders(namespace)
            .into_iter()
            .find(|(other, _)| other != host && (other == PLAYER_HOST || host == PLAYER_HOST));
        if let Some((other, holder)) = crossing {
            drop(lock);
            return Err(LockError::InUse { namespace: namespace.to_string(), host: other, holder });
        }
        Ok(lock)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_graph_on_a_namespace_and_host_is_refused_until_the_first_ends() {
        let ns = format!("lock-test-{}", std::process::id());
        let first = NamespaceLock::acquire(&ns, "local", "graph `first`").unwrap();
        let e = NamespaceLock::acquire(&ns, "local", "graph `second`").err().expect("refused");
        let text = e.to_string();
        assert!(text.contains(&ns) && text.contains("graph `first`") && text.contains("in use"), "{text}");
        // Another host of the same graph (two hosts on one machine, as the two-host tests run) is not refused.
        let other_host = NamespaceLock::acquire(&ns, "b", "graph `first`").unwrap();
        drop(first);
        let again = NamespaceLock::acquire(&ns, "local", "graph `second`").unwrap();
        drop((again, other_host));
        for host in ["local", "b"] {
            assert!(!NamespaceLock::folder().join(format!("{ns}@{host}.lock")).exists(), "{host}: left behind");
        }
    }

    /// Each graph used to leave its lock file: the folder grew by one per `dc eval`.
    #[test]
    fn a_lock_file_goes_with_its_graph_and_stale_ones_are_removed_but_held_ones_kept() {
        let ns = format!("lock-files-{}", std::process::id());
        let path = |host: &str| NamespaceLock::folder().join(format!("{ns}@{host}.lock"));
        let held = NamespaceLock::acquire(&ns, "held", "graph `held`").unwrap();
        assert!(path("held").is_file());
        // Left by a launcher that was killed: nobody holds it.
        std::fs::write(path("stale"), "graph `gone`, pid 999999999").unwrap();
        let other = NamespaceLock::acquire(&ns, "local", "graph `other`").unwrap();
        assert!(!path("stale").exists(), "a stale lock file is removed at start");
        assert!(path("held").is_file(), "a held one is kept");
        let e = NamespaceLock::acquire(&ns, "held", "graph `second`").err().expect("still refused");
        assert!(e.to_string().contains("graph `held`"), "{e}");
        drop(other);
        assert!(!path("local").exists(), "removed when its graph ends");
        drop(held);
        assert!(!path("held").exists());
    }

    #[test]
    fn the_holders_of_a_namespace_are_listed_by_host_and_a_player_shares_with_no_graph() {
        let ns = format!("lock-holders-{}", std::process::id());
        assert!(NamespaceLock::holders(&ns).is_empty());
        let b = NamespaceLock::acquire(&ns, PLAYER_HOST, "dc play x.mcap").unwrap();
        let e = NamespaceLock::acquire(&ns, "local", "graph `g`").err().expect("a player holds it");
        assert!(e.to_string().contains("dc play x.mcap"), "{e}");
        drop(b);
        let a = NamespaceLock::acquire(&ns, "local", "graph `g`").unwrap();
        let e = NamespaceLock::acquire(&ns, PLAYER_HOST, "dc play y.mcap").err().expect("a graph holds it");
        assert!(e.to_string().contains("graph `g`"), "{e}");
        // The refused player left nothing behind; the graph's lock is untouched.
        assert_eq!(NamespaceLock::holders(&ns).len(), 1);
        // Two hosts of one graph on one machine (as the two-host tests run) are both listed.
        let b = NamespaceLock::acquire(&ns, "b", "graph `g`").unwrap();
        // Another namespace that starts with this one's name is not this one.
        let c = NamespaceLock::acquire(&format!("{ns}x"), "local", "graph `h`").unwrap();
        let pid = std::process::id();
        assert_eq!(
            NamespaceLock::holders(&ns),
            [
                ("b".to_string(), format!("graph `g`, pid {pid}")),
                ("local".to_string(), format!("graph `g`, pid {pid}"))
            ]
        );
        drop((a, b, c));
        assert!(NamespaceLock::holders(&ns).is_empty());
    }
}
