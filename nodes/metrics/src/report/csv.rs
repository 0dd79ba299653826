//! The report's five CSV files, and `steps.csv` read back.
//!
//! Each file but `steps.csv` has one row type whose fields are its columns, in order, so a column's
//! name and its cell are written in one place. `steps.csv` is `msgs::StepStats` itself: the file
//! `dc-metrics --from-steps` reads back ([`read_steps`]).

use super::error::{csv_error, io, ReportError};
use crate::aggregate::{Aggregate, ModelSummary, StepRecord};
use crate::completeness::Completeness;
use crate::phases::{AccuracyRow, PhaseRow, SweepHistograms};
use ::csv::{Reader, StringRecord, Writer};
use serde::{Serialize, Serializer};
use std::path::{Path, PathBuf};

/// A number as `Display` writes it (`900`, `0.25`, `NaN`; `Option<Num>`: an empty cell for none): the files' format from before they
/// were serialised (the csv crate writes floats as `900.0`).
#[derive(Debug, Clone, Copy, Default)]
struct Num(f64);

impl Serialize for Num {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(&self.0)
    }
}

/// `steps.csv`: every step, models in report order, simulations then steps in order. No steps:
/// an empty file (no header).
pub fn steps(dir: &Path, aggregate: &Aggregate, models: &[String]) -> Result<PathBuf, ReportError> {
    let path = dir.join("steps.csv");
    let e = csv_error(&path);
    let mut w = Writer::from_path(&path).map_err(&e)?;
    for r in models.iter().flat_map(|m| aggregate.records(m)) {
        w.serialize(&r.stats).map_err(&e)?;
    }
    w.flush().map_err(io(&path))?;
    Ok(path)
}

/// The steps of a report's `steps.csv` (what [`steps`] puts there), to build a report again — with
/// newer tables, or other phases — without running the simulations again. The per-sweep residuals
/// are not in the file: the records come back without them.
/// Only a regular file is read: a FIFO, a device (`/dev/zero`) or a folder is refused by its kind.
pub fn read_steps(path: &Path) -> Result<Vec<StepRecord>, ReportError> {
    let e = csv_error(path);
    let file = runtime::files::open_regular(path, "steps file")
        .map_err(|source| ReportError::Io { path: path.display().to_string(), source: source.into() })?;
    let mut reader = Reader::from_reader(file);
    reader
        .deserialize::<msgs::StepStats>()
        .map(|row| row.map(|stats| StepRecord { stats, residuals: Vec::new() }).map_err(&e))
        .collect()
}

/// The aggregate of a report's `steps.csv` (`dc-metrics --from-steps`), with the checks the live
/// path applies to every frame: an empty file, or an impossible or repeated step, is an error
/// naming the file and the CSV record (record 1 is the first row after the header), so a damaged
/// or edited file never moves a report's totals.
pub fn aggregate_steps(
    path: &Path,
    settle_speed: f32,
    phase_boundaries: Option<&[u32]>,
) -> Result<Aggregate, ReportError> {
    let records = read_steps(path)?;
    let refused = |why: String| ReportError::Steps { path: path.display().to_string(), why };
    if records.is_empty() {
        return Err(refused("no steps (an empty or header-only steps.csv): nothing to report".into()));
    }
    if let Some((i, why)) = Completeness::first_implausible(records.iter().map(|r| &r.stats)) {
        return Err(refused(format!("record {}: impossible statistics: {why}", i + 1)));
    }
    let mut aggregate = Aggregate::new();
    aggregate.settle_speed = settle_speed;
    aggregate.phase_boundaries = phase_boundaries.map(<[u32]>::to_vec);
    for r in records {
        aggregate.add(r);
    }
    Ok(aggregate)
}

/// A row of `summary.csv`: one model over all its simulations.
#[derive(Debug, Default, Serialize)]
struct SummaryRow<'a> {
    model: &'a str,
    simulations: usize,
    steps: usize,
    total_sweeps: u64,
    ratio_to_builtin: Option<Num>,
    same_states_ratio_to_builtin: Option<Num>,
    same_states_worst_simulation: Option<u32>,
    same_states_worst_ratio: Option<Num>,
    median_sweeps: Num,
    mean_sweeps: Num,
    falling_steps: usize,
    falling_total_sweeps: u64,
    falling_median_sweeps: Num,
    settled_steps: usize,
    settled_total_sweeps: u64,
    settled_median_sweeps: Num,
    cap_hits: usize,
    fallbacks: usize,
    persisting_share: Num,
    median_warm_error_normal_mse: Num,
    median_warm_error_tangent_mse: Num,
    median_solve_us: Num,
    median_step_us: Num,
    total_solve_ms: Num,
    median_critical_us: Num,
    mean_natural_rms: Num,
    mean_natural_max: Num,
    mean_penetration_max: Num,
    mean_penetration_mean: Num,
    late_kinetic_energy: Num,
    /// The error split (`--error-split`), RMS over the contacts; empty where not measured.
    split_contacts: Option<u64>,
    split_smooth_rms: Option<Num>,
    split_rough_rms: Option<Num>,
    split_builtin_smooth_rms: Option<Num>,
    split_builtin_rough_rms: Option<Num>,
    split_smooth_removed: Option<Num>,
    split_rough_removed: Option<Num>,
    split_left_rms: Option<Num>,
    split_builtin_left_rms: Option<Num>,
    split_left_natural: Option<Num>,
    split_builtin_left_natural: Option<Num>,
}

impl<'a> From<&'a ModelSummary> for SummaryRow<'a> {
    fn from(m: &'a ModelSummary) -> Self {
        SummaryRow {
            model: &m.model,
            simulations: m.simulations,
            steps: m.all.steps,
            total_sweeps: m.all.total_sweeps,
            ratio_to_builtin: m.ratio_to_builtin.map(Num),
            same_states_ratio_to_builtin: m.same_states.map(|p| Num(p.ratio)),
            same_states_worst_simulation: m.same_states.map(|p| p.worst_simulation),
            same_states_worst_ratio: m.same_states.map(|p| Num(p.worst_ratio)),
            median_sweeps: Num(m.all.median_sweeps),
            mean_sweeps: Num(m.all.mean_sweeps),
            falling_steps: m.falling.steps,
            falling_total_sweeps: m.falling.total_sweeps,
            falling_median_sweeps: Num(m.falling.median_sweeps),
            settled_steps: m.settled.steps,
            settled_total_sweeps: m.settled.total_sweeps,
            settled_median_sweeps: Num(m.settled.median_sweeps),
            cap_hits: m.all.cap_hits,
            fallbacks: m.all.fallbacks,
            persisting_share: Num(m.persisting_share),
            median_warm_error_normal_mse: Num(m.median_warm_error_normal_mse),
            median_warm_error_tangent_mse: Num(m.median_warm_error_tangent_mse),
            median_solve_us: Num(m.all.median_solve_us),
            median_step_us: Num(m.all.median_step_us),
            total_solve_ms: Num(m.all.total_solve_ms),
            median_critical_us: Num(m.all.median_critical_us),
            mean_natural_rms: Num(m.accuracy.natural_rms),
            mean_natural_max: Num(m.accuracy.natural_max),
            mean_penetration_max: Num(m.accuracy.penetration_max),
            mean_penetration_mean: Num(m.accuracy.penetration_mean),
            late_kinetic_energy: Num(m.accuracy.late_kinetic_energy),
            split_contacts: m.split.map(|s| s.n),
            split_smooth_rms: m.split.map(|s| Num(s.model_rms().0)),
            split_rough_rms: m.split.map(|s| Num(s.model_rms().1)),
            split_builtin_smooth_rms: m.split.map(|s| Num(s.builtin_rms().0)),
            split_builtin_rough_rms: m.split.map(|s| Num(s.builtin_rms().1)),
            split_smooth_removed: m.split.map(|s| Num(s.removed().0)),
            split_rough_removed: m.split.map(|s| Num(s.removed().1)),
            split_left_rms: m.split.map(|s| Num(s.left_rms().0)),
            split_builtin_left_rms: m.split.map(|s| Num(s.left_rms().1)),
            split_left_natural: m.split.map(|s| Num(s.left_natural().0)),
            split_builtin_left_natural: m.split.map(|s| Num(s.left_natural().1)),
        }
    }
}

/// `summary.csv`: a row per model.
pub fn summary(dir: &Path, summaries: &[ModelSummary]) -> Result<PathBuf, ReportError> {
    write_rows(dir.join("summary.csv"), summaries.iter().map(SummaryRow::from))
}

/// A row of `phases.csv`: one model's sweeps in one step range.
#[derive(Debug, Default, Serialize)]
struct PhasesRow<'a> {
    model: &'a str,
    phase: String,
    first_step: u32,
    /// Empty for the phase that runs to the end.
    last_step: Option<u32>,
    steps: usize,
    total_sweeps: u64,
    model_total_sweeps: u64,
    share_of_model: Num,
    ratio_to_builtin_total: Option<Num>,
    same_states_ratio: Option<Num>,
    cap_hits: usize,
    cap_sweeps: u64,
    cap_sweeps_share: Num,
    median_sweeps: Num,
    median_warm_error_normal_mse: Num,
}

impl<'a> From<&'a PhaseRow> for PhasesRow<'a> {
    fn from(r: &'a PhaseRow) -> Self {
        PhasesRow {
            model: &r.model,
            phase: r.phase.label(),
            first_step: r.phase.first,
            last_step: r.phase.end.map(|e| e.saturating_sub(1)),
            steps: r.steps,
            total_sweeps: r.total_sweeps,
            model_total_sweeps: r.model_total_sweeps,
            share_of_model: Num(r.share_of_model),
            ratio_to_builtin_total: r.ratio_to_builtin_total.map(Num),
            same_states_ratio: r.same_states_ratio.map(Num),
            cap_hits: r.cap_hits,
            cap_sweeps: r.cap_sweeps,
            cap_sweeps_share: Num(r.cap_sweeps_share),
            median_sweeps: Num(r.median_sweeps),
            median_warm_error_normal_mse: Num(r.median_warm_error_normal_mse),
        }
    }
}

/// `phases.csv`: a row per model and step-range phase.
pub fn phases(dir: &Path, rows: &[PhaseRow]) -> Result<PathBuf, ReportError> {
    write_rows(dir.join("phases.csv"), rows.iter().map(PhasesRow::from))
}

/// A row of `sweeps_histogram.csv`: one bin of one model's histogram in one phase.
#[derive(Debug, Default, Serialize)]
struct HistogramRow<'a> {
    model: &'a str,
    phase: String,
    bin_lo: u32,
    bin_hi: u32,
    /// Steps in the bin.
    steps: usize,
    /// Share of the phase's steps in the bin.
    fraction: Num,
}

/// `sweeps_histogram.csv`: a row per model, phase and bin.
pub fn sweeps_histogram(dir: &Path, histograms: &SweepHistograms) -> Result<PathBuf, ReportError> {
    let rows = histograms.histograms.iter().flat_map(|h| {
        histograms.bins.iter().zip(h.counts.iter().zip(&h.fractions)).map(|(b, (&steps, &fraction))| HistogramRow {
            model: &h.model,
            phase: h.phase.label(),
            bin_lo: b.lo,
            bin_hi: b.hi,
            steps,
            fraction: Num(fraction),
        })
    });
    write_rows(dir.join("sweeps_histogram.csv"), rows)
}

/// A row of `accuracy.csv`: one model's point on the accuracy -> sweeps curve.
#[derive(Debug, Default, Serialize)]
struct AccuracyCsvRow<'a> {
    model: &'a str,
    late_phase: String,
    late_steps_persisting: usize,
    median_warm_error_normal_mse: Num,
    mean_warm_error_normal_mse: Num,
    error_vs_builtin: Option<Num>,
    total_sweeps: u64,
    sweeps_vs_builtin: Option<Num>,
    late_sweeps: u64,
    late_sweeps_vs_builtin: Option<Num>,
    same_states_vs_builtin: Option<Num>,
    /// F when inside the measured blends; the place's label (`< 0`, `> 0.75`) in the next column.
    blend_fraction_by_error: Option<Num>,
    blend_place_by_error: Option<String>,
    blend_fraction_by_sweeps: Option<Num>,
    blend_place_by_sweeps: Option<String>,
    blend_placed_on_same_states: bool,
}

impl<'a> From<&'a AccuracyRow> for AccuracyCsvRow<'a> {
    fn from(r: &'a AccuracyRow) -> Self {
        AccuracyCsvRow {
            model: &r.model,
            late_phase: r.late_phase.label(),
            late_steps_persisting: r.late_steps,
            median_warm_error_normal_mse: Num(r.median_warm_error_normal_mse),
            mean_warm_error_normal_mse: Num(r.mean_warm_error_normal_mse),
            error_vs_builtin: r.error_vs_builtin.map(Num),
            total_sweeps: r.total_sweeps,
            sweeps_vs_builtin: r.sweeps_vs_builtin.map(Num),
            late_sweeps: r.late_sweeps,
            late_sweeps_vs_builtin: r.late_sweeps_vs_builtin.map(Num),
            same_states_vs_builtin: r.same_states_vs_builtin.map(Num),
            blend_fraction_by_error: r.blend_by_error.and_then(|f| f.fraction()).map(Num),
            blend_place_by_error: r.blend_by_error.map(|f| f.label()),
            blend_fraction_by_sweeps: r.blend_by_sweeps.and_then(|f| f.fraction()).map(Num),
            blend_place_by_sweeps: r.blend_by_sweeps.map(|f| f.label()),
            blend_placed_on_same_states: r.placed_on_same_states,
        }
    }
}

/// `accuracy.csv`: a row per model.
pub fn accuracy(dir: &Path, rows: &[AccuracyRow]) -> Result<PathBuf, ReportError> {
    write_rows(dir.join("accuracy.csv"), rows.iter().map(AccuracyCsvRow::from))
}

/// Writes `rows` to `path` under a header of the row type's field names, the header also when
/// there are no rows.
fn write_rows<R: Serialize + Default>(
    path: PathBuf,
    rows: impl IntoIterator<Item = R>,
) -> Result<PathBuf, ReportError> {
    let e = csv_error(&path);
    let mut w = Writer::from_path(&path).map_err(&e)?;
    let mut rows = rows.into_iter().peekable();
    if rows.peek().is_none() {
        w.write_record(&header::<R>().map_err(&e)?).map_err(&e)?;
    }
    for row in rows {
        w.serialize(row).map_err(&e)?;
    }
    w.flush().map_err(io(&path))?;
    Ok(path)
}

/// The header the csv crate writes above rows of type `R`. Serde names a struct's fields only
/// while serialising one, so a default row is written to memory and its header read back.
fn header<R: Serialize + Default>() -> Result<StringRecord, ::csv::Error> {
    let mut w = Writer::from_writer(Vec::new());
    w.serialize(R::default())?;
    w.flush()?;
    Reader::from_reader(w.get_ref().as_slice()).headers().cloned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_written_as_display_writes_them() {
        let mut w = Writer::from_writer(Vec::new());
        w.serialize((Num(900.0), Num(0.25), Num(f64::NAN), None::<Num>, Some(Num(1e-7)))).unwrap();
        w.flush().unwrap();
        assert_eq!(String::from_utf8_lossy(w.get_ref()), "900,0.25,NaN,,0.0000001\n");
    }

    #[test]
    fn an_empty_table_keeps_its_header() {
        let dir = std::env::temp_dir().join(format!("dc-metrics-{}-csv-header", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = accuracy(&dir, &[]).unwrap();
        let text = std::fs::read_to_string(path).unwrap();
        assert!(
            text.starts_with("model,late_phase,late_steps_persisting,")
                && text.ends_with(",blend_placed_on_same_states\n")
        );
        assert_eq!(text.lines().count(), 1);
        assert_eq!(header::<SummaryRow>().unwrap().len(), 41);
    }
}
