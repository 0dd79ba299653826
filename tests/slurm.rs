//! docs/cluster.md's SLURM path against a real SLURM: a single-node cluster (munged, slurmctld and
//! slurmd, started here as root by scripts/slurm/local-cluster.sh), a `dc eval` run submitted as an
//! array of shards with its merge as a dependent job (scripts/slurm/submit.sh), waited for, and
//! its report compared, table for table, with the same run on one host.
//! Skipped with a message where SLURM is not installed or this is not root; failing under
//! DC_REQUIRE_ALL=1 (.ci/run installs slurm-wlm and munge).

use deep_contact::{bin, repo_root, report_figures, scratch_dir, skip_for_missing, text};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const TEST: &str = "slurm_array_of_shards";
/// The run: three seeds a shard on three shards, so one array task waits for a free core.
const RUN: &[&str] = &["--models", "builtin,copy", "--seeds", "0..6", "--steps", "150", "--n", "30", "--threads", "1"];
/// slurmctld's and slurmd's ports: fixed (a probed free port can be taken before they bind it),
/// and away from a system SLURM's 6817/6818.
const PORTS: &str = "16817 16818";

/// The cluster of this test, stopped when the test ends (passing or not).
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let o = Command::new("bash")
            .arg(repo_root().join("scripts/slurm/local-cluster.sh"))
            .arg("start")
            .arg(dir)
            .env("DC_SLURM_PORTS", PORTS)
            .output()
            .expect("run local-cluster.sh");
        assert!(o.status.success(), "the local SLURM did not start:\n{}", text(&o));
        Cluster { dir: dir.to_path_buf(), conf: dir.join("slurm.conf") }
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// `scontrol show job ID`'s JobState and Reason.
    fn job_state(&self, job: &str) -> (String, String) {
        let o = self.command("scontrol").args(["-o", "show", "job", job]).output().expect("run scontrol");
        let line = String::from_utf8_lossy(&o.stdout).lines().next().unwrap_or_default().to_string();
        let field = |name: &str| {
            line.split_whitespace().find_map(|f| f.strip_prefix(&format!("{name}="))).unwrap_or("").to_string()
        };
        (field("JobState"), field("Reason"))
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(repo_root().join("scripts/slurm/local-cluster.sh"))
            .arg("stop")
            .arg(&self.dir)
            .output();
    }
}

fn slurm_at_hand() -> bool {
    if unsafe { libc::geteuid() } != 0 {
        return !skip_for_missing(TEST, "slurmd must run as root (it starts jobs as their users)");
    }
    for program in ["sbatch", "scontrol", "sinfo", "slurmctld", "slurmd", "munged"] {
        let found = Command::new("sh")
            .args(["-c", &format!("command -v {program} || test -x /usr/sbin/{program}")])
            .output()
            .is_ok_and(|o| o.status.success());
        if !found {
            return !skip_for_missing(TEST, &format!("`{program}` not found (apt-get install slurm-wlm munge)"));
        }
    }
    true
}

fn eval_into(out: &Path) -> Output {
    Command::new(bin("dc")).arg("eval").args(RUN).arg("--out").arg(out).output().expect("run dc eval")
}

#[test]
fn slurm_array_of_shards_and_its_dependent_merge_make_the_one_host_report() {
    if !slurm_at_hand() {
        return;
    }
    // munged's socket path must fit a Unix socket's 108 bytes: a short folder of our own in /tmp.
    let cluster_dir = std::env::temp_dir().join(format!("dc-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cluster_dir);
    let cluster = Cluster::start(&cluster_dir);
    let scratch = scratch_dir("slurm");

    let run = scratch.join("run");
    let o = cluster
        .command("bash")
        .arg(repo_root().join("scripts/slurm/submit.sh"))
        .arg("3")
        .arg(&run)
        .arg("eval")
        .args(RUN)
        .env("DC", bin("dc"))
        .output()
        .expect("run submit.sh");
    assert!(o.status.success(), "submission:\n{}", text(&o));
    let said = String::from_utf8_lossy(&o.stdout).to_string();
    let job_after = |label: &str| {
        said.split(label)
            .nth(1)
            .and_then(|t| t.split_whitespace().nth(1))
            .map(|j| j.trim_end_matches(|c: char| !c.is_ascii_digit()).to_string())
    };
    let (array, merge) = (job_after("shards:"), job_after("merge:"));
    let (Some(array), Some(merge)) = (array, merge) else { panic!("submit.sh did not name its jobs:\n{said}") };

    // The one-host run, while the cluster works (it shares the cores; timings are not compared).
    let one = scratch.join("one");
    let o = eval_into(&one);
    assert!(o.status.success(), "one-host run:\n{}", text(&o));

    let deadline = Instant::now() + Duration::from_secs(600);
    let outputs = || {
        let mut logs = String::new();
        for entry in std::fs::read_dir(&run).into_iter().flatten().flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.ends_with(".out") {
                logs += &format!("--- {name}\n{}\n", std::fs::read_to_string(entry.path()).unwrap_or_default());
            }
        }
        logs
    };
    loop {
        let (state, reason) = cluster.job_state(&merge);
        match state.as_str() {
            "COMPLETED" => break,
            "PENDING" if reason.contains("DependencyNeverSatisfied") => {
                panic!("a shard of array job {array} failed, so the merge never ran:\n{}", outputs())
            }
            "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY" => {
                panic!("the merge job {merge} ended {state}:\n{}", outputs())
            }
            _ => {}
        }
        assert!(
            Instant::now() < deadline,
            "array {array} and merge {merge} not done in 600 s (merge {state} {reason}):\n{}",
            outputs()
        );
        std::thread::sleep(Duration::from_millis(500));
    }

    let report = run.join("report");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("merged.json")).expect("merged.json")).unwrap();
    let seeds: Vec<&str> = summary["shards"].as_array().unwrap().iter().map(|s| s["seeds"].as_str().unwrap()).collect();
    assert_eq!(seeds, ["0..2", "2..4", "4..6"], "one shard a task, in index order");
    let figures = report_figures(&one);
    let merged = report_figures(&report);
    assert_eq!(merged.keys().collect::<Vec<_>>(), figures.keys().collect::<Vec<_>>(), "the same tables");
    for (file, rows) in &figures {
        assert_eq!(&merged[file], rows, "{file}: the SLURM run's merged report differs from the one-host run's");
    }
    drop(cluster);
    let _ = std::fs::remove_dir_all(&cluster_dir);
}
