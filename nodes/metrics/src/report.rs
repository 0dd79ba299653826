//! The report folder: every step as CSV, the summary as CSV and markdown, PNG plots, and one
//! `report.html` that shows them side by side.

use crate::aggregate::{Aggregate, ModelSummary};
use crate::phases::{AccuracyRow, PhaseRow};
use crate::plot::{chart, Axis, Mark, Panel, Scale, Series};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: {source}")]
    Csv { path: String, source: csv::Error },
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> ReportError + '_ {
    move |source| ReportError::Io { path: path.display().to_string(), source }
}

/// What was written.
#[derive(Debug)]
pub struct Written {
    pub dir: PathBuf,
    pub files: Vec<PathBuf>,
    pub summaries: Vec<ModelSummary>,
    /// Per model and step-range phase: where the sweeps went (`phases.csv`).
    pub phases: Vec<PhaseRow>,
    /// The accuracy -> sweeps table (`accuracy.csv`).
    pub accuracy: Vec<AccuracyRow>,
}

/// Models in a stable, meaningful order: the contract's table order (the thesis's), then others.
fn model_order(a: &Aggregate) -> Vec<String> {
    a.model_order()
}

fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "-".to_string()
    }
}

/// Columns of the summary table (markdown and HTML).
pub const SUMMARY_COLUMNS: [&str; 16] = [
    "model",
    "sims",
    "steps",
    "total sweeps",
    "vs builtin",
    "same states vs builtin",
    "worst sim, same states",
    "median sweeps",
    "falling: median",
    "settled: median",
    "cap hits",
    "fallbacks",
    "persisting",
    "warm err n (median MSE)",
    "median solve us",
    "median step us",
];

/// The summary table as formatted cells, one row per model: what both the markdown table and the
/// HTML page show (one formatting, so they cannot disagree).
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryTable {
    /// One row per model, a cell per [`SUMMARY_COLUMNS`] entry.
    pub rows: Vec<[String; SUMMARY_COLUMNS.len()]>,
}

impl SummaryTable {
    pub fn new(summaries: &[ModelSummary]) -> SummaryTable {
        let rows = summaries
            .iter()
            .map(|m| {
                [
                    m.model.clone(),
                    m.simulations.to_string(),
                    m.all.steps.to_string(),
                    m.all.total_sweeps.to_string(),
                    m.ratio_to_builtin.map(|r| format!("{r:.3}x")).unwrap_or_else(|| "-".into()),
                    m.same_states.map(|p| format!("{:.3}x", p.ratio)).unwrap_or_else(|| "-".into()),
                    m.same_states
                        .map(|p| format!("{:.3}x (sim {})", p.worst_ratio, p.worst_simulation))
                        .unwrap_or_else(|| "-".into()),
                    fmt(m.all.median_sweeps, 1),
                    fmt(m.falling.median_sweeps, 1),
                    fmt(m.settled.median_sweeps, 1),
                    m.all.cap_hits.to_string(),
                    m.all.fallbacks.to_string(),
                    fmt(m.persisting_share * 100.0, 1) + "%",
                    fmt(m.median_warm_error_normal_mse, 4),
                    fmt(m.all.median_solve_us, 1),
                    fmt(m.all.median_step_us, 1),
                ]
            })
            .collect();
        SummaryTable { rows }
    }

    /// A markdown table: the model column left-aligned, the numbers right-aligned.
    pub fn to_markdown(&self) -> String {
        markdown_table(&SUMMARY_COLUMNS, 1, &self.rows)
    }

    /// An HTML `<table>`: a header row, then one row per model (cells escaped).
    pub fn to_html(&self) -> String {
        html_table(&SUMMARY_COLUMNS, &self.rows)
    }
}

/// A markdown table: the first `left` columns left-aligned, the others right-aligned.
fn markdown_table<R: AsRef<[String]>>(columns: &[&str], left: usize, rows: &[R]) -> String {
    let line = |cells: &[&str]| format!("| {} |\n", cells.join(" | "));
    let mut s = line(columns);
    s.push('|');
    s.push_str(&"---|".repeat(left.min(columns.len())));
    s.push_str(&"---:|".repeat(columns.len().saturating_sub(left)));
    s.push('\n');
    for row in rows {
        s.push_str(&line(&row.as_ref().iter().map(String::as_str).collect::<Vec<_>>()));
    }
    s
}

/// An HTML `<table>`: a header row, then a row per row (cells escaped).
fn html_table<R: AsRef<[String]>>(columns: &[&str], rows: &[R]) -> String {
    let mut html = String::from("<table>");
    let mut row = |tag: &str, cells: &mut dyn Iterator<Item = &str>| {
        html.push_str("<tr>");
        for c in cells {
            let _ = write!(html, "<{tag}>{}</{tag}>", escape(c));
        }
        html.push_str("</tr>");
    };
    row("th", &mut columns.iter().copied());
    for r in rows {
        row("td", &mut r.as_ref().iter().map(String::as_str));
    }
    html.push_str("</table>");
    html
}

/// A ratio to builtin as `0.730x`; a small one with three significant digits (`1.23e-4x`).
fn fmt_ratio(r: Option<f64>) -> String {
    match r {
        Some(r) if r.is_finite() && (r == 0.0 || r >= 0.01) => format!("{r:.3}x"),
        Some(r) if r.is_finite() => format!("{r:.2e}x"),
        _ => "-".into(),
    }
}

/// A small quantity (an MSE) with four decimals, or three significant digits below 0.001.
fn fmt_small(v: f64) -> String {
    if v.is_finite() && v != 0.0 && v.abs() < 1e-3 {
        format!("{v:.2e}")
    } else {
        fmt(v, 4)
    }
}

/// Columns of the per-phase table (markdown and HTML).
pub const PHASE_COLUMNS: [&str; 11] = [
    "model",
    "phase",
    "steps",
    "sweeps",
    "share of model",
    "vs builtin total",
    "same states vs builtin",
    "capped steps",
    "capped sweeps (% of model)",
    "median sweeps",
    "warm err n (median MSE)",
];

/// Per model and step-range phase: where the sweeps went, as formatted cells (one formatting for
/// the markdown table and the HTML page).
#[derive(Debug, Clone, PartialEq)]
pub struct PhaseTable {
    /// One row per (model, phase), a cell per [`PHASE_COLUMNS`] entry.
    pub rows: Vec<[String; PHASE_COLUMNS.len()]>,
}

impl PhaseTable {
    pub fn new(rows: &[PhaseRow]) -> PhaseTable {
        let rows = rows
            .iter()
            .map(|r| {
                [
                    r.model.clone(),
                    r.phase.label(),
                    r.steps.to_string(),
                    r.total_sweeps.to_string(),
                    fmt(r.share_of_model * 100.0, 1) + "%",
                    fmt_ratio(r.ratio_to_builtin_total),
                    fmt_ratio(r.same_states_ratio),
                    r.cap_hits.to_string(),
                    fmt(r.cap_sweeps_share * 100.0, 1) + "%",
                    fmt(r.median_sweeps, 1),
                    fmt_small(r.median_warm_error_normal_mse),
                ]
            })
            .collect();
        PhaseTable { rows }
    }

    /// A markdown table: model and phase left-aligned, the numbers right-aligned.
    pub fn to_markdown(&self) -> String {
        markdown_table(&PHASE_COLUMNS, 2, &self.rows)
    }

    pub fn to_html(&self) -> String {
        html_table(&PHASE_COLUMNS, &self.rows)
    }
}

/// Columns of the accuracy -> sweeps table (markdown and HTML).
pub const ACCURACY_COLUMNS: [&str; 11] = [
    "model",
    "late steps (persisting)",
    "warm err n (late median MSE)",
    "err vs builtin",
    "warm err n (late mean MSE)",
    "total sweeps",
    "sweeps vs builtin",
    "late sweeps vs builtin",
    "same states vs builtin",
    "blend F by error",
    "blend F by sweeps",
];

/// The accuracy -> sweeps table as formatted cells, one row per model.
#[derive(Debug, Clone, PartialEq)]
pub struct AccuracyTable {
    /// One row per model, a cell per [`ACCURACY_COLUMNS`] entry.
    pub rows: Vec<[String; ACCURACY_COLUMNS.len()]>,
}

impl AccuracyTable {
    pub fn new(rows: &[AccuracyRow]) -> AccuracyTable {
        let rows = rows
            .iter()
            .map(|r| {
                [
                    r.model.clone(),
                    r.late_steps.to_string(),
                    fmt_small(r.median_warm_error_normal_mse),
                    fmt_ratio(r.error_vs_builtin),
                    fmt_small(r.mean_warm_error_normal_mse),
                    r.total_sweeps.to_string(),
                    fmt_ratio(r.sweeps_vs_builtin),
                    fmt_ratio(r.late_sweeps_vs_builtin),
                    fmt_ratio(r.same_states_vs_builtin),
                    r.blend_by_error.map_or_else(|| "-".into(), |f| f.label()),
                    r.blend_by_sweeps.map_or_else(|| "-".into(), |f| f.label()),
                ]
            })
            .collect();
        AccuracyTable { rows }
    }

    pub fn to_markdown(&self) -> String {
        markdown_table(&ACCURACY_COLUMNS, 1, &self.rows)
    }

    pub fn to_html(&self) -> String {
        html_table(&ACCURACY_COLUMNS, &self.rows)
    }
}

/// The summary as a markdown table.
pub fn summary_markdown(summaries: &[ModelSummary]) -> String {
    SummaryTable::new(summaries).to_markdown()
}

/// The markdown of the per-phase table with a heading and what its columns mean.
pub fn phases_markdown(rows: &[PhaseRow]) -> String {
    format!("## Sweeps per phase\n\n{}\n{PHASES_NOTE}\n", PhaseTable::new(rows).to_markdown())
}

/// The markdown of the accuracy -> sweeps table with a heading and what its columns mean.
pub fn accuracy_markdown(rows: &[AccuracyRow]) -> String {
    let late = rows.first().map(|r| r.late_phase.label()).unwrap_or_else(|| "-".into());
    let mut md = format!(
        "## Accuracy -> sweeps (late phase: steps {late})\n\n{}\n{ACCURACY_NOTE}\n",
        AccuracyTable::new(rows).to_markdown()
    );
    let notes = crate::phases::placement_notes(rows);
    if !notes.is_empty() {
        md.push_str("\nOn the ablation curve:\n\n");
        for n in notes {
            let _ = writeln!(md, "- {n}");
        }
    }
    md
}

const SUMMARY_NOTE: &str = "*vs builtin* compares whole runs: once a warm start differs from builtin's, \
the solver stops elsewhere within its tolerance and the run's trajectory (a chaotic pile) parts from builtin's run, \
so that ratio mixes what the warm start saves with how hard the states it meets are. *same states vs builtin*: \
the model's sweeps over the sweeps builtin's warm start needs on the very same step problems (`dc-sim \
--shadow-builtin`, which `dc eval` turns on), over every step, and the simulation where that ratio is worst.";

const PHASES_NOTE: &str = "Phases are step ranges of every simulation (`--phases`). *share of model*: the \
phase's sweeps as a share of the model's total; *vs builtin total*: the phase's sweeps relative to builtin's \
sweeps over the whole run; *same states vs builtin*: the phase's sweeps over builtin's on the very same step \
problems; *capped*: steps that hit the sweep cap (not converged) and their sweeps as a \
share of the model's total; the warm-start error is the median over the phase's steps with contacts.";

const ACCURACY_NOTE: &str = "Per model: the median (and mean) warm-start MSE of the normal impulse over the \
late phase's steps with persisting contacts, and total sweeps over the whole run, each also relative to \
builtin's (builtin: 1.000x). *blend F*: where the model sits on the run's oracle ablation curve `blend:F` \
(builtin + F x (oracle - builtin); builtin is F = 0, `copy` F = 1): the F whose blend leaves the same late \
error, and the F whose blend needs as many sweeps (on the same states when every model measured them, else over \
whole runs), linear between the blends measured; `< 0`: worse than builtin, `> F`: better than the best blend \
measured. A model placed lower by sweeps than by error removes error PGS removes cheaply anyway. Run blends \
(e.g. `blend:0.1,blend:0.25,blend:0.5,blend:0.75`) beside the models to place them.";

fn csv_file<R: IntoIterator<Item = Vec<String>>>(path: &Path, header: &[&str], rows: R) -> Result<(), ReportError> {
    let e = |source| ReportError::Csv { path: path.display().to_string(), source };
    let mut w = csv::Writer::from_path(path).map_err(e)?;
    w.write_record(header).map_err(e)?;
    for row in rows {
        w.write_record(&row).map_err(e)?;
    }
    w.flush().map_err(io(path))
}

fn opt(v: Option<f64>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// Whether an accuracy point (error, sweeps relative to builtin) belongs in the zoom on builtin.
fn near_builtin(error: f64, sweeps: f64) -> bool {
    (0.0..=2.0).contains(&error) && (0.5..=1.5).contains(&sweeps)
}

/// Log scale when the positive values span more than a decade.
fn spread_scale(values: impl Iterator<Item = f64>) -> Scale {
    let positive: Vec<f64> = values.filter(|v| *v > 0.0 && v.is_finite()).collect();
    let lo = positive.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = positive.iter().copied().fold(0.0, f64::max);
    if positive.len() >= 2 && hi / lo > 10.0 {
        Scale::Log
    } else {
        Scale::Linear
    }
}

/// At most this many points per model in the sweeps-vs-error scatter plot.
pub const SCATTER_POINTS_PER_MODEL: usize = 3000;

/// The steps of a report's `steps.csv` (what [`write`] puts there), to build a report again — with
/// newer tables, or other phases — without running the simulations again. The per-sweep residuals
/// are not in the file: the records come back without them.
pub fn read_steps(path: &Path) -> Result<Vec<crate::StepRecord>, ReportError> {
    let e = |source| ReportError::Csv { path: path.display().to_string(), source };
    let mut reader = csv::Reader::from_path(path).map_err(e)?;
    reader
        .deserialize::<msgs::StepStats>()
        .map(|row| row.map(|stats| crate::StepRecord { stats, residuals: Vec::new() }).map_err(e))
        .collect()
}

/// Writes the report for `aggregate` into `dir`; `missing` lists what the data lacks (a partial
/// run's missing steps, a rebuilt report's residuals).
pub fn write(aggregate: &Aggregate, dir: &Path, title: &str, missing: &[String]) -> Result<Written, ReportError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let models = model_order(aggregate);
    let mut summaries = aggregate.summaries();
    summaries.sort_by_key(|s| models.iter().position(|m| *m == s.model));
    let phases = aggregate.phase_rows();
    let accuracy = aggregate.accuracy();
    let histograms = aggregate.sweeps_histograms();

    // Every step.
    let steps_csv = dir.join("steps.csv");
    {
        let mut w = csv::Writer::from_path(&steps_csv)
            .map_err(|source| ReportError::Csv { path: steps_csv.display().to_string(), source })?;
        for m in &models {
            for r in aggregate.records(m) {
                w.serialize(&r.stats)
                    .map_err(|source| ReportError::Csv { path: steps_csv.display().to_string(), source })?;
            }
        }
        w.flush().map_err(io(&steps_csv))?;
    }
    files.push(steps_csv);

    // Summary.
    let summary_csv = dir.join("summary.csv");
    csv_file(
        &summary_csv,
        &[
            "model",
            "simulations",
            "steps",
            "total_sweeps",
            "ratio_to_builtin",
            "same_states_ratio_to_builtin",
            "same_states_worst_simulation",
            "same_states_worst_ratio",
            "median_sweeps",
            "mean_sweeps",
            "falling_steps",
            "falling_total_sweeps",
            "falling_median_sweeps",
            "settled_steps",
            "settled_total_sweeps",
            "settled_median_sweeps",
            "cap_hits",
            "fallbacks",
            "persisting_share",
            "median_warm_error_normal_mse",
            "median_warm_error_tangent_mse",
            "median_solve_us",
            "median_step_us",
            "total_solve_ms",
        ],
        summaries.iter().map(|m| {
            vec![
                m.model.clone(),
                m.simulations.to_string(),
                m.all.steps.to_string(),
                m.all.total_sweeps.to_string(),
                opt(m.ratio_to_builtin),
                opt(m.same_states.map(|p| p.ratio)),
                m.same_states.map(|p| p.worst_simulation.to_string()).unwrap_or_default(),
                opt(m.same_states.map(|p| p.worst_ratio)),
                m.all.median_sweeps.to_string(),
                m.all.mean_sweeps.to_string(),
                m.falling.steps.to_string(),
                m.falling.total_sweeps.to_string(),
                m.falling.median_sweeps.to_string(),
                m.settled.steps.to_string(),
                m.settled.total_sweeps.to_string(),
                m.settled.median_sweeps.to_string(),
                m.all.cap_hits.to_string(),
                m.all.fallbacks.to_string(),
                m.persisting_share.to_string(),
                m.median_warm_error_normal_mse.to_string(),
                m.median_warm_error_tangent_mse.to_string(),
                m.all.median_solve_us.to_string(),
                m.all.median_step_us.to_string(),
                m.all.total_solve_ms.to_string(),
            ]
        }),
    )?;
    files.push(summary_csv);

    // Per phase, the histogram's numbers, the accuracy -> sweeps table.
    let phases_csv = dir.join("phases.csv");
    csv_file(
        &phases_csv,
        &[
            "model",
            "phase",
            "first_step",
            "last_step",
            "steps",
            "total_sweeps",
            "model_total_sweeps",
            "share_of_model",
            "ratio_to_builtin_total",
            "same_states_ratio",
            "cap_hits",
            "cap_sweeps",
            "cap_sweeps_share",
            "median_sweeps",
            "median_warm_error_normal_mse",
        ],
        phases.iter().map(|r| {
            vec![
                r.model.clone(),
                r.phase.label(),
                r.phase.first.to_string(),
                r.phase.end.map(|e| e.saturating_sub(1).to_string()).unwrap_or_default(),
                r.steps.to_string(),
                r.total_sweeps.to_string(),
                r.model_total_sweeps.to_string(),
                r.share_of_model.to_string(),
                opt(r.ratio_to_builtin_total),
                opt(r.same_states_ratio),
                r.cap_hits.to_string(),
                r.cap_sweeps.to_string(),
                r.cap_sweeps_share.to_string(),
                r.median_sweeps.to_string(),
                r.median_warm_error_normal_mse.to_string(),
            ]
        }),
    )?;
    files.push(phases_csv);
    let histogram_csv = dir.join("sweeps_histogram.csv");
    csv_file(
        &histogram_csv,
        &["model", "phase", "bin_lo", "bin_hi", "steps", "fraction"],
        histograms.histograms.iter().flat_map(|h| {
            histograms.bins.iter().zip(h.counts.iter().zip(&h.fractions)).map(|(b, (c, f))| {
                vec![h.model.clone(), h.phase.label(), b.lo.to_string(), b.hi.to_string(), c.to_string(), f.to_string()]
            })
        }),
    )?;
    files.push(histogram_csv);
    let accuracy_csv = dir.join("accuracy.csv");
    csv_file(
        &accuracy_csv,
        &[
            "model",
            "late_phase",
            "late_steps_persisting",
            "median_warm_error_normal_mse",
            "mean_warm_error_normal_mse",
            "error_vs_builtin",
            "total_sweeps",
            "sweeps_vs_builtin",
            "late_sweeps",
            "late_sweeps_vs_builtin",
            "same_states_vs_builtin",
            "blend_fraction_by_error",
            "blend_place_by_error",
            "blend_fraction_by_sweeps",
            "blend_place_by_sweeps",
            "blend_placed_on_same_states",
        ],
        accuracy.iter().map(|r| {
            vec![
                r.model.clone(),
                r.late_phase.label(),
                r.late_steps.to_string(),
                r.median_warm_error_normal_mse.to_string(),
                r.mean_warm_error_normal_mse.to_string(),
                opt(r.error_vs_builtin),
                r.total_sweeps.to_string(),
                opt(r.sweeps_vs_builtin),
                r.late_sweeps.to_string(),
                opt(r.late_sweeps_vs_builtin),
                opt(r.same_states_vs_builtin),
                opt(r.blend_by_error.and_then(|f| f.fraction())),
                r.blend_by_error.map(|f| f.label()).unwrap_or_default(),
                opt(r.blend_by_sweeps.and_then(|f| f.fraction())),
                r.blend_by_sweeps.map(|f| f.label()).unwrap_or_default(),
                r.placed_on_same_states.to_string(),
            ]
        }),
    )?;
    files.push(accuracy_csv);

    let table = SummaryTable::new(&summaries);
    let summary_md = dir.join("summary.md");
    let mut md = format!("# {title}\n\n{}\n{SUMMARY_NOTE}\n", table.to_markdown());
    if !aggregate.is_empty() {
        let _ = write!(md, "\n{}\n{}", phases_markdown(&phases), accuracy_markdown(&accuracy));
    }
    if !missing.is_empty() {
        md.push_str("\n## Missing data\n\n");
        for m in missing {
            let _ = writeln!(md, "- {m}");
        }
    }
    std::fs::write(&summary_md, &md).map_err(io(&summary_md))?;
    files.push(summary_md);

    // Plots: those of the phase and accuracy sections, then the per-step ones.
    let mut phase_plots: Vec<(String, PathBuf)> = Vec::new();
    let mut accuracy_plots: Vec<(String, PathBuf)> = Vec::new();
    let mut plots: Vec<(String, PathBuf)> = Vec::new();
    if !aggregate.is_empty() {
        // Sweeps histogram: a panel per phase, a line per model.
        let labels: Vec<String> = histograms.bins.iter().map(|b| b.label()).collect();
        let ranges = aggregate.phase_ranges();
        let per_phase: Vec<Vec<Series>> = ranges
            .iter()
            .map(|range| {
                histograms
                    .histograms
                    .iter()
                    .filter(|h| h.phase == *range)
                    .map(|h| Series {
                        name: h.model.clone(),
                        points: if h.steps == 0 {
                            Vec::new()
                        } else {
                            h.fractions.iter().enumerate().map(|(i, &f)| (i as f64, f)).collect()
                        },
                        band: None,
                    })
                    .collect()
            })
            .collect();
        let panels: Vec<Panel> = ranges
            .iter()
            .zip(&per_phase)
            .map(|(range, series)| {
                Panel::new(
                    Axis::categories("sweeps per step (bin)", labels.clone()),
                    Axis::linear("fraction of steps").from_zero(),
                    series,
                    Mark::Lines,
                )
                .titled(&format!("steps {}", range.label()))
            })
            .collect();
        let caption = "Sweeps per step by phase: fraction of each model's steps per bin";
        let path = dir.join("sweeps_histogram.png");
        chart(&path, caption, &panels)?;
        phase_plots.push((caption.into(), path));

        // The accuracy -> sweeps curve: one labelled point per model, relative to builtin.
        // Every model is a series (those without a point too), so each keeps its style.
        let points: Vec<Series> = accuracy
            .iter()
            .map(|r| Series {
                name: r.model.clone(),
                points: r.error_vs_builtin.zip(r.placement_sweeps()).into_iter().collect(),
                band: None,
            })
            .collect();
        let located = || points.iter().flat_map(|s| s.points.iter().copied());
        if located().next().is_some() {
            let late = accuracy[0].late_phase.label();
            let x_scale = spread_scale(located().map(|p| p.0));
            let y_scale = spread_scale(located().map(|p| p.1));
            let x_label = format!("median warm-start MSE of the normal impulse, steps {late} (× builtin's)");
            let same_states = accuracy[0].placed_on_same_states;
            let y_label = if same_states {
                "total sweeps on the same states (× builtin's)"
            } else {
                "total sweeps, whole runs (× builtin's)"
            };
            let panel = Panel::new(
                Axis::linear(&x_label).with_scale(x_scale).from_zero(),
                Axis::linear(y_label).with_scale(y_scale).from_zero(),
                &points,
                Mark::LabelledPoints,
            )
            .guides(&[1.0], &[1.0]);
            let caption = if same_states {
                "Accuracy -> sweeps: late-phase warm-start error and total sweeps on the same states, relative to builtin"
            } else {
                "Accuracy -> sweeps: late-phase warm-start error and total sweeps, relative to builtin"
            };
            // Beside it, the models near builtin on linear axes: the oracle's point (error ~0,
            // sweeps ~0.01x) otherwise squeezes every warm start worth comparing into one corner.
            let near: Vec<Series> = points
                .iter()
                .map(|s| Series {
                    name: s.name.clone(),
                    points: s.points.iter().copied().filter(|&(e, w)| near_builtin(e, w)).collect(),
                    band: None,
                })
                .collect();
            let inside = near.iter().map(|s| s.points.len()).sum::<usize>();
            let zoom =
                Panel::new(Axis::linear(&x_label).from_zero(), Axis::linear(y_label), &near, Mark::LabelledPoints)
                    .titled("near builtin (error <= 2x, sweeps 0.5x-1.5x)")
                    .guides(&[1.0], &[1.0]);
            let path = dir.join("accuracy_vs_sweeps.png");
            if inside >= 2 && inside < located().count() {
                chart(&path, caption, &[panel.titled("all models"), zoom])?;
            } else {
                chart(&path, caption, &[panel])?;
            }
            accuracy_plots.push((caption.into(), path));
        }

        // Per step: sweeps against the warm start's error.
        let scatter: Vec<Series> = models
            .iter()
            .map(|m| Series {
                name: m.clone(),
                points: aggregate.sweeps_vs_warm_error(m, SCATTER_POINTS_PER_MODEL),
                band: None,
            })
            .collect();
        let caption = format!(
            "Sweeps vs warm-start error per step (every k-th step, at most {SCATTER_POINTS_PER_MODEL} per model)"
        );
        let path = dir.join("sweeps_vs_warm_error.png");
        let panel = Panel::new(
            Axis::log("warm-start MSE of the normal impulse per step ((N·s)²)"),
            Axis::log("sweeps per step").integer(),
            &scatter,
            Mark::Points,
        );
        chart(&path, &caption, &[panel])?;
        accuracy_plots.push((caption, path));

        let per_step = |f: &dyn Fn(&crate::StepRecord) -> f64, band: bool| -> Vec<Series> {
            models
                .iter()
                .map(|m| {
                    let b = aggregate.per_step(m, f);
                    Series {
                        name: m.clone(),
                        points: b.iter().map(|b| (b.step as f64, b.median)).collect(),
                        band: band.then(|| b.iter().map(|b| (b.step as f64, b.p10, b.p90)).collect()),
                    }
                })
                .collect()
        };
        let mut lines = |file: &str, caption: &str, x: Axis, y: Axis, series: Vec<Series>| -> Result<(), ReportError> {
            let path = dir.join(file);
            chart(&path, caption, &[Panel::new(x, y, &series, Mark::Lines)])?;
            plots.push((caption.to_string(), path));
            Ok(())
        };
        let step = || Axis::counts("step");
        lines(
            "sweeps_per_step.png",
            "Sweeps per step (median, 10-90% band across simulations)",
            step(),
            Axis::counts("sweeps per step"),
            per_step(&|r| r.sweeps as f64, true),
        )?;
        lines(
            "contacts_per_step.png",
            "Contacts per step (median, 10-90% band)",
            step(),
            Axis::counts("contacts"),
            per_step(&|r| r.contacts as f64, true),
        )?;
        lines(
            "solve_time_per_step.png",
            "Solve time per step (velocity solve only, median)",
            step(),
            Axis::linear("solve time (µs)").from_zero(),
            per_step(&|r| r.solve_us as f64, false),
        )?;
        lines(
            "step_time_per_step.png",
            "Whole step time (collision + warm start + solve + integrate, median)",
            step(),
            Axis::linear("step time (µs)").from_zero(),
            per_step(&|r| r.step_us as f64, false),
        )?;
        lines(
            "warm_error_normal.png",
            "Warm-start error vs solution, normal impulse (median MSE)",
            step(),
            Axis::log("MSE ((N·s)²)"),
            per_step(&|r| r.warm_error_normal_mse as f64, false),
        )?;
        lines(
            "warm_error_tangent.png",
            "Warm-start error vs solution, tangent impulse (median MSE)",
            step(),
            Axis::log("MSE ((N·s)²)"),
            per_step(&|r| r.warm_error_tangent_mse as f64, false),
        )?;
        let max_sweeps =
            models.iter().flat_map(|m| aggregate.records(m).map(|r| r.sweeps)).max().unwrap_or(1).clamp(1, 1000);
        let within = models
            .iter()
            .map(|m| Series {
                name: m.clone(),
                points: aggregate.converged_within(m, max_sweeps).into_iter().map(|(n, f)| (n as f64, f)).collect(),
                band: None,
            })
            .collect();
        lines(
            "converged_within.png",
            "Share of steps converged within n sweeps",
            Axis::counts("sweeps n"),
            Axis::linear("share of steps").from_zero(),
            within,
        )?;
        let convergence = models
            .iter()
            .map(|m| Series {
                name: m.clone(),
                points: aggregate.convergence(m, 1000).into_iter().map(|(n, r)| (n as f64, r)).collect(),
                band: None,
            })
            .collect();
        lines(
            "convergence.png",
            "Convergence: median residual after n sweeps",
            Axis::counts("sweeps n"),
            Axis::log("largest impulse change (N·s)"),
            convergence,
        )?;
    }
    files.extend(phase_plots.iter().chain(&accuracy_plots).chain(&plots).map(|(_, p)| p.clone()));

    // One page that shows it all.
    let html_path = dir.join("report.html");
    let mut html = format!(
        "<!doctype html><meta charset=utf-8><title>{title}</title>\
         <style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}img{{max-width:100%}}</style>\
         <h1>{title}</h1>"
    );
    if !missing.is_empty() {
        html.push_str("<h2>Missing data</h2><ul>");
        for m in missing {
            let _ = write!(html, "<li>{}</li>", escape(m));
        }
        html.push_str("</ul>");
    }
    if aggregate.is_empty() {
        html.push_str("<p><b>No solver statistics arrived.</b> Nothing to summarise or plot.</p>");
    }
    html.push_str("<h2>Summary</h2>");
    html.push_str(&table.to_html());
    let _ = write!(html, "<p>{}</p>", escape(&SUMMARY_NOTE.replace(['*', '`'], "")));
    html.push_str("<p>Phases: a step is <i>settled</i> once every body of its simulation stays slower than the settle speed (default 0.1 m/s) for the rest of the simulation; earlier steps are <i>falling</i> (a dash: no step settled). Times are wall-clock on the machine that ran the simulator.</p>");
    let img = |html: &mut String, plots: &[(String, PathBuf)]| {
        for (caption, path) in plots {
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let _ = write!(html, "<h3>{}</h3><img src=\"{name}\" alt=\"{}\">", escape(caption), escape(caption));
        }
    };
    if !aggregate.is_empty() {
        html.push_str("<h2>Sweeps per phase</h2>");
        html.push_str(&PhaseTable::new(&phases).to_html());
        let _ = write!(html, "<p>{}</p>", escape(PHASES_NOTE));
        img(&mut html, &phase_plots);
        let late = accuracy.first().map(|r| r.late_phase.label()).unwrap_or_default();
        let _ = write!(html, "<h2>Accuracy &rarr; sweeps (late phase: steps {})</h2>", escape(&late));
        html.push_str(&AccuracyTable::new(&accuracy).to_html());
        let _ = write!(
            html,
            "<p>{} In the accuracy plot a model whose error is 0 sits at the left end of a log axis (tick 0, label marked (0)); the scatter plot leaves out steps whose error or sweeps are 0 (log axes).</p>",
            escape(ACCURACY_NOTE)
        );
        let notes = crate::phases::placement_notes(&accuracy);
        if !notes.is_empty() {
            html.push_str("<p>On the ablation curve:</p><ul>");
            for n in &notes {
                let _ = write!(html, "<li>{}</li>", escape(n));
            }
            html.push_str("</ul>");
        }
        img(&mut html, &accuracy_plots);
    }
    for (caption, path) in &plots {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let _ = write!(html, "<h2>{}</h2><img src=\"{name}\" alt=\"{}\">", escape(caption), escape(caption));
    }
    html.push_str("<p>Data: <a href=steps.csv>steps.csv</a> (every step), <a href=summary.csv>summary.csv</a>, <a href=phases.csv>phases.csv</a>, <a href=sweeps_histogram.csv>sweeps_histogram.csv</a>, <a href=accuracy.csv>accuracy.csv</a>.</p>");
    std::fs::write(&html_path, html).map_err(io(&html_path))?;
    files.push(html_path);
    Ok(Written { dir: dir.to_path_buf(), files, summaries, phases, accuracy })
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aggregate::Totals;

    fn summary(model: &str, ratio: Option<f64>) -> ModelSummary {
        let all = Totals {
            steps: 60,
            total_sweeps: 900,
            median_sweeps: 15.0,
            median_solve_us: 45.0,
            median_step_us: 50.0,
            ..Default::default()
        };
        ModelSummary {
            model: model.into(),
            simulations: 3,
            all: all.clone(),
            falling: Totals { median_sweeps: f64::NAN, ..all.clone() },
            settled: all,
            ratio_to_builtin: ratio,
            same_states: ratio.map(|r| crate::aggregate::Paired {
                ratio: r - 0.5,
                worst_simulation: 1,
                worst_ratio: r - 0.25,
            }),
            persisting_share: 0.25,
            median_warm_error_normal_mse: 0.012345,
            median_warm_error_tangent_mse: 0.1,
        }
    }

    #[test]
    fn markdown_and_html_show_the_same_cells() {
        let table = SummaryTable::new(&[summary("none", Some(3.0)), summary("a<b", None)]);
        let md = table.to_markdown();
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(lines[0], "| model | sims | steps | total sweeps | vs builtin | same states vs builtin | worst sim, same states | median sweeps | falling: median | settled: median | cap hits | fallbacks | persisting | warm err n (median MSE) | median solve us | median step us |");
        assert_eq!(lines[1], "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        assert_eq!(
            lines[2],
            "| none | 3 | 60 | 900 | 3.000x | 2.500x | 2.750x (sim 1) | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 |"
        );
        assert_eq!(
            lines[3],
            "| a<b | 3 | 60 | 900 | - | - | - | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 |"
        );
        assert_eq!(lines.len(), 4);
        let html = table.to_html();
        assert!(
            html.starts_with("<table><tr><th>model</th><th>sims</th>") && html.ends_with("</td></tr></table>"),
            "{html}"
        );
        assert!(
            html.contains("<tr><td>none</td><td>3</td><td>60</td><td>900</td><td>3.000x</td><td>2.500x</td>"),
            "{html}"
        );
        assert!(
            html.contains("<td>a&lt;b</td>")
                && html.contains("<td>25.0%</td><td>0.0123</td><td>45.0</td><td>50.0</td></tr>"),
            "{html}"
        );
        assert_eq!(html.matches("<tr>").count(), 3);
        assert_eq!(html.matches("<th>").count(), SUMMARY_COLUMNS.len());
        assert_eq!(html.matches("<td>").count(), 2 * SUMMARY_COLUMNS.len());
        assert_eq!(summary_markdown(&[]).lines().count(), 2);
    }
}
