//! Where the sweeps go, from synthetic statistics with known numbers: per-phase totals, shares and
//! builtin-relative sweeps, custom phase boundaries, the sweeps histogram, the accuracy -> sweeps
//! table, and the report's phase / accuracy files and plots.

use metrics::phases::{BlendPlace, StepRange};
use metrics::report::{self, AccuracyTable, PhaseTable, ACCURACY_COLUMNS, PHASE_COLUMNS};
use metrics::{Aggregate, StepRecord};
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

/// A step's statistics; `converged` false means the step hit the cap.
fn step(
    model: &str,
    simulation: u32,
    step: u32,
    sweeps: u32,
    converged: bool,
    error: f32,
    persisting: u32,
) -> StepRecord {
    let h = SolveStatsHeader {
        step: StepHeader { run_id: 7, simulation, step },
        model: name16(model),
        used_model: name16(model),
        contacts: 20,
        persisting_contacts: persisting,
        sweeps,
        converged: converged as u32,
        warm_error_normal_mse: error,
        warm_error_tangent_mse: error / 2.0,
        solve_us: 2.0 * sweeps as f32,
        step_us: 40.0,
        ..Default::default()
    };
    StepRecord::from_msg(&h, &[])
}

/// builtin: per simulation (200 steps) sweeps 2 (steps 0-99), 4 (100-149), 10 (150-199): 900 per
/// simulation, 1800 over two. `half`: exactly half of builtin's sweeps at every step. `capped`:
/// builtin's sweeps, but late steps 190-199 hit the cap (1000 sweeps, not converged).
/// Warm-start errors: builtin 0.2, half 0.05 on steps with persisting contacts; late steps
/// 195-199 have no persisting contacts and a huge error (left out of the accuracy table).
fn synthetic() -> Aggregate {
    let mut a = thesis_phases();
    let sweeps_at = |s: u32| match s {
        0..=99 => 2,
        100..=149 => 4,
        _ => 10,
    };
    for sim in 0..2 {
        for s in 0..200 {
            let persisting = if s >= 195 { 0 } else { 10 };
            let err = |e: f32| if persisting == 0 { 1e6 } else { e };
            a.add(step("builtin", sim, s, sweeps_at(s), true, err(0.2), persisting));
            a.add(step("half", sim, s, sweeps_at(s) / 2, true, err(0.05), persisting));
            let cap = s >= 190;
            a.add(step("capped", sim, s, if cap { 1000 } else { sweeps_at(s) }, !cap, err(0.4), persisting));
        }
    }
    a
}

#[test]
fn phase_totals_add_up_and_compare_with_builtins_whole_run() {
    let a = synthetic();
    let rows = a.phase_rows();
    assert_eq!(rows.len(), 3 * 3);
    // Models in the report's order: the contract's (builtin) first, then by name.
    let order: Vec<&str> = rows.iter().step_by(3).map(|r| r.model.as_str()).collect();
    assert_eq!(order, ["builtin", "capped", "half"]);
    let labels: Vec<String> = rows[..3].iter().map(|r| r.phase.label()).collect();
    assert_eq!(labels, ["0-99", "100-149", "150-end"]);

    let builtin: Vec<_> = rows.iter().filter(|r| r.model == "builtin").collect();
    assert_eq!(builtin.iter().map(|r| r.steps).collect::<Vec<_>>(), [200, 100, 100]);
    assert_eq!(builtin.iter().map(|r| r.total_sweeps).collect::<Vec<_>>(), [400, 400, 1000]);
    assert_eq!(builtin.iter().map(|r| r.median_sweeps).collect::<Vec<_>>(), [2.0, 4.0, 10.0]);
    for r in &rows {
        let model_total: u64 = a.records(&r.model).map(|s| s.sweeps as u64).sum();
        assert_eq!(r.model_total_sweeps, model_total);
        // Exactly the phase's sweeps over builtin's total over all phases.
        assert_eq!(r.ratio_to_builtin_total, Some(r.total_sweeps as f64 / 1800.0), "{r:?}");
    }
    for model in ["builtin", "half", "capped"] {
        let mine: Vec<_> = rows.iter().filter(|r| r.model == model).collect();
        let total: u64 = a.records(model).map(|s| s.sweeps as u64).sum();
        assert_eq!(mine.iter().map(|r| r.total_sweeps).sum::<u64>(), total, "{model}: phases add up");
        assert_eq!(mine.iter().map(|r| r.steps).sum::<usize>(), 400);
        let shares: f64 = mine.iter().map(|r| r.share_of_model).sum();
        assert!((shares - 1.0).abs() < 1e-12, "{model}: shares sum to {shares}");
    }
    let half_late = rows.iter().find(|r| r.model == "half" && r.phase.first == 150).unwrap();
    assert_eq!(half_late.total_sweeps, 500);
    assert_eq!(half_late.ratio_to_builtin_total, Some(500.0 / 1800.0));
    assert_eq!(half_late.share_of_model, 500.0 / 900.0);

    // Capped: 2 x 10 late steps at 1000 sweeps.
    let capped: Vec<_> = rows.iter().filter(|r| r.model == "capped").collect();
    let capped_total = 2 * (200 + 200 + 40 * 10 + 10 * 1000);
    assert_eq!(capped[0].model_total_sweeps, capped_total);
    assert_eq!(capped.iter().map(|r| r.cap_hits).collect::<Vec<_>>(), [0, 0, 20]);
    assert_eq!(capped[2].cap_sweeps, 20_000);
    assert_eq!(capped[2].cap_sweeps_share, 20_000.0 / capped_total as f64);
    assert_eq!(capped[0].cap_sweeps_share, 0.0);
    assert_eq!(builtin[2].median_warm_error_normal_mse, 0.2f32 as f64);

    // The table shows those numbers.
    let table = PhaseTable::new(&rows);
    assert_eq!(
        table.rows[2].to_vec(),
        ["builtin", "150-end", "100", "1000", "55.6%", "0.556x", "-", "0", "0.0%", "10.0", "0.2000"]
    );
    assert_eq!(table.rows[5][7..9], ["20".to_string(), format!("{:.1}%", 2e6 / capped_total as f64)]);
}

#[test]
fn same_states_per_phase_pair_each_step_with_builtin_on_it() {
    let mut a = thesis_phases();
    for s in 0..200 {
        // Early steps: 3 sweeps where builtin needs 4; late ones: 9 where it needs 6.
        let (own, builtin) = if s < 150 { (3, 4) } else { (9, 6) };
        let mut r = step("m", 0, s, own, true, 0.1, 5);
        (r.stats.builtin_sweeps, r.stats.builtin_measured) = (builtin, true);
        a.add(r);
    }
    let rows = a.phase_rows();
    let ratios: Vec<Option<f64>> = rows.iter().map(|r| r.same_states_ratio).collect();
    assert_eq!(ratios, [Some(0.75), Some(0.75), Some(1.5)]);
    assert_eq!(PhaseTable::new(&rows).rows[2][6], "1.500x");
    // One late step without builtin measured: that phase has no figure, the others keep theirs.
    a.add(step("m", 0, 200, 9, true, 0.1, 5));
    let ratios: Vec<Option<f64>> = a.phase_rows().iter().map(|r| r.same_states_ratio).collect();
    assert_eq!(ratios, [Some(0.75), Some(0.75), None]);
}

#[test]
fn without_builtin_there_is_no_builtin_column() {
    let mut a = thesis_phases();
    for s in 0..10 {
        a.add(step("none", 0, s, 3, true, 0.1, 5));
    }
    let rows = a.phase_rows();
    assert!(rows.iter().all(|r| r.ratio_to_builtin_total.is_none()));
    assert_eq!(PhaseTable::new(&rows).rows[0][5], "-");
    assert!(a.accuracy().iter().all(|r| r.sweeps_vs_builtin.is_none() && r.error_vs_builtin.is_none()));
    // Steps 0-9 only: the later phases are empty, with zero sweeps and no medians.
    assert_eq!(rows[1].steps, 0);
    assert_eq!(rows[1].total_sweeps, 0);
    assert!(rows[1].median_sweeps.is_nan());
    assert_eq!(PhaseTable::new(&rows).rows[1][9], "-");
}

#[test]
fn custom_phase_boundaries() {
    let mut a = synthetic();
    a.phase_boundaries = Some(vec![50]);
    let rows = a.phase_rows();
    let builtin: Vec<_> = rows.iter().filter(|r| r.model == "builtin").collect();
    assert_eq!(builtin.iter().map(|r| r.phase.label()).collect::<Vec<_>>(), ["0-49", "50-end"]);
    assert_eq!(builtin.iter().map(|r| r.total_sweeps).collect::<Vec<_>>(), [200, 1600]);

    a.phase_boundaries = Some(vec![10, 20, 190]);
    let rows = a.phase_rows();
    let builtin: Vec<_> = rows.iter().filter(|r| r.model == "builtin").collect();
    assert_eq!(builtin.iter().map(|r| r.phase.label()).collect::<Vec<_>>(), ["0-9", "10-19", "20-189", "190-end"]);
    assert_eq!(builtin.iter().map(|r| r.steps).collect::<Vec<_>>(), [20, 20, 340, 20]);
    assert_eq!(builtin.iter().map(|r| r.total_sweeps).sum::<u64>(), 1800);
    // The late phase of the accuracy table is the last range.
    assert_eq!(a.accuracy()[0].late_phase, StepRange { first: 190, end: None });
    let capped = a.accuracy().into_iter().find(|r| r.model == "capped").unwrap();
    assert_eq!(capped.late_sweeps, 20_000);

    a.phase_boundaries = Some(Vec::new());
    assert_eq!(a.phase_rows().iter().filter(|r| r.model == "half").count(), 1);
    assert_eq!(a.phase_rows()[0].phase.label(), "0-end");
}

#[test]
fn histogram_fractions_sum_to_one_per_model_and_phase() {
    let a = synthetic();
    let h = a.sweeps_histograms();
    let labels: Vec<String> = h.bins.iter().map(|b| b.label()).collect();
    assert_eq!(labels.first().unwrap(), "1");
    assert_eq!(labels.last().unwrap(), "512-1023");
    assert_eq!(h.histograms.len(), 3 * 3);
    for hist in &h.histograms {
        let sum: f64 = hist.fractions.iter().sum();
        assert!((sum - 1.0).abs() < 1e-12, "{} {}: {sum}", hist.model, hist.phase.label());
        assert_eq!(hist.counts.iter().sum::<usize>(), hist.steps);
    }
    let bin = |label: &str| labels.iter().position(|l| l == label).unwrap();
    let builtin_late = &h.histograms[2];
    assert_eq!((builtin_late.model.as_str(), builtin_late.phase.first), ("builtin", 150));
    assert_eq!(builtin_late.counts[bin("8-15")], 100);
    let capped_late = h.histograms.iter().find(|x| x.model == "capped" && x.phase.first == 150).unwrap();
    assert_eq!(capped_late.fractions[bin("512-1023")], 0.2);
    assert_eq!(capped_late.fractions[bin("8-15")], 0.8);
}

#[test]
fn accuracy_table_puts_builtin_at_one_and_half_the_sweeps_at_half() {
    let a = synthetic();
    let acc = a.accuracy();
    let row = |m: &str| acc.iter().find(|r| r.model == m).unwrap().clone();
    let builtin = row("builtin");
    assert_eq!((builtin.error_vs_builtin, builtin.sweeps_vs_builtin), (Some(1.0), Some(1.0)));
    assert_eq!(builtin.late_phase.label(), "150-end");
    // Late steps with persisting contacts: 150-194 in two simulations.
    assert_eq!(builtin.late_steps, 90);
    assert_eq!(builtin.median_warm_error_normal_mse, 0.2f32 as f64, "steps without persisting contacts left out");
    assert_eq!(builtin.total_sweeps, 1800);
    let half = row("half");
    assert_eq!(half.sweeps_vs_builtin, Some(0.5));
    assert_eq!(half.late_sweeps_vs_builtin, Some(0.5));
    assert_eq!(half.error_vs_builtin, Some(0.05f32 as f64 / 0.2f32 as f64));
    let table = AccuracyTable::new(&acc);
    let cells = |m: &str| table.rows.iter().find(|r| r[0] == m).unwrap().to_vec();
    assert_eq!(
        cells("builtin"),
        ["builtin", "90", "0.2000", "1.000x", "0.2000", "1800", "1.000x", "1.000x", "-", "-", "-"],
        "no same states measured, no blend to place on"
    );
    assert_eq!(cells("half")[3], "0.250x");
    assert_eq!(cells("half")[6], "0.500x");
    let md = table.to_markdown();
    assert_eq!(md.lines().next().unwrap(), format!("| {} |", ACCURACY_COLUMNS.join(" | ")));
    assert_eq!(md.lines().nth(1).unwrap(), "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let html = table.to_html();
    assert!(html.contains("<tr><td>half</td><td>90</td><td>0.0500</td><td>0.250x</td>"), "{html}");
    assert_eq!(html.matches("<tr>").count(), 1 + 3);
}

/// A step that also measured builtin's sweeps on its own problem (`--shadow-builtin`).
fn shadowed(model: &str, simulation: u32, k: u32, sweeps: u32, builtin_sweeps: u32, error: f32) -> StepRecord {
    let h = SolveStatsHeader {
        step: StepHeader { run_id: 7, simulation, step: k },
        model: name16(model),
        used_model: name16(model),
        contacts: 20,
        persisting_contacts: 10,
        sweeps,
        converged: 1,
        warm_error_normal_mse: error,
        builtin_sweeps,
        builtin_measured: 1,
        ..Default::default()
    };
    StepRecord::from_msg(&h, &[])
}

/// builtin needs 100 sweeps a step at late error 0.4; blend:0.5 78 at 0.1; `cheap` (error 0.1,
/// a quarter of builtin's, like blend:0.5) needs 96 on its own states where builtin needs 100 —
/// its sweeps are what blend:0.09 needs; `right` needs 117 where builtin needs 150 (0.78x): on
/// the curve; `worse` needs more than builtin.
#[test]
fn accuracy_places_models_on_the_blend_curve_and_says_why() {
    let mut a = thesis_phases();
    for sim in 0..2 {
        for k in 0..200 {
            a.add(shadowed("builtin", sim, k, 100, 100, 0.4));
            a.add(shadowed("blend:0.5", sim, k, 78, 100, 0.1));
            a.add(shadowed("cheap", sim, k, 96, 100, 0.1));
            // Its run meets harder states (builtin needs 150 there): whole runs would say 1.17x.
            a.add(shadowed("right", sim, k, 117, 150, 0.1));
            a.add(shadowed("worse", sim, k, 110, 100, 0.5));
        }
    }
    let acc = a.accuracy();
    let row = |m: &str| acc.iter().find(|r| r.model == m).unwrap().clone();
    assert!(acc.iter().all(|r| r.placed_on_same_states));
    let cheap = row("cheap");
    assert_eq!(cheap.same_states_vs_builtin, Some(0.96));
    assert!((cheap.blend_by_error.unwrap().fraction().unwrap() - 0.5).abs() < 1e-12, "{cheap:?}");
    assert!((cheap.blend_by_sweeps.unwrap().fraction().unwrap() - 0.04 / 0.22 * 0.5).abs() < 1e-12, "{cheap:?}");
    let right = row("right");
    assert!((right.same_states_vs_builtin.unwrap() - 0.78).abs() < 1e-12);
    assert!((right.blend_by_sweeps.unwrap().fraction().unwrap() - 0.5).abs() < 1e-12, "same states, not whole runs");
    assert_eq!(row("builtin").blend_by_sweeps, Some(BlendPlace::At(0.0)));
    assert_eq!(row("worse").blend_by_sweeps, Some(BlendPlace::BelowBuiltin));

    let notes = metrics::phases::placement_notes(&acc);
    assert_eq!(notes.len(), 4, "the reference line, then every model but builtin and the blend: {notes:?}");
    assert_eq!(
        notes[0],
        "Of builtin's sweeps on the same states, 0.85x needs blend F 0.34, 0.5x needs blend F > 0.50."
    );
    let cheap_note = "`cheap`: sweeps on the same states 0.960x builtin's (blend F 0.09), late-phase error 0.250x \
                      builtin's (blend F 0.50) — its sweeps buy less than its accuracy suggests";
    assert!(notes[1].starts_with(cheap_note), "{}", notes[1]);
    assert!(notes[2].contains("on the curve"), "{}", notes[2]);
    assert!(notes[3].contains("(blend F < 0)") && notes[3].contains("no gain over builtin"), "{}", notes[3]);

    let table = AccuracyTable::new(&acc);
    let cells = table.rows.iter().find(|r| r[0] == "cheap").unwrap();
    assert_eq!(cells[8..], ["0.960x".to_string(), "0.50".into(), "0.09".into()]);
    let md = report::accuracy_markdown(&acc);
    assert!(md.contains(&format!("- {}", notes[1])), "{md}");

    // One model without same-states measurements: every model is placed on whole runs.
    a.add(step("unshadowed", 0, 0, 50, true, 0.4, 10));
    let acc = a.accuracy();
    assert!(acc.iter().all(|r| !r.placed_on_same_states));
    let right = acc.iter().find(|r| r.model == "right").unwrap();
    assert_eq!(right.placement_sweeps(), right.sweeps_vs_builtin);
}

#[test]
fn scatter_points_are_positive_and_subsampled_deterministically() {
    let mut a = thesis_phases();
    for sim in 0..10 {
        for s in 0..1000 {
            // Every 10th step has no error (skipped on a log axis), every 7th no sweeps.
            let err = if s % 10 == 0 { 0.0 } else { s as f32 };
            a.add(step("m", sim, s, if s % 7 == 0 { 0 } else { 5 }, true, err, 3));
        }
    }
    let p = a.sweeps_vs_warm_error("m", 3000);
    assert!(p.len() <= 3000 && p.len() > 2000, "{}", p.len());
    assert!(p.iter().all(|&(e, s)| e > 0.0 && s > 0.0));
    assert_eq!(p, a.sweeps_vs_warm_error("m", 3000));
    assert_eq!(a.sweeps_vs_warm_error("m", 1_000_000).len(), 10 * (1000 - 100 - 143 + 15));
    assert!(a.sweeps_vs_warm_error("nobody", 10).is_empty());
}

#[test]
fn phase_table_markdown_and_html_show_the_same_cells() {
    let table = PhaseTable::new(&synthetic().phase_rows());
    let md = table.to_markdown();
    let lines: Vec<&str> = md.lines().collect();
    assert_eq!(lines[0], format!("| {} |", PHASE_COLUMNS.join(" | ")));
    assert_eq!(lines[1], "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    assert_eq!(lines.len(), 2 + 9);
    let html = table.to_html();
    for row in &table.rows {
        assert!(md.contains(&format!("| {} |", row.join(" | "))));
        let cells: String = row.iter().map(|c| format!("<td>{c}</td>")).collect();
        assert!(html.contains(&format!("<tr>{cells}</tr>")), "{cells}");
    }
}

fn is_png(path: &std::path::Path) -> bool {
    let bytes = std::fs::read(path).unwrap();
    bytes.len() > 1000 && bytes.starts_with(b"\x89PNG\r\n\x1a\n")
}

/// A tiny deterministic generator (xorshift) for realistic-looking synthetic runs.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Oracle ablations and the contract's models over 4 simulations of 250 steps: sweeps grow with
/// the warm-start error and in the late (jammed) phase; some late steps hit the cap.
fn ablations() -> Aggregate {
    let models: [(&str, f64); 12] = [
        ("none", 1.0),
        ("builtin", 0.17),
        ("copy", 0.0),
        ("blend:0.5", 0.17 * 0.25),
        ("blend:0.75", 0.17 * 0.0625),
        ("blend:0.9", 0.17 * 0.01),
        ("noise:0.5", 0.05),
        ("copy-persisting", 0.02),
        ("copy-new", 0.15),
        ("smooth-error", 0.12),
        ("unet", 0.11),
        ("grid", 0.18),
    ];
    let mut a = thesis_phases();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for (model, err) in models {
        for sim in 0..4 {
            for s in 0..250u32 {
                let late = s >= 150;
                let base = if s < 100 {
                    20.0
                } else if late {
                    300.0
                } else {
                    120.0
                };
                let e = err * (0.3 + 1.4 * rng.next());
                let sweeps = (base * (0.15 + 3.0 * e.sqrt()) * (0.5 + rng.next())).round().clamp(1.0, 1000.0) as u32;
                let sweeps = if late && rng.next() < 0.1 * err.sqrt() { 1000 } else { sweeps };
                let mut r = step(model, sim, s, sweeps, sweeps < 1000, e as f32, 10);
                // Residuals decaying geometrically from the warm start's error to the tolerance.
                let start = e.sqrt().max(1e-3);
                let rate = (1e-4 / start).powf(1.0 / sweeps as f64);
                r.residuals = (1..=sweeps).map(|i| (start * rate.powi(i as i32)) as f32).collect();
                a.add(r);
            }
        }
    }
    a
}

#[test]
fn report_has_phase_and_accuracy_tables_and_plots() {
    let a = ablations();
    let dir = scratch("phases");
    let w = report::write(&a, &dir, "ablations", &[]).unwrap();
    for f in [
        "phases.csv",
        "accuracy.csv",
        "sweeps_histogram.csv",
        "sweeps_histogram.png",
        "sweeps_vs_warm_error.png",
        "accuracy_vs_sweeps.png",
    ] {
        assert!(dir.join(f).is_file(), "{f} missing");
        assert!(w.files.contains(&dir.join(f)), "{f} not listed");
    }
    for f in w.files.iter().filter(|f| f.extension().is_some_and(|e| e == "png")) {
        assert!(is_png(f), "{} is not a PNG", f.display());
    }
    assert_eq!(w.phases.len(), 12 * 3);
    assert_eq!(w.accuracy.len(), 12);
    let phases_csv = std::fs::read_to_string(dir.join("phases.csv")).unwrap();
    assert_eq!(phases_csv.lines().count(), 1 + 12 * 3);
    assert!(phases_csv.starts_with("model,phase,first_step,last_step,steps,total_sweeps,"));
    assert!(phases_csv.contains("\nbuiltin,150-end,150,,400,"), "{phases_csv}");
    let md = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    let phase_md = PhaseTable::new(&w.phases).to_markdown();
    let accuracy_md = AccuracyTable::new(&w.accuracy).to_markdown();
    assert!(md.contains("## Sweeps per phase") && md.contains(&phase_md), "{md}");
    assert!(md.contains("## Accuracy -> sweeps (late phase: steps 150-end)") && md.contains(&accuracy_md));
    assert!(md.contains("| builtin | 400 | "), "{md}");
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains(&PhaseTable::new(&w.phases).to_html()));
    assert!(html.contains(&AccuracyTable::new(&w.accuracy).to_html()));
    for img in ["sweeps_histogram.png", "accuracy_vs_sweeps.png", "sweeps_vs_warm_error.png"] {
        assert!(html.contains(&format!("<img src=\"{img}\"")), "{img}");
    }
    // The markdown main.rs prints.
    assert!(report::phases_markdown(&w.phases).contains(&phase_md));
    assert!(report::accuracy_markdown(&w.accuracy).contains(&accuracy_md));
}

/// The 16 models of the README's ablation run, at their measured (late error, total sweeps)
/// relative to builtin: many labels crowd around (1, 1), some must move left of their marker
/// (a layout that once made the label placement panic and lost a 7-minute report).
#[test]
fn a_crowded_accuracy_chart_renders() {
    let measured = [
        ("none", 13.6, 1.302),
        ("builtin", 1.0, 1.0),
        ("copy", 0.0, 0.011),
        ("copy-persisting", 0.039, 0.270),
        ("copy-new", 1.17, 1.021),
        ("blend:0.5", 0.284, 0.790),
        ("blend:0.75", 0.069, 0.561),
        ("blend:0.9", 0.0088, 0.360),
        ("noise:0.35", 0.173, 0.449),
        ("noise:1", 1.37, 0.710),
        ("smooth-error", 0.224, 0.631),
        ("rough-error", 0.736, 0.943),
        ("extrapolate:0.25", 1.46, 1.044),
        ("extrapolate:0.5", 1.98, 1.080),
        ("extrapolate:1", 2.80, 1.148),
        ("builtin-reappear", 1.16, 1.020),
    ];
    let mut a = thesis_phases();
    for (model, error, sweeps) in measured {
        for k in 0..200 {
            a.add(step(model, 0, k, (400.0 * sweeps) as u32, true, 0.01 * error as f32, 10));
        }
    }
    let dir = scratch("crowded");
    report::write(&a, &dir, "crowded", &[]).unwrap();
    let png = std::fs::read(dir.join("accuracy_vs_sweeps.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"));
}
