//! The report's PNG plots: the sweeps histogram of the phase section, the accuracy -> sweeps and
//! sweeps-vs-error plots of the accuracy section, and the per-step curves.

use super::error::ReportError;
use crate::aggregate::{Aggregate, StepRecord};
use crate::phases::{AccuracyRow, SweepHistograms};
use charts::{chart, Axis, Mark, Panel, Scale, Series};
use std::path::{Path, PathBuf};

/// At most this many points per model in the sweeps-vs-error scatter plot.
pub const SCATTER_POINTS_PER_MODEL: usize = 3000;

/// A written plot.
#[derive(Debug, Clone, PartialEq)]
pub struct Plot {
    /// What the plot shows (its title, and its heading on the page).
    pub caption: String,
    /// The PNG.
    pub path: PathBuf,
}

/// The report's plots by the section of the page that shows them.
#[derive(Debug, Default)]
pub struct Plots {
    /// The sweeps histogram.
    pub phases: Vec<Plot>,
    /// Accuracy -> sweeps (when some model has a point) and sweeps vs warm-start error.
    pub accuracy: Vec<Plot>,
    /// The per-step curves, each a section of its own.
    pub per_step: Vec<Plot>,
}

impl Plots {
    /// Every PNG, in page order.
    pub fn files(&self) -> impl Iterator<Item = &PathBuf> {
        self.phases.iter().chain(&self.accuracy).chain(&self.per_step).map(|p| &p.path)
    }
}

/// Draws every plot of `aggregate` into `dir` (none when it is empty).
pub fn write(
    dir: &Path,
    aggregate: &Aggregate,
    models: &[String],
    histograms: &SweepHistograms,
    accuracy: &[AccuracyRow],
) -> Result<Plots, ReportError> {
    if aggregate.is_empty() {
        return Ok(Plots::default());
    }
    Ok(Plots {
        phases: vec![sweeps_histogram(dir, aggregate, histograms)?],
        accuracy: accuracy_vs_sweeps(dir, accuracy)?
            .into_iter()
            .chain([sweeps_vs_warm_error(dir, aggregate, models)?])
            .collect(),
        per_step: per_step_curves(dir, aggregate, models)?,
    })
}

/// Draws `panels` into `dir/file` under `caption`.
fn draw(dir: &Path, file: &str, caption: &str, panels: &[Panel]) -> Result<Plot, ReportError> {
    let path = dir.join(file);
    chart(&path, caption, panels)?;
    Ok(Plot { caption: caption.into(), path })
}

/// Sweeps histogram: a panel per phase, a line per model.
fn sweeps_histogram(dir: &Path, aggregate: &Aggregate, histograms: &SweepHistograms) -> Result<Plot, ReportError> {
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
    draw(dir, "sweeps_histogram.png", caption, &panels)
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

/// The accuracy -> sweeps curve: one labelled point per model, relative to builtin; none when no
/// model has both ratios.
fn accuracy_vs_sweeps(dir: &Path, accuracy: &[AccuracyRow]) -> Result<Option<Plot>, ReportError> {
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
    if located().next().is_none() {
        return Ok(None);
    }
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
    let zoom = Panel::new(Axis::linear(&x_label).from_zero(), Axis::linear(y_label), &near, Mark::LabelledPoints)
        .titled("near builtin (error <= 2x, sweeps 0.5x-1.5x)")
        .guides(&[1.0], &[1.0]);
    let file = "accuracy_vs_sweeps.png";
    let plot = if inside >= 2 && inside < located().count() {
        draw(dir, file, caption, &[panel.titled("all models"), zoom])?
    } else {
        draw(dir, file, caption, &[panel])?
    };
    Ok(Some(plot))
}

/// Per step: sweeps against the warm start's error.
fn sweeps_vs_warm_error(dir: &Path, aggregate: &Aggregate, models: &[String]) -> Result<Plot, ReportError> {
    let scatter = per_model(models, |m| aggregate.sweeps_vs_warm_error(m, SCATTER_POINTS_PER_MODEL));
    let caption =
        format!("Sweeps vs warm-start error per step (every k-th step, at most {SCATTER_POINTS_PER_MODEL} per model)");
    let panel = Panel::new(
        Axis::log("warm-start MSE of the normal impulse per step ((N·s)²)"),
        Axis::log("sweeps per step").integer(),
        &scatter,
        Mark::Points,
    );
    draw(dir, "sweeps_vs_warm_error.png", &caption, &[panel])
}

/// A series per model, named by the model, with `points` of it and no band.
fn per_model(models: &[String], points: impl Fn(&str) -> Vec<(f64, f64)>) -> Vec<Series> {
    models.iter().map(|m| Series { name: m.clone(), points: points(m), band: None }).collect()
}

/// A per-step curve: its file, caption, y axis, the statistic whose median across simulations
/// it draws, and whether the 10-90% band is drawn beneath it.
type PerStep = (&'static str, &'static str, fn() -> Axis, fn(&StepRecord) -> f64, bool);

/// The per-step curves, in page order.
const PER_STEP: [PerStep; 6] = [
    (
        "sweeps_per_step.png",
        "Sweeps per step (median, 10-90% band across simulations)",
        || Axis::counts("sweeps per step"),
        |r| r.sweeps as f64,
        true,
    ),
    (
        "contacts_per_step.png",
        "Contacts per step (median, 10-90% band)",
        || Axis::counts("contacts"),
        |r| r.contacts as f64,
        true,
    ),
    (
        "solve_time_per_step.png",
        "Solve time per step (velocity solve only, median)",
        || Axis::linear("solve time (µs)").from_zero(),
        |r| r.solve_us as f64,
        false,
    ),
    (
        "step_time_per_step.png",
        "Whole step time (collision + warm start + solve + integrate, median)",
        || Axis::linear("step time (µs)").from_zero(),
        |r| r.step_us as f64,
        false,
    ),
    (
        "warm_error_normal.png",
        "Warm-start error vs solution, normal impulse (median MSE)",
        || Axis::log("MSE ((N·s)²)"),
        |r| r.warm_error_normal_mse as f64,
        false,
    ),
    (
        "warm_error_tangent.png",
        "Warm-start error vs solution, tangent impulse (median MSE)",
        || Axis::log("MSE ((N·s)²)"),
        |r| r.warm_error_tangent_mse as f64,
        false,
    ),
];

/// The per-step curves: a line per model of a statistic per step ([`PER_STEP`]), then the
/// convergence curves per sweep.
fn per_step_curves(dir: &Path, aggregate: &Aggregate, models: &[String]) -> Result<Vec<Plot>, ReportError> {
    let lines = |file: &str, caption: &str, x: Axis, y: Axis, series: Vec<Series>| {
        draw(dir, file, caption, &[Panel::new(x, y, &series, Mark::Lines)])
    };
    let mut plots = Vec::new();
    for (file, caption, y, statistic, band) in PER_STEP {
        let series = models
            .iter()
            .map(|m| {
                let b = aggregate.per_step(m, statistic);
                Series {
                    name: m.clone(),
                    points: b.iter().map(|b| (b.step as f64, b.median)).collect(),
                    band: band.then(|| b.iter().map(|b| (b.step as f64, b.p10, b.p90)).collect()),
                }
            })
            .collect();
        plots.push(lines(file, caption, Axis::counts("step"), y(), series)?);
    }
    let max_sweeps =
        models.iter().flat_map(|m| aggregate.records(m).map(|r| r.sweeps)).max().unwrap_or(1).clamp(1, 1000);
    plots.push(lines(
        "converged_within.png",
        "Share of steps converged within n sweeps",
        Axis::counts("sweeps n"),
        Axis::linear("share of steps").from_zero(),
        per_model(models, |m| {
            aggregate.converged_within(m, max_sweeps).into_iter().map(|(n, f)| (n as f64, f)).collect()
        }),
    )?);
    plots.push(lines(
        "convergence.png",
        "Convergence: median residual after n sweeps",
        Axis::counts("sweeps n"),
        Axis::log("largest impulse change (N·s)"),
        per_model(models, |m| aggregate.convergence(m, 1000).into_iter().map(|(n, r)| (n as f64, r)).collect()),
    )?);
    Ok(plots)
}
