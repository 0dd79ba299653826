//! The report folder: every step as CSV, the summary as CSV and markdown, PNG plots, and one
//! `report.html` that shows them side by side.

use crate::aggregate::{Aggregate, ModelSummary};
use crate::plot::{line_chart, Series, YScale};
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
}

/// Models in a stable, meaningful order: the contract's table order (the thesis's), then others.
fn model_order(a: &Aggregate) -> Vec<String> {
    let order = msgs::models::MODELS;
    let mut models: Vec<String> = a.models.keys().cloned().collect();
    models.sort_by_key(|m| (order.iter().position(|o| o.name == m).unwrap_or(order.len()), m.clone()));
    models
}

fn fmt(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "-".to_string()
    }
}

/// Columns of the summary table (markdown and HTML).
pub const SUMMARY_COLUMNS: [&str; 14] = [
    "model",
    "sims",
    "steps",
    "total sweeps",
    "vs builtin",
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
        let line = |cells: &[&str]| format!("| {} |\n", cells.join(" | "));
        let mut s = line(&SUMMARY_COLUMNS);
        s.push_str("|---|");
        s.push_str(&"---:|".repeat(SUMMARY_COLUMNS.len() - 1));
        s.push('\n');
        for row in &self.rows {
            s.push_str(&line(&row.each_ref().map(String::as_str)));
        }
        s
    }

    /// An HTML `<table>`: a header row, then one row per model (cells escaped).
    pub fn to_html(&self) -> String {
        let mut html = String::from("<table>");
        let mut row = |tag: &str, cells: &[&str]| {
            html.push_str("<tr>");
            for c in cells {
                let _ = write!(html, "<{tag}>{}</{tag}>", escape(c));
            }
            html.push_str("</tr>");
        };
        row("th", &SUMMARY_COLUMNS);
        for r in &self.rows {
            row("td", &r.each_ref().map(String::as_str));
        }
        html.push_str("</table>");
        html
    }
}

/// The summary as a markdown table.
pub fn summary_markdown(summaries: &[ModelSummary]) -> String {
    SummaryTable::new(summaries).to_markdown()
}

/// Writes the report for `aggregate` into `dir`; `missing` lists what a partial run lacks.
pub fn write(aggregate: &Aggregate, dir: &Path, title: &str, missing: &[String]) -> Result<Written, ReportError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let models = model_order(aggregate);
    let mut summaries = aggregate.summaries();
    summaries.sort_by_key(|s| models.iter().position(|m| *m == s.model));

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
    {
        let mut w = csv::Writer::from_path(&summary_csv)
            .map_err(|source| ReportError::Csv { path: summary_csv.display().to_string(), source })?;
        w.write_record([
            "model",
            "simulations",
            "steps",
            "total_sweeps",
            "ratio_to_builtin",
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
        ])
        .map_err(|source| ReportError::Csv { path: summary_csv.display().to_string(), source })?;
        for m in &summaries {
            let row = [
                m.model.clone(),
                m.simulations.to_string(),
                m.all.steps.to_string(),
                m.all.total_sweeps.to_string(),
                m.ratio_to_builtin.map(|r| r.to_string()).unwrap_or_default(),
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
            ];
            w.write_record(&row)
                .map_err(|source| ReportError::Csv { path: summary_csv.display().to_string(), source })?;
        }
        w.flush().map_err(io(&summary_csv))?;
    }
    files.push(summary_csv);
    let table = SummaryTable::new(&summaries);
    let summary_md = dir.join("summary.md");
    let mut md = format!("# {title}\n\n{}\n", table.to_markdown());
    if !missing.is_empty() {
        md.push_str("\n## Missing data (partial run)\n\n");
        for m in missing {
            let _ = writeln!(md, "- {m}");
        }
    }
    std::fs::write(&summary_md, &md).map_err(io(&summary_md))?;
    files.push(summary_md);

    // Plots.
    let mut plots: Vec<(String, PathBuf)> = Vec::new();
    if !aggregate.is_empty() {
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
        let mut chart = |file: &str,
                         caption: &str,
                         x: &str,
                         y: &str,
                         series: Vec<Series>,
                         scale: YScale|
         -> Result<(), ReportError> {
            let path = dir.join(file);
            line_chart(&path, caption, x, y, &series, scale)?;
            plots.push((caption.to_string(), path));
            Ok(())
        };
        chart(
            "sweeps_per_step.png",
            "Sweeps per step (median, 10-90% band across simulations)",
            "step",
            "sweeps",
            per_step(&|r| r.sweeps as f64, true),
            YScale::Linear,
        )?;
        chart(
            "contacts_per_step.png",
            "Contacts per step (median, 10-90% band)",
            "step",
            "contacts",
            per_step(&|r| r.contacts as f64, true),
            YScale::Linear,
        )?;
        chart(
            "solve_time_per_step.png",
            "Solve time per step (velocity solve only, median)",
            "step",
            "microseconds",
            per_step(&|r| r.solve_us as f64, false),
            YScale::Linear,
        )?;
        chart(
            "step_time_per_step.png",
            "Whole step time (collision + warm start + solve + integrate, median)",
            "step",
            "microseconds",
            per_step(&|r| r.step_us as f64, false),
            YScale::Linear,
        )?;
        chart(
            "warm_error_normal.png",
            "Warm-start error vs solution, normal impulse (median MSE)",
            "step",
            "MSE",
            per_step(&|r| r.warm_error_normal_mse as f64, false),
            YScale::Log,
        )?;
        chart(
            "warm_error_tangent.png",
            "Warm-start error vs solution, tangent impulse (median MSE)",
            "step",
            "MSE",
            per_step(&|r| r.warm_error_tangent_mse as f64, false),
            YScale::Log,
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
        chart(
            "converged_within.png",
            "Share of steps converged within n sweeps",
            "sweeps n",
            "share of steps",
            within,
            YScale::Linear,
        )?;
        let convergence = models
            .iter()
            .map(|m| Series {
                name: m.clone(),
                points: aggregate.convergence(m, 1000).into_iter().map(|(n, r)| (n as f64, r)).collect(),
                band: None,
            })
            .collect();
        chart(
            "convergence.png",
            "Convergence: median residual after n sweeps",
            "sweeps n",
            "largest impulse change",
            convergence,
            YScale::Log,
        )?;
    }
    files.extend(plots.iter().map(|(_, p)| p.clone()));

    // One page that shows it all.
    let html_path = dir.join("report.html");
    let mut html = format!(
        "<!doctype html><meta charset=utf-8><title>{title}</title>\
         <style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;text-align:right}}img{{max-width:100%}}</style>\
         <h1>{title}</h1>"
    );
    if !missing.is_empty() {
        html.push_str("<h2>Missing data (partial run)</h2><ul>");
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
    html.push_str("<p>Phases: a step is <i>settled</i> once every body of its simulation stays slower than the settle speed (default 0.1 m/s) for the rest of the simulation; earlier steps are <i>falling</i> (a dash: no step settled). Times are wall-clock on the machine that ran the simulator.</p>");
    for (caption, path) in &plots {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let _ = write!(html, "<h2>{}</h2><img src=\"{name}\" alt=\"{}\">", escape(caption), escape(caption));
    }
    html.push_str("<p>Data: <a href=steps.csv>steps.csv</a> (every step), <a href=summary.csv>summary.csv</a>.</p>");
    std::fs::write(&html_path, html).map_err(io(&html_path))?;
    files.push(html_path);
    Ok(Written { dir: dir.to_path_buf(), files, summaries })
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
        assert_eq!(lines[0], "| model | sims | steps | total sweeps | vs builtin | median sweeps | falling: median | settled: median | cap hits | fallbacks | persisting | warm err n (median MSE) | median solve us | median step us |");
        assert_eq!(lines[1], "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        assert_eq!(
            lines[2],
            "| none | 3 | 60 | 900 | 3.000x | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 |"
        );
        assert_eq!(lines[3], "| a<b | 3 | 60 | 900 | - | 15.0 | - | 15.0 | 0 | 0 | 25.0% | 0.0123 | 45.0 | 50.0 |");
        assert_eq!(lines.len(), 4);
        let html = table.to_html();
        assert!(
            html.starts_with("<table><tr><th>model</th><th>sims</th>") && html.ends_with("</td></tr></table>"),
            "{html}"
        );
        assert!(
            html.contains("<tr><td>none</td><td>3</td><td>60</td><td>900</td><td>3.000x</td><td>15.0</td><td>-</td>"),
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
