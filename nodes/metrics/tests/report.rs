//! The report folder from synthetic statistics: files exist, PNGs are PNGs, the summary holds the
//! known numbers, and an empty or partial run says what is missing instead of failing.

use metrics::{report, Aggregate, StepRecord};
use msgs::{name16, SolveStatsHeader, StepHeader};

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
    let mut a = Aggregate::new();
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
    let w = report::write(&Aggregate::new(), &dir, "empty", &missing).unwrap();
    assert!(w.summaries.is_empty());
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains("No solver statistics arrived"));
    assert!(html.contains("no run end"));
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(md.contains("Missing data (partial run)"));
}
