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
