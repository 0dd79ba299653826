//! The report folder from synthetic statistics: files exist, PNGs are PNGs, the summary holds the
//! known numbers, and an empty or partial run says what is missing instead of failing.

use metrics::{report, Aggregate, StepRecord};
use msgs::{name16, SolveStatsHeader, StepHeader};

/// An aggregate with the thesis's phases (0-99, 100-149, 150-end) whatever the simulations'
/// length: these tests' runs are shorter than 250 steps.
fn thesis_phases() -> Aggregate {
    let mut a = Aggregate::new();
    a.phase_boundaries = Some(metrics::phases::DEFAULT_PHASE_BOUNDARIES.to_vec());
    a
}

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("dc-metrics-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn stats(model: &str, simulation: u32, step: u32, sweeps: u32) -> StepRecord {
    let h = SolveStatsHeader {
        step: StepHeader { run_id: 9, simulation, step },
        model: name16(model),
        used_model: name16(model),
        contacts: 10 + step,
        persisting_contacts: step,
        sweeps,
        converged: 1,
        warm_error_normal_mse: 0.5 / (step + 1) as f32,
        warm_error_tangent_mse: 0.1,
        solve_us: 3.0 * sweeps as f32,
        step_us: 50.0,
        ..Default::default()
    };
    let residuals: Vec<f32> = (0..sweeps).map(|i| 0.5f32.powi(i as i32)).collect();
    StepRecord::from_msg(&h, &residuals)
}

fn is_png(path: &std::path::Path) -> bool {
    let bytes = std::fs::read(path).unwrap();
    bytes.len() > 1000 && bytes.starts_with(b"\x89PNG\r\n\x1a\n")
}

#[test]
fn report_folder_has_csv_summary_plots_and_html() {
    let mut a = thesis_phases();
    for sim in 0..3 {
        for step in 0..20 {
            a.add(stats("builtin", sim, step, 5));
            a.add(stats("none", sim, step, 15));
        }
    }
    let dir = scratch("full");
    let w = report::write(&a, &dir, "test report", &[]).unwrap();
    let none = w.summaries.iter().find(|s| s.model == "none").unwrap();
    assert_eq!(none.all.total_sweeps, 3 * 20 * 15);
    assert_eq!(none.ratio_to_builtin, Some(3.0));
    for f in [
        "steps.csv",
        "summary.csv",
        "summary.md",
        "report.html",
        "sweeps_per_step.png",
        "convergence.png",
        "converged_within.png",
        "warm_error_normal.png",
        "solve_time_per_step.png",
        "step_time_per_step.png",
        "contacts_per_step.png",
    ] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    for f in w.files.iter().filter(|f| f.extension().is_some_and(|e| e == "png")) {
        assert!(is_png(f), "{} is not a PNG", f.display());
    }
    let steps = std::fs::read_to_string(dir.join("steps.csv")).unwrap();
    assert_eq!(steps.lines().count(), 1 + 2 * 3 * 20);
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(md.contains("| none | 3 | 60 | 900 | 3.000x |"), "{md}");
    // The table lists builtin before none? No: the thesis order puts none first.
    assert!(md.find("| none").unwrap() < md.find("| builtin").unwrap());
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains("<img src=\"sweeps_per_step.png\""));
}

#[test]
fn empty_run_writes_a_report_that_says_so() {
    let dir = scratch("empty");
    let missing = vec!["run 3 (model unet): no run end (the simulator stopped or died before finishing)".to_string()];
    let w = report::write(&thesis_phases(), &dir, "empty", &missing).unwrap();
    assert!(w.summaries.is_empty());
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains("No solver statistics arrived"));
    assert!(html.contains("no run end"));
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(md.contains("## Missing data"));
}

/// A report rebuilt from an earlier report's `steps.csv` (`dc-metrics --from-steps`) has the same
/// tables: every statistic but the per-sweep residuals survives the file.
#[test]
fn a_report_rebuilt_from_its_steps_csv_has_the_same_tables() {
    let mut a = thesis_phases();
    for sim in 0..2 {
        for step in 0..160 {
            for (model, sweeps) in [("builtin", 20 + step % 7), ("blend:0.5", 12 + step % 5), ("gnn", 21 + step % 3)] {
                let mut r = stats(model, sim, step, sweeps);
                r.stats.builtin_sweeps = 20 + step % 7;
                r.stats.builtin_measured = true;
                a.add(r);
            }
        }
    }
    let first = scratch("from-steps-a");
    let written = report::write(&a, &first, "first", &[]).unwrap();
    let records = report::read_steps(&first.join("steps.csv")).unwrap();
    assert_eq!(records.len(), 3 * 2 * 160);
    assert!(records.iter().all(|r| r.residuals.is_empty()), "residuals are not in the file");
    let mut b = thesis_phases();
    for r in records {
        b.add(r);
    }
    assert_eq!(report::summary_markdown(&b.summaries()), report::summary_markdown(&a.summaries()));
    assert_eq!(b.phase_rows(), written.phases);
    assert_eq!(b.accuracy(), written.accuracy);

    // The binary does the same and says what the file cannot give back.
    let second = scratch("from-steps-b");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dc-metrics"))
        .arg("--from-steps")
        .arg(first.join("steps.csv"))
        .args(["--phases", "100,150"])
        .arg("--out")
        .arg(&second)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains(&report::accuracy_markdown(&written.accuracy)), "{stdout}");
    let summary = std::fs::read_to_string(second.join("summary.md")).unwrap();
    assert!(summary.contains("per-sweep residuals are not kept in steps.csv"), "{summary}");
    assert_eq!(std::fs::read(second.join("steps.csv")).unwrap(), std::fs::read(first.join("steps.csv")).unwrap());

    // A damaged file: the error names it and the record.
    let bad = first.join("bad.csv");
    let text = std::fs::read_to_string(first.join("steps.csv")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[5] = "1,2,three";
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let e = report::read_steps(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.csv") && e.contains("record 5"), "{e}");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dc-metrics"))
        .arg("--from-steps")
        .arg(&bad)
        .arg("--out")
        .arg(scratch("from-steps-c"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bad.csv"), "{}", String::from_utf8_lossy(&out.stderr));
}

/// `--from-steps` applies the live path's checks: an impossible row (more persisting contacts
/// than contacts, an infinite time), a duplicated step and an empty file are errors naming the
/// file and the record, never a report with wrong totals.
#[test]
fn a_steps_file_with_impossible_or_repeated_rows_is_refused_naming_the_record() {
    let mut a = thesis_phases();
    for step in 0..20 {
        a.add(stats("builtin", 0, step, 10 + step % 3));
    }
    let dir = scratch("from-steps-checks");
    report::write(&a, &dir, "checks", &[]).unwrap();
    let text = std::fs::read_to_string(dir.join("steps.csv")).unwrap();
    let (header, rows) = text.split_once('\n').unwrap();
    let rows: Vec<&str> = rows.lines().collect();
    let column = |name: &str| header.split(',').position(|c| c == name).unwrap();
    let edit = |row: &str, name: &str, value: &str| {
        let mut cells: Vec<String> = row.split(',').map(String::from).collect();
        cells[column(name)] = value.to_string();
        cells.join(",")
    };
    let run = |name: &str, body: String| {
        let file = dir.join(name);
        std::fs::write(&file, body).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_dc-metrics"))
            .arg("--from-steps")
            .arg(&file)
            .arg("--out")
            .arg(dir.join(format!("{name}-report")))
            .output()
            .unwrap();
        assert!(!out.status.success(), "{name} was accepted");
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let with_row = |i: usize, row: String| {
        let mut r: Vec<String> = rows.iter().map(|s| s.to_string()).collect();
        r[i] = row;
        format!("{header}\n{}\n", r.join("\n"))
    };
    let e = run("persisting.csv", with_row(3, edit(rows[3], "persisting_contacts", "999")));
    assert!(e.contains("persisting.csv") && e.contains("record 4") && e.contains("persisting of"), "{e}");
    let e = run("inf.csv", with_row(7, edit(rows[7], "solve_us", "inf")));
    assert!(e.contains("record 8") && e.contains("solve_us"), "{e}");
    let e = run("twice.csv", format!("{header}\n{}\n{}\n", rows.join("\n"), rows[2]));
    assert!(e.contains("record 21") && e.contains("arrived twice"), "{e}");
    let e = run("empty.csv", format!("{header}\n"));
    assert!(e.contains("empty.csv") && e.contains("no steps"), "{e}");
}
