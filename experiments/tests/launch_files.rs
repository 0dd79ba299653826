//! The experiments' launch files (`experiments/launch/`) still load and their nodes accept their
//! parameters: `dc launch FILE --dry-run` from the repository root, as their comments say to run
//! them (which checks every node's parameters without starting the graph).

use deep_contact::{bin, repo_root, text};
use std::process::Command;

#[test]
fn every_experiment_launch_file_loads_and_its_parameters_check() {
    let dir = repo_root().join("experiments/launch");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("experiments/launch")
        .map(|e| e.expect("dir entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no launch files in {}", dir.display());
    for file in files {
        let out = Command::new(bin("dc"))
            .arg("launch")
            .arg(&file)
            .arg("--dry-run")
            .current_dir(repo_root())
            .output()
            .expect("run dc");
        assert!(out.status.success(), "{}: {}", file.display(), text(&out));
    }
}
