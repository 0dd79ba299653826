//! The report folder: every step as CSV, the summary as CSV and markdown, PNG plots, and one
//! `report.html` that shows them side by side.
//!
//! [`write`] computes the tables once and hands them to one writer per output: `csv` (five files),
//! `markdown` (`summary.md`), `plots` (the PNGs) and `html` (the page); `tables` formats the cells
//! that markdown and HTML share, once for both.

mod csv;
mod error;
mod html;
mod markdown;
mod plots;
mod tables;

pub use self::csv::{aggregate_steps, read_steps};
pub use error::ReportError;
pub use markdown::{accuracy_markdown, phases_markdown, summary_markdown};
pub use plots::SCATTER_POINTS_PER_MODEL;
pub use tables::{AccuracyTable, PhaseTable, SummaryTable, ACCURACY_COLUMNS, PHASE_COLUMNS, SUMMARY_COLUMNS};

use crate::aggregate::{Aggregate, ModelSummary};
use crate::phases::{AccuracyRow, PhaseRow};
use std::path::{Path, PathBuf};

/// What was written.
#[derive(Debug)]
pub struct Written {
    /// The report folder.
    pub dir: PathBuf,
    /// Every file written, in the order written (the page last).
    pub files: Vec<PathBuf>,
    /// Per model, in the report's model order (`summary.csv`).
    pub summaries: Vec<ModelSummary>,
    /// Per model and step-range phase: where the sweeps went (`phases.csv`).
    pub phases: Vec<PhaseRow>,
    /// The accuracy -> sweeps table (`accuracy.csv`).
    pub accuracy: Vec<AccuracyRow>,
}

/// Writes the report for `aggregate` into `dir`; `missing` lists what the data lacks (a partial
/// run's missing steps, a rebuilt report's residuals).
pub fn write(aggregate: &Aggregate, dir: &Path, title: &str, missing: &[String]) -> Result<Written, ReportError> {
    std::fs::create_dir_all(dir).map_err(error::io(dir))?;
    let models = aggregate.model_order();
    let mut summaries = aggregate.summaries();
    summaries.sort_by_key(|s| models.iter().position(|m| *m == s.model));
    let phases = aggregate.phase_rows();
    let accuracy = aggregate.accuracy();
    let histograms = aggregate.sweeps_histograms();
    let tables = tables::Tables::new(&summaries, &phases, &accuracy, aggregate.is_empty());

    let mut files = vec![
        csv::steps(dir, aggregate, &models)?,
        csv::summary(dir, &summaries)?,
        csv::phases(dir, &phases)?,
        csv::sweeps_histogram(dir, &histograms)?,
        csv::accuracy(dir, &accuracy)?,
        markdown::write(dir, title, &tables, missing)?,
    ];
    let plots = plots::write(dir, aggregate, &models, &histograms, &accuracy)?;
    files.extend(plots.files().cloned());
    files.push(html::write(dir, title, missing, &tables, &plots)?);
    Ok(Written { dir: dir.to_path_buf(), files, summaries, phases, accuracy })
}
