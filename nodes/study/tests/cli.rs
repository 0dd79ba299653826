//! `dc-study` as users run it: bad flags are refused before anything runs, naming the flag; a
//! reader that goes away (`| head`) ends it quietly.

use std::process::{Command, Stdio};

fn dc_study(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dc-study")).args(args).output().expect("run dc-study");
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn bad_flags_are_refused_naming_what_is_wrong() {
    for (args, says) in [
        (&["solvers", "pgs,pgs"][..], "asked for twice"),
        (&["solvers", "pgs,jacobi"], "unknown method `jacobi`"),
        (&["budget", "0"], "from 1 to"),
        (&["budget", "8", "--models", "builtin,builtin"], "twice"),
        (&["budget", "8", "--timing-repeats", "0"], "--timing-repeats"),
        (&["bench", "--cases", "100000000:10"], "at most 1000000"),
        (&["solvers", "pgs", "--n", "1000", "--side", "15"], "scene too dense"),
        (&["solvers", "ipm:nd+cold"], "ipm:nd+warm"),
        (&["friction", "--seeds", "3"], "at least 2 seeds"),
        (&["friction", "--seeds", "40..42", "--steps", "50", "--late", "60"], "--late 60"),
        (&["friction", "--seeds", "40..42", "--late", "0"], "--late"),
    ] {
        let (code, err) = dc_study(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: no `{says}` in\n{err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    // Nothing is trained on the evaluation seeds.
    let (code, err) = dc_study(&["solvers", "pgs,sor:1.4", "--train-seeds", "25..35", "--steps", "2"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--train-seeds 25..35") && err.contains("evaluation seed"), "{err}");
    // The node's flags are not the studies' and the other way round.
    let (code, err) = dc_study(&["solvers", "pgs", "--publish-problem"]);
    assert_eq!(code, 2, "{err}");
    let node = Command::new(env!("CARGO_BIN_EXE_dc-study")).args(["solvers", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&node.stdout);
    assert!(
        help.contains("--train-seeds") && help.contains("--tolerance") && !help.contains("--step-period"),
        "{help}"
    );
}

#[test]
fn a_closed_output_pipe_ends_the_study_quietly() {
    // `dc study solvers ... | head -0`: the reader is gone before the report is written.
    let mut child = Command::new(env!("CARGO_BIN_EXE_dc-study"))
        .args(["solvers", "pgs,nncg:1.2/down", "--seeds", "40..42", "--steps", "30", "--n", "30"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run dc-study");
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(!err.contains("panicked") && !err.contains("Broken pipe"), "{err}");
}

#[test]
fn the_friction_study_runs_both_laws_and_writes_its_verdict() {
    let dir = std::env::temp_dir().join(format!("dc-friction-study-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_dc-study"))
        .args(["friction", "--n", "30", "--seeds", "40..42", "--steps", "80", "--late", "20", "--threads", "1"])
        .arg("--out")
        .arg(&dir)
        .output()
        .expect("run dc-study");
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    for says in ["| pile height (m) |", "| late mean body speed (m/s) |", "| per-step |", "Verdict: "] {
        assert!(stdout.contains(says), "no `{says}` in\n{stdout}");
    }
    let report = std::fs::read_to_string(dir.join("friction.md")).unwrap();
    assert_eq!(report.trim(), stdout.trim());
    // Two seeds under two laws: four runs.
    let csv = std::fs::read_to_string(dir.join("friction-runs.csv")).unwrap();
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(csv.lines().filter(|l| l.contains(",per-step,")).count() == 2, "{csv}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_factorising_solver_gets_its_time_broken_down() {
    let out = Command::new(env!("CARGO_BIN_EXE_dc-study"))
        .args(["solvers", "nncg:1.2/down,ipm,ipm:nd+warm", "--n", "30", "--seeds", "40..41", "--steps", "100"])
        .args(["--friction", "per-step", "--threads", "1"])
        .output()
        .expect("run dc-study");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = stdout.split("## Where a factorising solver's time goes").nth(1).expect("the breakdown");
    // The sweeps factorise nothing: only the interior points have a row.
    assert!(table.contains("| ipm | ") && table.contains("| ipm:nd+warm | ") && !table.contains("| nncg"), "{table}");
}
