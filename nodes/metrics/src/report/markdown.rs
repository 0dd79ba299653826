//! `summary.md`: the report's tables in markdown (also what `dc-metrics` prints).

use super::error::{io, ReportError};
use super::tables::{AccuracyTable, PhaseTable, SummaryTable, ACCURACY_NOTE, PHASES_NOTE, SUMMARY_NOTE};
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

/// `summary.md`: the title, the summary table, the per-phase and accuracy tables (`details`: none
/// when no statistics arrived), and what is missing.
pub fn write(
    dir: &Path,
    title: &str,
    summaries: &[ModelSummary],
    details: Option<(&[PhaseRow], &[AccuracyRow])>,
    missing: &[String],
) -> Result<PathBuf, ReportError> {
    let path = dir.join("summary.md");
    let mut md = format!("# {title}\n\n{}\n{SUMMARY_NOTE}\n", summary_markdown(summaries));
    if let Some((phases, accuracy)) = details {
        let _ = write!(md, "\n{}\n{}", phases_markdown(phases), accuracy_markdown(accuracy));
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
