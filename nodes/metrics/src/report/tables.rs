//! The report's tables as formatted cells: the summary, the per-phase and the accuracy -> sweeps
//! tables, each written once and shown both in `summary.md` and on the HTML page (one formatting,
//! so the two cannot disagree), with the notes that say what their columns mean.
//!
//! Each table is a list of columns, a column its header beside the function that writes its cell.

use crate::aggregate::ModelSummary;
use crate::phases::{AccuracyRow, PhaseRow};
use std::fmt::Write as _;

/// A column of a formatted table: its header, and its cell of a row.
type Column<T> = (&'static str, fn(&T) -> String);

/// The headers of `columns`, in order.
const fn headers<T, const N: usize>(columns: &[Column<T>; N]) -> [&'static str; N] {
    let mut out = [""; N];
    let mut i = 0;
    while i < N {
        out[i] = columns[i].0;
        i += 1;
    }
    out
}

/// A formatted table of `T`s: one row of cells per item, a cell per column; its first
/// `key_columns` columns are left-aligned in markdown, the numbers right-aligned.
#[derive(Debug, Clone, PartialEq)]
pub struct Table<T: 'static, const N: usize> {
    columns: &'static [Column<T>; N],
    key_columns: usize,
    /// One row per item, a cell per column.
    pub rows: Vec<[String; N]>,
}

impl<T, const N: usize> Table<T, N> {
    fn build(columns: &'static [Column<T>; N], key_columns: usize, items: &[T]) -> Self {
        let rows = items.iter().map(|item| columns.map(|(_, cell)| cell(item))).collect();
        Table { columns, key_columns, rows }
    }

    /// A markdown table.
    pub fn to_markdown(&self) -> String {
        markdown_table(&headers(self.columns), self.key_columns, &self.rows)
    }

    /// An HTML `<table>`: a header row, then one row per item (cells escaped).
    pub fn to_html(&self) -> String {
        html_table(&headers(self.columns), &self.rows)
    }
}

fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "-".to_string()
    }
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

/// A share (0..1) as a percentage with one decimal.
fn fmt_percent(share: f64) -> String {
    fmt(share * 100.0, 1) + "%"
}

const SUMMARY: [Column<ModelSummary>; 18] = [
    ("model", |m| m.model.clone()),
    ("sims", |m| m.simulations.to_string()),
    ("steps", |m| m.all.steps.to_string()),
    ("total sweeps", |m| m.all.total_sweeps.to_string()),
    ("vs builtin", |m| m.ratio_to_builtin.map(|r| format!("{r:.3}x")).unwrap_or_else(|| "-".into())),
    ("same states vs builtin", |m| m.same_states.map(|p| format!("{:.3}x", p.ratio)).unwrap_or_else(|| "-".into())),
    ("worst sim, same states", |m| {
        m.same_states
            .map(|p| format!("{:.3}x (sim {})", p.worst_ratio, p.worst_simulation))
            .unwrap_or_else(|| "-".into())
    }),
    ("median sweeps", |m| fmt(m.all.median_sweeps, 1)),
    ("falling: median", |m| fmt(m.falling.median_sweeps, 1)),
    ("settled: median", |m| fmt(m.settled.median_sweeps, 1)),
    ("cap hits", |m| m.all.cap_hits.to_string()),
    ("fallbacks", |m| m.all.fallbacks.to_string()),
    ("persisting", |m| fmt_percent(m.persisting_share)),
    ("warm err n (median MSE)", |m| fmt(m.median_warm_error_normal_mse, 4)),
    ("median solve us", |m| fmt(m.all.median_solve_us, 1)),
    ("median step us", |m| fmt(m.all.median_step_us, 1)),
    ("RMS natural residual (mean)", |m| fmt_small(m.accuracy.natural_rms)),
    ("penetration max (mean, m)", |m| fmt_small(m.accuracy.penetration_max)),
];

/// Columns of the summary table (markdown and HTML).
pub const SUMMARY_COLUMNS: [&str; SUMMARY.len()] = headers(&SUMMARY);

/// The summary table as formatted cells, one row per model: what both the markdown table and the
/// HTML page show (the model column left-aligned, the numbers right-aligned).
pub type SummaryTable = Table<ModelSummary, { SUMMARY.len() }>;

impl SummaryTable {
    /// The cells of `summaries`, in their order.
    pub fn new(summaries: &[ModelSummary]) -> SummaryTable {
        Table::build(&SUMMARY, 1, summaries)
    }
}

const PHASE: [Column<PhaseRow>; 11] = [
    ("model", |r| r.model.clone()),
    ("phase", |r| r.phase.label()),
    ("steps", |r| r.steps.to_string()),
    ("sweeps", |r| r.total_sweeps.to_string()),
    ("share of model", |r| fmt_percent(r.share_of_model)),
    ("vs builtin total", |r| fmt_ratio(r.ratio_to_builtin_total)),
    ("same states vs builtin", |r| fmt_ratio(r.same_states_ratio)),
    ("capped steps", |r| r.cap_hits.to_string()),
    ("capped sweeps (% of model)", |r| fmt_percent(r.cap_sweeps_share)),
    ("median sweeps", |r| fmt(r.median_sweeps, 1)),
    ("warm err n (median MSE)", |r| fmt_small(r.median_warm_error_normal_mse)),
];

/// Columns of the per-phase table (markdown and HTML).
pub const PHASE_COLUMNS: [&str; PHASE.len()] = headers(&PHASE);

/// Per model and step-range phase: where the sweeps went, as formatted cells (model and phase
/// left-aligned).
pub type PhaseTable = Table<PhaseRow, { PHASE.len() }>;

impl PhaseTable {
    /// The cells of `rows`, in their order.
    pub fn new(rows: &[PhaseRow]) -> PhaseTable {
        Table::build(&PHASE, 2, rows)
    }
}

const ACCURACY: [Column<AccuracyRow>; 11] = [
    ("model", |r| r.model.clone()),
    ("late steps (persisting)", |r| r.late_steps.to_string()),
    ("warm err n (late median MSE)", |r| fmt_small(r.median_warm_error_normal_mse)),
    ("err vs builtin", |r| fmt_ratio(r.error_vs_builtin)),
    ("warm err n (late mean MSE)", |r| fmt_small(r.mean_warm_error_normal_mse)),
    ("total sweeps", |r| r.total_sweeps.to_string()),
    ("sweeps vs builtin", |r| fmt_ratio(r.sweeps_vs_builtin)),
    ("late sweeps vs builtin", |r| fmt_ratio(r.late_sweeps_vs_builtin)),
    ("same states vs builtin", |r| fmt_ratio(r.same_states_vs_builtin)),
    ("blend F by error", |r| r.blend_by_error.map_or_else(|| "-".into(), |f| f.label())),
    ("blend F by sweeps", |r| r.blend_by_sweeps.map_or_else(|| "-".into(), |f| f.label())),
];

/// Columns of the accuracy -> sweeps table (markdown and HTML).
pub const ACCURACY_COLUMNS: [&str; ACCURACY.len()] = headers(&ACCURACY);

/// The accuracy -> sweeps table as formatted cells, one row per model.
pub type AccuracyTable = Table<AccuracyRow, { ACCURACY.len() }>;

impl AccuracyTable {
    /// The cells of `rows`, in their order.
    pub fn new(rows: &[AccuracyRow]) -> AccuracyTable {
        Table::build(&ACCURACY, 1, rows)
    }
}

/// A summary's error split (only rows that have one are tabulated).
fn split_of(m: &ModelSummary) -> msgs::ErrorSplit {
    m.split.unwrap_or_default()
}

const SPLIT: [Column<ModelSummary>; 12] = [
    ("model", |m| m.model.clone()),
    ("contacts", |m| split_of(m).n.to_string()),
    ("smooth RMS", |m| fmt_small(split_of(m).model_rms().0)),
    ("rough RMS", |m| fmt_small(split_of(m).model_rms().1)),
    ("builtin's smooth RMS", |m| fmt_small(split_of(m).builtin_rms().0)),
    ("builtin's rough RMS", |m| fmt_small(split_of(m).builtin_rms().1)),
    ("smooth removed", |m| fmt_percent(split_of(m).removed().0)),
    ("rough removed", |m| fmt_percent(split_of(m).removed().1)),
    ("left after the sweeps", |m| fmt_small(split_of(m).left_rms().0)),
    ("builtin's left", |m| fmt_small(split_of(m).left_rms().1)),
    ("natural residual left", |m| fmt_small(split_of(m).left_natural().0)),
    ("builtin's natural residual left", |m| fmt_small(split_of(m).left_natural().1)),
];

/// Which part of builtin's warm-start error each model removes, one row per model that measured
/// it (`dc-sim --error-split`).
pub type SplitTable = Table<ModelSummary, { SPLIT.len() }>;

impl SplitTable {
    /// The cells of the `summaries` that measured a split, in their order; None when none did.
    pub fn new(summaries: &[ModelSummary]) -> Option<SplitTable> {
        let measured: Vec<ModelSummary> = summaries.iter().filter(|m| m.split.is_some()).cloned().collect();
        (!measured.is_empty()).then(|| Table::build(&SPLIT, 1, &measured))
    }
}

/// What the error-split table's columns mean.
pub const SPLIT_NOTE: &str = "Measured with `dc-sim --error-split` (`dc eval --error-split`): on each of the model's steps, its warm start's error against the step's exact solution and builtin's warm start's error on the same step, each split into the part 4 passes of averaging over the contact graph keep (*smooth*: pile-wide) and the rest (*rough*: local); *removed*: the share of builtin's RMS the model's start does not have (negative: further from the solution than builtin); *left after the sweeps*: the error the run's sweep cap (its budget) leaves from the model's start, beside what it leaves from builtin's on the same step (the part slow for the solver). RMS over the contacts, impulse units, normal and tangent together. *natural residual left*: the RMS natural residual those sweeps leave from each start, mean over the steps: solver-independent, and blind to which of a jammed pile's many solutions a start heads for (the error columns count another valid solution as error); at a budget it is the same-states comparison.";

/// The report's tables formatted once, for both `summary.md` and `report.html`.
pub(super) struct Tables<'a> {
    /// A row per model.
    pub summary: SummaryTable,
    /// A row per model that measured its error split; None when none did.
    pub split: Option<SplitTable>,
    /// The per-phase and accuracy sections: none when no statistics arrived.
    pub details: Option<Details<'a>>,
}

/// The per-phase and accuracy -> sweeps sections' tables.
pub(super) struct Details<'a> {
    /// Per model and step-range phase.
    pub phases: PhaseTable,
    /// A row per model.
    pub accuracy: AccuracyTable,
    /// The rows `accuracy` formats: its late phase and the placement notes.
    pub accuracy_rows: &'a [AccuracyRow],
}

impl<'a> Tables<'a> {
    /// The tables of `summaries`, and of `phases` and `accuracy` unless `empty`.
    pub fn new(summaries: &[ModelSummary], phases: &[PhaseRow], accuracy: &'a [AccuracyRow], empty: bool) -> Self {
        Tables {
            summary: SummaryTable::new(summaries),
            split: SplitTable::new(summaries),
            details: (!empty).then(|| Details {
                phases: PhaseTable::new(phases),
                accuracy: AccuracyTable::new(accuracy),
                accuracy_rows: accuracy,
            }),
        }
    }
}

/// What the summary's builtin-relative columns compare.
pub const SUMMARY_NOTE: &str = "*vs builtin* compares whole runs: once a warm start differs from builtin's, \
the solver stops elsewhere within its tolerance and the run's trajectory (a chaotic pile) parts from builtin's run, \
so that ratio mixes what the warm start saves with how hard the states it meets are. *same states vs builtin*: \
the model's sweeps over the sweeps builtin's warm start needs on the very same step problems (`dc-sim \
--shadow-builtin`, which `dc eval` turns on), over every step, and the simulation where that ratio is worst. *RMS natural residual*: how far each step's \
impulses are from solving its contact problem (what one projected Jacobi step would still change, RMS over the \
rows, impulse units; mean over the steps with contacts), whatever stopped the solve: at a fixed sweep budget \
(`dc eval --budget`) it is what a warm start buys. *penetration max*: the largest overlap the position pass \
left, mean over steps.";

/// What the per-phase table's columns mean.
pub const PHASES_NOTE: &str = "Phases are step ranges of every simulation (`--phases`). *share of model*: the \
phase's sweeps as a share of the model's total; *vs builtin total*: the phase's sweeps relative to builtin's \
sweeps over the whole run; *same states vs builtin*: the phase's sweeps over builtin's on the very same step \
problems; *capped*: steps that hit the sweep cap (not converged) and their sweeps as a \
share of the model's total; the warm-start error is the median over the phase's steps with contacts.";

/// What the accuracy -> sweeps table's columns mean.
pub const ACCURACY_NOTE: &str = "Per model: the median (and mean) warm-start MSE of the normal impulse over the \
late phase's steps with persisting contacts, and total sweeps over the whole run, each also relative to \
builtin's (builtin: 1.000x). *blend F*: where the model sits on the run's oracle ablation curve `blend:F` \
(builtin + F x (oracle - builtin); builtin is F = 0, `copy` F = 1): the F whose blend leaves the same late \
error, and the F whose blend needs as many sweeps (on the same states when every model measured them, else over \
whole runs), linear between the blends measured; `< 0`: worse than builtin, `> F`: better than the best blend \
measured. A model placed lower by sweeps than by error removes error PGS removes cheaply anyway. Run blends \
(e.g. `blend:0.1,blend:0.25,blend:0.5,blend:0.75`) beside the models to place them.";

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

/// `s` with HTML's special characters escaped, for text and attribute values.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aggregate::{Paired, Totals};

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
            same_states: ratio.map(|r| Paired { ratio: r - 0.5, worst_simulation: 1, worst_ratio: r - 0.25 }),
            persisting_share: 0.25,
            median_warm_error_normal_mse: 0.012345,
            median_warm_error_tangent_mse: 0.1,
            accuracy: Default::default(),
            split: None,
        }
    }

    #[test]
    fn the_split_table_has_a_row_per_model_that_measured_it() {
        assert!(SplitTable::new(&[summary("builtin", None)]).is_none(), "nothing measured: no table");
        let split = msgs::ErrorSplit {
            model_smooth: 1.0,
            model_rough: 16.0,
            builtin_smooth: 4.0,
            builtin_rough: 4.0,
            model_left: 0.25,
            builtin_left: 1.0,
            model_left_natural: 0.002,
            builtin_left_natural: 0.003,
            n: 4,
            steps: 1,
        };
        let gnn = ModelSummary { split: Some(split), ..summary("gnn", None) };
        let table = SplitTable::new(&[summary("builtin", None), gnn]).unwrap();
        let md = table.to_markdown();
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(lines[0], format!("| {} |", headers(&SPLIT).join(" | ")));
        // RMS over 4 contacts: smooth 0.5 against builtin's 1 (50% removed), rough 2 against 1
        // (-100%: further from the solution), left 0.25 against 0.5.
        assert_eq!(
            lines[2],
            "| gnn | 4 | 0.5000 | 2.0000 | 1.0000 | 1.0000 | 50.0% | -100.0% | 0.2500 | 0.5000 | 0.0020 | 0.0030 |"
        );
        assert_eq!(lines.len(), 3);
    }

    #[test]
    fn markdown_and_html_show_the_same_cells() {
        let table = SummaryTable::new(&[summary("none", Some(3.0)), summary("a<b", None)]);
        let md = table.to_markdown();
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(lines[0], "| model | sims | steps | total sweeps | vs builtin | same states vs builtin | worst sim, same states | median sweeps | falling: median | settled: median | cap hits | fallbacks | persisting | warm err n (median MSE) | median solve us | median step us | RMS natural residual (mean) | penetration max (mean, m) |");
        assert_eq!(
            lines[1],
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        assert_eq!(
            lines[2],
            "| none | 3 | 60 | 900 | 3.000x | 2.500x | 2.750x (sim 1) | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 | 0.0000 | 0.0000 |"
        );
        assert_eq!(
            lines[3],
            "| a<b | 3 | 60 | 900 | - | - | - | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 | 0.0000 | 0.0000 |"
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
                && html.contains(
                    "<td>25.0%</td><td>0.0123</td><td>45.0</td><td>50.0</td><td>0.0000</td><td>0.0000</td></tr>"
                ),
            "{html}"
        );
        assert_eq!(html.matches("<tr>").count(), 3);
        assert_eq!(html.matches("<th>").count(), SUMMARY_COLUMNS.len());
        assert_eq!(html.matches("<td>").count(), 2 * SUMMARY_COLUMNS.len());
        assert_eq!(SummaryTable::new(&[]).to_markdown().lines().count(), 2, "no models: the header alone");
    }
}
