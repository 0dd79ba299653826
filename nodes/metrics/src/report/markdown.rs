//! `summary.md`: the report's tables in markdown (also what `dc-metrics` prints).

use super::error::{io, ReportError};
use super::tables::{
    AccuracyTable, PhaseTable, SplitTable, SummaryTable, Tables, ACCURACY_NOTE, PHASES_NOTE, SPLIT_NOTE, SUMMARY_NOTE,
};
use crate::aggregate::ModelSummary;
use crate::phases::{AccuracyRow, PhaseRow};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The summary as a markdown table.
pub fn summary_markdown(summaries: &[ModelSummary]) -> String {
    SummaryTable::new(summaries).to_markdown()
}

/// The markdown of the per-phase table with a heading and what its columns mean.
pub fn phases_markdown(rows: &[PhaseRow]) -> String {
    phases_section(&PhaseTable::new(rows))
}

/// The markdown of the accuracy -> sweeps table with a heading and what its columns mean.
pub fn accuracy_markdown(rows: &[AccuracyRow]) -> String {
    accuracy_section(&AccuracyTable::new(rows), rows)
}

/// [`phases_markdown`] of a formatted table.
fn phases_section(table: &PhaseTable) -> String {
    format!("## Sweeps per phase\n\n{}\n{PHASES_NOTE}\n", table.to_markdown())
}

/// [`accuracy_markdown`] of a formatted table (`table`, the cells of `rows`).
fn accuracy_section(table: &AccuracyTable, rows: &[AccuracyRow]) -> String {
    let late = rows.first().map(|r| r.late_phase.label()).unwrap_or_else(|| "-".into());
    let mut md =
        format!("## Accuracy -> sweeps (late phase: steps {late})\n\n{}\n{ACCURACY_NOTE}\n", table.to_markdown());
    let notes = crate::phases::placement_notes(rows);
    if !notes.is_empty() {
        md.push_str("\nOn the ablation curve:\n\n");
        for n in notes {
            let _ = writeln!(md, "- {n}");
        }
    }
    md
}

/// The markdown of the error-split table with a heading and what its columns mean.
pub fn split_section(table: &SplitTable) -> String {
    format!("## Which part of builtin's error each model removes\n\n{}\n{SPLIT_NOTE}\n", table.to_markdown())
}

/// `summary.md`: the title, the summary table, the per-phase and accuracy tables (none when no
/// statistics arrived), and what is missing.
pub fn write(dir: &Path, title: &str, tables: &Tables, missing: &[String]) -> Result<PathBuf, ReportError> {
    let path = dir.join("summary.md");
    let mut md = format!("# {title}\n\n{}\n{SUMMARY_NOTE}\n", tables.summary.to_markdown());
    if let Some(d) = &tables.details {
        let _ = write!(md, "\n{}\n{}", phases_section(&d.phases), accuracy_section(&d.accuracy, d.accuracy_rows));
    }
    if let Some(split) = &tables.split {
        let _ = write!(md, "\n{}", split_section(split));
    }
    if !missing.is_empty() {
        md.push_str("\n## Missing data\n\n");
        for m in missing {
            let _ = writeln!(md, "- {m}");
        }
    }
    std::fs::write(&path, &md).map_err(io(&path))?;
    Ok(path)
}
