//! The Kubernetes manifests of docs/cluster.md, checked offline against the API's schema and
//! against each other (scripts/check-kubernetes.py); and the check itself catches what it claims to.

use deep_contact::{have_python, python, repo_root, scratch_dir, text};
use std::path::Path;

fn check(dir: &Path) -> std::process::Output {
    python("scripts/check-kubernetes.py", &[dir.to_str().unwrap()])
}

/// A copy of deploy/kubernetes with `edit` applied to the text of `file`.
fn edited(test: &str, file: &str, edit: impl FnOnce(String) -> String) -> std::path::PathBuf {
    let dir = scratch_dir(test);
    for entry in std::fs::read_dir(repo_root().join("deploy/kubernetes")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), dir.join(entry.file_name())).unwrap();
    }
    let path = dir.join(file);
    let text = std::fs::read_to_string(&path).unwrap();
    let changed = edit(text.clone());
    assert_ne!(changed, text, "the edit of {file} changed nothing");
    std::fs::write(&path, changed).unwrap();
    dir
}

#[test]
fn shipped_manifests_pass_the_schema_and_agree_with_each_other() {
    if !have_python("kubernetes_manifests", "kubernetes_validate, yaml") {
        return;
    }
    let o = check(&repo_root().join("deploy/kubernetes"));
    assert!(o.status.success(), "{}", text(&o));

    // An unknown field (a typo of completionMode): the strict schema refuses it, naming it.
    let dir = edited("k8s-typo", "eval-indexed-job.yaml", |t| t.replace("completionMode:", "completionsMode:"));
    let o = check(&dir);
    assert!(!o.status.success() && text(&o).contains("completionsMode"), "{}", text(&o));

    // More pods than the shards say: seeds would be run twice, or left out.
    let dir = edited("k8s-count", "eval-indexed-job.yaml", |t| t.replace("completions: 4", "completions: 5"));
    let o = check(&dir);
    assert!(!o.status.success() && text(&o).contains("DC_SHARDS"), "{}", text(&o));

    // A merge of another run's folder.
    let dir = edited("k8s-run", "merge-job.yaml", |t| t.replace("value: eval-run", "value: other-run"));
    let o = check(&dir);
    assert!(!o.status.success() && text(&o).contains("DC_RUN"), "{}", text(&o));
}
