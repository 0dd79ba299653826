//! Bring your own model: a Python process served through `external:NAME` is judged by `dc eval`
//! under its user's name, on the same states as the Rust models (real processes: dc, the
//! simulator, the metrics node, the launcher's zenoh router and the server). Its sweeps equal
//! builtin's when it returns builtin's values; a late answer falls back, counted; a server that
//! fails is reported by name. Skipped, saying why, without python3 and the PyPI packages
//! (`python/requirements.txt`), except under `DC_REQUIRE_ALL=1` (CI).

use deep_contact::{bin, have_python, repo_root, report_columns, scratch_dir, text};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// One row of `steps.csv`: (model, simulation, step) -> (sweeps, fallback).
fn steps(report: &Path) -> BTreeMap<(String, u32, u32), (u32, bool)> {
    report_columns(report, &["model", "simulation", "step", "sweeps", "fallback"])
        .into_iter()
        .map(|f| {
            ((f[0].clone(), f[1].parse().unwrap(), f[2].parse().unwrap()), (f[3].parse().unwrap(), f[4] == "true"))
        })
        .collect()
}

/// `dc eval` of `models` served by `serve`, from a scratch folder (paths are the repository's,
/// absolute): two evaluation seeds of 40 steps, 30 balls.
fn eval(test: &str, models: &str, serve: &[String], sim_args: &[&str]) -> (PathBuf, Output) {
    let dir = scratch_dir(test);
    let report = dir.join("report");
    let mut command = Command::new(bin("dc"));
    command.current_dir(&dir).args(["eval", "--models", models, "--seeds", "0..2", "--steps", "40", "--n", "30"]);
    command.arg("--out").arg(&report);
    for s in serve {
        command.args(["--serve", s]);
    }
    if !sim_args.is_empty() {
        command.arg("--").args(sim_args);
    }
    (report, command.output().expect("run dc"))
}

fn server(script: &str, args: &str) -> String {
    format!("python3 {} {args}", repo_root().join(script).display())
}

#[test]
fn a_python_model_is_judged_under_its_own_name_and_builtins_values_cost_builtins_sweeps() {
    if !have_python("external model", "numpy, cbor2, zenoh, mcap") {
        return;
    }
    // Two servers at once: builtin's values under the name `py`, and the example's fitted
    // correction (the repository's coefficients) under `py-fit`; each answers its own runs.
    let serve = [server("python/serve_example.py", "--builtin"), server("python/serve_example.py", "")];
    let (report, out) = eval("external-builtin", "builtin,external:py,external:py-fit", &serve, &[]);
    assert!(out.status.success(), "{}", text(&out));
    let rows = steps(&report);
    let of = |model: &str| -> Vec<(u32, u32, u32, bool)> {
        rows.iter()
            .filter(|((m, ..), _)| m == model)
            .map(|((_, sim, step), (sw, fb))| (*sim, *step, *sw, *fb))
            .collect()
    };
    let (builtin, py, fit) = (of("builtin"), of("py"), of("py-fit"));
    assert_eq!(builtin.len(), 80, "two seeds of 40 steps: {}", text(&out));
    assert_eq!(py.len(), 80, "the row carries the user's name: {}", text(&out));
    assert_eq!(fit.len(), 80, "{}", text(&out));
    assert!(py.iter().chain(&fit).all(|r| !r.3), "a server in lockstep is never late: {}", text(&out));
    // Builtin's values cost builtin's sweeps, step for step (same trajectory, same starts).
    let sweeps = |rows: &[(u32, u32, u32, bool)]| rows.iter().map(|r| r.2).collect::<Vec<_>>();
    assert_eq!(sweeps(&py), sweeps(&builtin));
    assert!(sweeps(&fit).iter().sum::<u32>() > 0);
    let summary = std::fs::read_to_string(report.join("summary.csv")).unwrap();
    assert!(
        summary.lines().any(|l| l.starts_with("py,")) && summary.lines().any(|l| l.starts_with("py-fit,")),
        "{summary}"
    );
}

#[test]
fn a_late_answer_falls_back_to_builtin_and_is_counted() {
    if !have_python("external model", "numpy, cbor2, zenoh") {
        return;
    }
    // Every 10th step answered 1.5 s late against a 1 s deadline: those steps, and only
    // those, fall back.
    let serve = [server("tests/python/external_server.py", "--late-every 10 --late-by 1.5")];
    let (report, out) = eval("external-late", "external:late", &serve, &["--deadline", "1s"]);
    assert!(out.status.success(), "{}", text(&out));
    let rows = steps(&report);
    let fell_back: Vec<(u32, u32)> =
        rows.iter().filter(|(_, (_, fb))| *fb).map(|((_, sim, step), _)| (*sim, *step)).collect();
    let late: Vec<(u32, u32)> = (0..2).flat_map(|sim| (0..40).step_by(10).map(move |step| (sim, step))).collect();
    assert_eq!(fell_back, late, "{}", text(&out));
    let summary = std::fs::read_to_string(report.join("summary.csv")).unwrap();
    let header: Vec<&str> = summary.lines().next().unwrap().split(',').collect();
    let row: Vec<&str> =
        summary.lines().find(|l| l.starts_with("late,")).expect("a row named late").split(',').collect();
    let fallbacks = header.iter().position(|h| *h == "fallbacks").expect("a fallbacks column");
    assert_eq!(row[fallbacks], "8", "{summary}");
}

#[test]
fn a_failing_server_stops_the_evaluation_and_is_named() {
    if !have_python("external model", "numpy, cbor2, zenoh") {
        return;
    }
    let serve = [server("tests/python/external_server.py", "--fail-at-step 5")];
    let (_, out) = eval("external-fails", "builtin,external:flaky", &serve, &[]);
    assert!(!out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("node `flaky`") && stderr.contains("fails at step 5"), "{}", text(&out));
    assert!(!stderr.contains("Traceback"), "one line, no traceback: {stderr}");
}

#[test]
fn external_models_and_their_servers_must_pair_up() {
    let dc = |args: &[&str]| Command::new(bin("dc")).args(args).output().unwrap();
    let out = dc(&["eval", "--models", "builtin,external:py", "--seeds", "0..1", "--dry-run"]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("1 external models (py) and 0 --serve commands"),
        "{}",
        text(&out)
    );
    let out = dc(&["eval", "--models", "external:Py", "--seeds", "0..1", "--serve", "true", "--dry-run"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("1 to 16 of a-z"), "{}", text(&out));
    let out = dc(&["eval", "--models", "external:py", "--seeds", "0..1", "--serve", "python3 'x", "--dry-run"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("unbalanced quotes"), "{}", text(&out));
}
