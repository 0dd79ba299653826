//! `report.html`: one page that shows the report's tables and plots.

use super::error::{io, ReportError};
use super::plots::{Plot, Plots};
use super::tables::{escape, Tables, ACCURACY_NOTE, PHASES_NOTE, SPLIT_NOTE, SUMMARY_NOTE};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// `report.html`: what is missing, the summary, the per-phase and accuracy sections with their
/// plots (none when no statistics arrived), the per-step plots, and links to the CSVs.
pub fn write(
    dir: &Path,
    title: &str,
    missing: &[String],
    tables: &Tables,
    plots: &Plots,
) -> Result<PathBuf, ReportError> {
    let path = dir.join("report.html");
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
    if tables.details.is_none() {
        html.push_str("<p><b>No solver statistics arrived.</b> Nothing to summarise or plot.</p>");
    }
    html.push_str("<h2>Summary</h2>");
    html.push_str(&tables.summary.to_html());
    let _ = write!(html, "<p>{}</p>", escape(&SUMMARY_NOTE.replace(['*', '`'], "")));
    html.push_str("<p>Phases: a step is <i>settled</i> once every body of its simulation stays slower than the settle speed (default 0.1 m/s) for the rest of the simulation; earlier steps are <i>falling</i> (a dash: no step settled). Times are wall-clock on the machine that ran the simulator.</p>");
    if let Some(d) = &tables.details {
        html.push_str("<h2>Sweeps per phase</h2>");
        html.push_str(&d.phases.to_html());
        let _ = write!(html, "<p>{}</p>", escape(PHASES_NOTE));
        images(&mut html, "h3", &plots.phases);
        let late = d.accuracy_rows.first().map(|r| r.late_phase.label()).unwrap_or_default();
        let _ = write!(html, "<h2>Accuracy &rarr; sweeps (late phase: steps {})</h2>", escape(&late));
        html.push_str(&d.accuracy.to_html());
        let _ = write!(
            html,
            "<p>{} In the accuracy plot a model whose error is 0 sits at the left end of a log axis (tick 0, label marked (0)); the scatter plot leaves out steps whose error or sweeps are 0 (log axes).</p>",
            escape(ACCURACY_NOTE)
        );
        let notes = crate::phases::placement_notes(d.accuracy_rows);
        if !notes.is_empty() {
            html.push_str("<p>On the ablation curve:</p><ul>");
            for n in &notes {
                let _ = write!(html, "<li>{}</li>", escape(n));
            }
            html.push_str("</ul>");
        }
        images(&mut html, "h3", &plots.accuracy);
    }
    if let Some(split) = &tables.split {
        html.push_str("<h2>Which part of builtin's error each model removes</h2>");
        html.push_str(&split.to_html());
        let _ = write!(html, "<p>{}</p>", escape(&SPLIT_NOTE.replace(['*', '`'], "")));
    }
    images(&mut html, "h2", &plots.per_step);
    html.push_str("<p>Data: <a href=steps.csv>steps.csv</a> (every step), <a href=summary.csv>summary.csv</a>, <a href=phases.csv>phases.csv</a>, <a href=sweeps_histogram.csv>sweeps_histogram.csv</a>, <a href=accuracy.csv>accuracy.csv</a>.</p>");
    std::fs::write(&path, html).map_err(io(&path))?;
    Ok(path)
}

/// Each plot under a `heading` (`h2`, `h3`) of its caption.
fn images(html: &mut String, heading: &str, plots: &[Plot]) {
    for Plot { caption, path } in plots {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let caption = escape(caption);
        let _ = write!(html, "<{heading}>{caption}</{heading}><img src=\"{name}\" alt=\"{caption}\">");
    }
}
