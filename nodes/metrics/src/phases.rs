//! Where the sweeps are spent: runs split into step ranges ("phases" by step number, e.g. 0-99,
//! 100-149, 150-end: the late phase is where the piles jam), per model and phase the sweeps and
//! their share, the sweeps histogram, the per-step (warm-start error, sweeps) pairs, and the
//! accuracy -> sweeps table (late-phase warm-start error and total sweeps, both relative to
//! `builtin`).
//!
//! These phases are fixed step ranges, the same for every model and simulation, so models compare
//! like for like; the falling / settled split of the summary depends on each simulation's bodies
//! instead. The tables are computed from the records by `Aggregate` (`phase_rows`, `accuracy`,
//! `sweeps_histograms`); this module holds their rows and the blend curve, and knows no records.

use msgs::curve::blend_place;
pub use msgs::curve::BlendPlace;
use serde::Serialize;

/// The default phase boundaries: steps 0-99, 100-149 and 150-end.
pub const DEFAULT_PHASE_BOUNDARIES: [u32; 2] = [100, 150];

/// Steps `first..end` of every simulation (`end` exclusive; `None`: to the last step).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct StepRange {
    pub first: u32,
    pub end: Option<u32>,
}

impl StepRange {
    /// The ranges between `boundaries` (each the first step of a range after the first): `[100,
    /// 150]` -> 0-99, 100-149, 150-end; none -> 0-end. Boundaries are sorted, repeats and 0 are
    /// dropped.
    pub fn from_boundaries(boundaries: &[u32]) -> Vec<StepRange> {
        let mut b: Vec<u32> = boundaries.iter().copied().filter(|&b| b > 0).collect();
        b.sort_unstable();
        b.dedup();
        let starts = std::iter::once(0).chain(b.iter().copied());
        let ends = b.iter().copied().map(Some).chain(std::iter::once(None));
        starts.zip(ends).map(|(first, end)| StepRange { first, end }).collect()
    }

    pub fn contains(&self, step: u32) -> bool {
        step >= self.first && self.end.is_none_or(|end| step < end)
    }

    /// `0-99`, `150-end`.
    pub fn label(&self) -> String {
        match self.end {
            Some(end) => format!("{}-{}", self.first, end.saturating_sub(1)),
            None => format!("{}-end", self.first),
        }
    }
}

/// Checks phase boundaries given by hand: positive and strictly increasing.
pub fn check_boundaries(boundaries: &[u32]) -> Result<(), String> {
    if boundaries.contains(&0) {
        return Err("phase boundaries are first steps of later phases: 0 is not one".into());
    }
    if boundaries.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!("phase boundaries must increase strictly, got {boundaries:?}"));
    }
    Ok(())
}

/// Parses phase boundaries written `100,150` (spaces allowed; empty: none) and checks them.
pub fn parse_boundaries(s: &str) -> Result<Vec<u32>, String> {
    let b = s
        .split(',')
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .map(|p| p.parse::<u32>().map_err(|e| format!("`{p}`: {e}")))
        .collect::<Result<Vec<u32>, String>>()?;
    check_boundaries(&b)?;
    Ok(b)
}

/// One model's sweeps in one phase.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhaseRow {
    pub model: String,
    pub phase: StepRange,
    pub steps: usize,
    pub total_sweeps: u64,
    /// The model's total sweeps over all phases.
    pub model_total_sweeps: u64,
    /// `total_sweeps / model_total_sweeps` (0..1; NaN when the model spent no sweeps).
    pub share_of_model: f64,
    /// `total_sweeps / builtin's total sweeps over all phases` (None without a builtin run, or
    /// when builtin spent no sweeps).
    pub ratio_to_builtin_total: Option<f64>,
    /// The phase's sweeps over builtin's on the same step problems (None unless every step of
    /// the phase measured builtin alongside, or builtin needed none there).
    pub same_states_ratio: Option<f64>,
    /// Steps that hit the sweep cap (not converged).
    pub cap_hits: usize,
    /// Sweeps of those steps.
    pub cap_sweeps: u64,
    /// `cap_sweeps / model_total_sweeps` (NaN when the model spent no sweeps).
    pub cap_sweeps_share: f64,
    pub median_sweeps: f64,
    /// Median over the phase's steps with contacts of the warm start's normal MSE.
    pub median_warm_error_normal_mse: f64,
}

/// A bin of sweeps per step, `lo..=hi`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct SweepBin {
    pub lo: u32,
    pub hi: u32,
}

impl SweepBin {
    /// `0`, `1`, `2-3`, `512-1023`.
    pub fn label(&self) -> String {
        if self.lo == self.hi {
            self.lo.to_string()
        } else {
            format!("{}-{}", self.lo, self.hi)
        }
    }

    /// Log-spaced bins 0 (with `zero`), 1, 2-3, 4-7, ... up to the one holding `max`.
    pub fn log2_bins(max: u32, zero: bool) -> Vec<SweepBin> {
        let top = 32 - max.max(1).leading_zeros(); // bins 1..=top: [2^(k-1), 2^k - 1]
        let zero = zero.then_some(SweepBin { lo: 0, hi: 0 });
        zero.into_iter()
            .chain(
                (1..=top)
                    .map(|k| SweepBin { lo: 1u32 << (k - 1), hi: if k == 32 { u32::MAX } else { (1u32 << k) - 1 } }),
            )
            .collect()
    }
}

/// One model's steps in one phase, counted per [`SweepBin`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepHistogram {
    pub model: String,
    pub phase: StepRange,
    pub steps: usize,
    /// Steps per bin (the bins of [`SweepHistograms::bins`]).
    pub counts: Vec<usize>,
    /// `counts / steps` (all 0 for a phase without steps).
    pub fractions: Vec<f64>,
}

/// Sweeps histograms of every model and phase over the same bins.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SweepHistograms {
    pub bins: Vec<SweepBin>,
    /// Models in the report's order (`Aggregate::model_order`), phases in order within each.
    pub histograms: Vec<SweepHistogram>,
}

/// One model's point on the accuracy -> sweeps curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AccuracyRow {
    pub model: String,
    /// The late phase: the last of the step ranges.
    pub late_phase: StepRange,
    /// Late-phase steps with persisting contacts (those the warm-start error is taken over).
    pub late_steps: usize,
    /// Median / mean over those steps of the warm start's normal MSE.
    pub median_warm_error_normal_mse: f64,
    pub mean_warm_error_normal_mse: f64,
    /// The median relative to builtin's (builtin: 1.0; None without builtin or when its median is
    /// 0 or undefined).
    pub error_vs_builtin: Option<f64>,
    pub total_sweeps: u64,
    /// Total sweeps relative to builtin's (builtin: 1.0).
    pub sweeps_vs_builtin: Option<f64>,
    /// Sweeps of every late-phase step, and relative to builtin's.
    pub late_sweeps: u64,
    pub late_sweeps_vs_builtin: Option<f64>,
    /// Total sweeps over builtin's on the very same step problems (None unless every step
    /// measured builtin alongside).
    pub same_states_vs_builtin: Option<f64>,
    /// Where the model sits on the oracle ablation curve `blend:F` of the same run: the F whose
    /// blend leaves the same late-phase error, and the F whose blend needs as many sweeps (see
    /// [`BlendPlacement`]).
    pub blend_by_error: Option<BlendPlace>,
    pub blend_by_sweeps: Option<BlendPlace>,
    /// Whether `blend_by_sweeps` (and the accuracy plot) compare sweeps on the same states (every
    /// model of the table measured them) or over whole runs.
    pub placed_on_same_states: bool,
}

impl AccuracyRow {
    /// The sweeps ratio the placement and the accuracy plot use (same states or whole runs).
    pub fn placement_sweeps(&self) -> Option<f64> {
        if self.placed_on_same_states {
            self.same_states_vs_builtin
        } else {
            self.sweeps_vs_builtin
        }
    }
}

/// How far apart (in F) a model's two places on the blend curve must be before the report calls
/// its sweeps cheaper or dearer than its accuracy suggests.
pub const PLACEMENT_MARGIN: f64 = 0.02;

/// Sweep ratios the report translates into the blend they need: the learned warm start's
/// milestone (0.85x builtin's sweeps) and target (0.5x).
pub const REFERENCE_SWEEP_RATIOS: [f64; 2] = [0.85, 0.5];

/// One sentence saying which blend each reference sweep ratio needs (`> F` beyond the blends
/// measured), then one per model off the curve (not builtin, not a blend or copy) placed both ways: where it sits on the
/// oracle ablation curve, and what the gap between its two places says.
pub fn placement_notes(rows: &[AccuracyRow]) -> Vec<String> {
    let Some(first) = rows.first() else { return Vec::new() };
    let basis = if first.placed_on_same_states { "on the same states" } else { "over whole runs" };
    let curve = BlendPlacement::of_table(rows);
    let needs: Vec<String> = REFERENCE_SWEEP_RATIOS
        .iter()
        .filter_map(|&target| Some(format!("{target}x needs blend F {}", curve.as_ref()?.by_sweeps(target)?.label())))
        .collect();
    let reference = (!needs.is_empty()).then(|| format!("Of builtin's sweeps {basis}, {}.", needs.join(", ")));
    let models =
        rows.iter().filter(|r| r.model != "builtin" && blend_fraction_of(&r.model).is_none()).filter_map(|r| {
            let (by_error, by_sweeps) = (r.blend_by_error?, r.blend_by_sweeps?);
            let (error, sweeps) = (r.error_vs_builtin?, r.placement_sweeps()?);
            let (e, s) = (by_error.position(), by_sweeps.position());
            let beyond = |p: BlendPlace| matches!(p, BlendPlace::Beyond(_));
            let why = if beyond(by_error) && beyond(by_sweeps) {
                "beyond every blend measured by both measures"
            } else if e <= PLACEMENT_MARGIN && s <= PLACEMENT_MARGIN {
                "no gain over builtin by either measure"
            } else if s < e - PLACEMENT_MARGIN {
                "its sweeps buy less than its accuracy suggests: the error it removes is error PGS removes cheaply"
            } else if s > e + PLACEMENT_MARGIN {
                "its sweeps buy more than its accuracy suggests: the error it leaves is error PGS removes cheaply"
            } else {
                "on the curve: its sweeps are what its accuracy predicts"
            };
            Some(format!(
                "`{}`: sweeps {basis} {sweeps:.3}x builtin's (blend F {}), late-phase error {error:.3}x builtin's \
             (blend F {}) — {why}.",
                r.model,
                by_sweeps.label(),
                by_error.label()
            ))
        });
    reference.into_iter().chain(models).collect()
}

/// The oracle ablation curve of one run — builtin at F = 0, each `blend:F` (0 < F <= 1), and
/// `copy` (the oracle itself) at F = 1 — as (F, late-phase error vs builtin, sweeps vs builtin)
/// points, and its inverse: which F matches a given error or sweeps ratio.
///
/// Placing a model twice on it says *why* its sweeps are what they are: a model whose sweeps
/// match a smaller F than its error does removes error PGS would have removed cheaply anyway.
#[derive(Debug, Clone, PartialEq)]
pub struct BlendPlacement {
    /// (F, error ratio, sweeps ratio), sorted by F, one per F.
    pub points: Vec<(f64, f64, f64)>,
}

/// F of an oracle ablation name: `blend:F` with 0 < F <= 1, `copy` (the oracle) 1.
pub fn blend_fraction_of(model: &str) -> Option<f64> {
    if model == "copy" {
        return Some(1.0);
    }
    let f: f64 = model.strip_prefix("blend:")?.trim().parse().ok()?;
    (f > 0.0 && f <= 1.0).then_some(f)
}

impl BlendPlacement {
    /// The curve from `(model, error ratio, sweeps ratio)` rows: builtin at (0, 1, 1), the blends
    /// and copy with both ratios known; a `blend:1` wins over `copy`. None without a blend
    /// strictly between builtin and the oracle.
    pub fn from_rows<'a>(rows: impl IntoIterator<Item = (&'a str, Option<f64>, Option<f64>)>) -> Option<Self> {
        let mut points = vec![(0.0, 1.0, 1.0)];
        for (model, error, sweeps) in rows {
            if let (Some(f), Some(e), Some(s)) = (blend_fraction_of(model), error, sweeps) {
                if e.is_finite() && s.is_finite() && (model != "copy" || !points.iter().any(|p| p.0 == 1.0)) {
                    points.retain(|p| p.0 != f);
                    points.push((f, e, s));
                }
            }
        }
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        // builtin and the oracle alone are no curve: the sweeps between them are far from a line.
        points.iter().any(|p| p.0 > 0.0 && p.0 < 1.0).then_some(BlendPlacement { points })
    }

    /// The curve of an accuracy table's rows (their placement sweeps: same states or whole runs).
    pub fn of_table(rows: &[AccuracyRow]) -> Option<Self> {
        Self::from_rows(rows.iter().map(|r| (r.model.as_str(), r.error_vs_builtin, r.placement_sweeps())))
    }

    /// The F whose blend leaves this late-phase error (relative to builtin's). A blend leaves
    /// (1 - F)^2 of builtin's squared error, so the curve is interpolated in the error's square
    /// root, where it is a line.
    pub fn by_error(&self, error_vs_builtin: f64) -> Option<BlendPlace> {
        let root = |e: f64| e.max(0.0).sqrt();
        blend_place(self.points.iter().map(|p| (p.0, root(p.1))), root(error_vs_builtin))
    }

    /// The F whose blend needs this many sweeps (relative to builtin's).
    pub fn by_sweeps(&self, sweeps_vs_builtin: f64) -> Option<BlendPlace> {
        blend_place(self.points.iter().map(|p| (p.0, p.2)), sweeps_vs_builtin)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_from_boundaries() {
        let r = StepRange::from_boundaries(&[100, 150]);
        assert_eq!(r.iter().map(StepRange::label).collect::<Vec<_>>(), ["0-99", "100-149", "150-end"]);
        assert!(r[0].contains(0) && r[0].contains(99) && !r[0].contains(100));
        assert!(r[2].contains(150) && r[2].contains(u32::MAX));
        assert_eq!(StepRange::from_boundaries(&[]), vec![StepRange { first: 0, end: None }]);
        assert_eq!(StepRange::from_boundaries(&[50, 0, 20, 50]).len(), 3, "sorted, 0 and repeats dropped");
        assert!(check_boundaries(&[100, 150]).is_ok());
        assert!(check_boundaries(&[]).is_ok());
        assert!(check_boundaries(&[150, 100]).is_err());
        assert!(check_boundaries(&[0, 100]).is_err());
        assert!(check_boundaries(&[100, 100]).is_err());
        assert_eq!(parse_boundaries("100,150").unwrap(), DEFAULT_PHASE_BOUNDARIES, "the CLI's default");
        assert_eq!(parse_boundaries(" 50 , 200 ").unwrap(), [50, 200]);
        assert_eq!(parse_boundaries("").unwrap(), Vec::<u32>::new());
        assert!(parse_boundaries("150,100").is_err());
        assert!(parse_boundaries("10,x").unwrap_err().contains("`x`"));
    }

    #[test]
    fn blend_curve_is_inverted_piecewise_linearly() {
        let rows = [
            ("builtin", Some(1.0), Some(1.0)),
            ("blend:0.5", Some(0.25), Some(0.8)),
            ("blend:0.75", Some(0.0625), Some(0.5)),
            ("gnn", Some(0.5), Some(1.0)),
            ("blend:1.5", Some(0.1), Some(0.1)),
            ("blend:0.9", None, Some(0.5)),
        ];
        let c = BlendPlacement::from_rows(rows).unwrap();
        assert_eq!(
            c.points,
            [(0.0, 1.0, 1.0), (0.5, 0.25, 0.8), (0.75, 0.0625, 0.5)],
            "blends out of 0..1 or unmeasured left out"
        );
        assert_eq!(c.by_error(0.25), Some(BlendPlace::At(0.5)));
        assert_eq!(c.by_error(1.0), Some(BlendPlace::At(0.0)));
        assert_eq!(c.by_sweeps(0.9), Some(BlendPlace::At(0.25)));
        assert!((c.by_sweeps(0.65).unwrap().fraction().unwrap() - 0.625).abs() < 1e-12);
        // Outside the measured blends: worse than builtin, or better than the best blend.
        assert_eq!(c.by_sweeps(1.1), Some(BlendPlace::BelowBuiltin));
        assert_eq!(c.by_error(0.01), Some(BlendPlace::Beyond(0.75)));
        assert_eq!(c.by_sweeps(f64::NAN), None);
        let labels = [BlendPlace::At(0.123), BlendPlace::BelowBuiltin, BlendPlace::Beyond(0.75)].map(|p| p.label());
        assert_eq!(labels, ["0.12", "< 0", "> 0.75"]);
        assert_eq!(BlendPlace::BelowBuiltin.position(), 0.0);
        assert_eq!(BlendPlace::Beyond(0.75).fraction(), None);
        // The error is interpolated in its square root: halfway in F leaves a quarter.
        let c =
            BlendPlacement::from_rows([("blend:0.5", Some(0.25), Some(0.8)), ("copy", Some(0.0), Some(0.01))]).unwrap();
        assert_eq!(c.by_error(0.5625), Some(BlendPlace::At(0.25)));
        // copy is blend:1 unless a blend:1 was run; builtin and the oracle alone are no curve.
        let rows =
            [("blend:1", Some(0.01), Some(0.02)), ("copy", Some(0.0), Some(0.01)), ("blend:0.5", Some(0.3), Some(0.8))];
        let c = BlendPlacement::from_rows(rows).unwrap();
        assert_eq!(c.points, [(0.0, 1.0, 1.0), (0.5, 0.3, 0.8), (1.0, 0.01, 0.02)]);
        assert_eq!(BlendPlacement::from_rows([("copy", Some(0.0), Some(0.01))]), None);
        assert_eq!(BlendPlacement::from_rows([("gnn", Some(0.5), Some(0.9))]), None);
        assert_eq!(blend_fraction_of("blend: 0.25"), Some(0.25));
        assert_eq!(blend_fraction_of("blend:0"), None);
        assert_eq!(blend_fraction_of("blend"), None);
        assert_eq!(blend_fraction_of("copy-new"), None);
    }

    #[test]
    fn log2_bins_cover_every_count_once() {
        let bins = SweepBin::log2_bins(1000, true);
        assert_eq!(bins.iter().map(SweepBin::label).collect::<Vec<_>>()[..4], ["0", "1", "2-3", "4-7"]);
        assert_eq!(bins.last().unwrap().label(), "512-1023");
        for s in 0..=1000u32 {
            assert_eq!(bins.iter().filter(|b| (b.lo..=b.hi).contains(&s)).count(), 1, "{s}");
        }
        assert_eq!(SweepBin::log2_bins(1024, false).last().unwrap().label(), "1024-2047");
        assert_eq!(SweepBin::log2_bins(0, false), vec![SweepBin { lo: 1, hi: 1 }]);
        assert_eq!(SweepBin::log2_bins(u32::MAX, false).len(), 32);
    }
}
