//! PNG charts (plotters, bitmap backend, a bundled font so no system font library is needed): line
//! charts with bands, scatter plots, labelled points, and panels stacked above one shared legend.
//!
//! Every series is drawn in the [`Style`] of its name ([`styles`]): a colour, a line style and a
//! marker. The two references always look the same (`builtin` solid black, `none` solid grey);
//! any other name (`unet`, `copy`, oracle ablations such as `blend:0.5`) gets a colour chosen from
//! a hash of its name among those no other series of the chart uses, so a report whose plots all
//! show the same models draws each model alike in every plot. The legend sits to the right of the
//! data area, never over it; count axes get whole-number ticks.

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::BTreeSet;
use std::path::Path;

/// One model's curve, optionally with a band (x, low, high) drawn beneath it.
pub struct Series {
    /// The legend's name; it also picks the style ([`styles`]).
    pub name: String,
    /// (x, y) in data units, in drawing order.
    pub points: Vec<(f64, f64)>,
    /// (x, low, high) of a shaded band beneath the line.
    pub band: Option<Vec<(f64, f64, f64)>>,
}

/// How an axis maps values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// The values as they are.
    Linear,
    /// log10 of the values; non-positive values are left out.
    Log,
}

/// How an axis's ticks are labelled.
#[derive(Debug, Clone, PartialEq)]
pub enum Ticks {
    /// As many decimals as the tick needs (`0`, `0.5`, `1`; `0.001`, `1e-6` on log axes).
    Auto,
    /// Whole numbers only (counts: steps, sweeps, contacts); ticks between them are not labelled.
    Integer,
    /// One category per whole x value 0, 1, 2, ... (e.g. histogram bins), labelled by name.
    Categories(Vec<String>),
}

/// One axis of a [`Panel`].
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// The axis description, with its unit.
    pub label: String,
    /// How values map onto the axis.
    pub scale: Scale,
    /// How the ticks are placed and labelled.
    pub ticks: Ticks,
    /// A linear axis reaches down (or up) to 0.
    pub include_zero: bool,
}

impl Axis {
    /// A linear axis with automatic ticks.
    pub fn linear(label: &str) -> Axis {
        Axis { label: label.into(), scale: Scale::Linear, ticks: Ticks::Auto, include_zero: false }
    }

    /// A log10 axis (non-positive values are left out).
    pub fn log(label: &str) -> Axis {
        Axis { scale: Scale::Log, ..Axis::linear(label) }
    }

    /// A linear count axis from 0 with whole-number ticks.
    pub fn counts(label: &str) -> Axis {
        Axis { ticks: Ticks::Integer, include_zero: true, ..Axis::linear(label) }
    }

    /// Categories at x = 0, 1, 2, ... labelled with `names`.
    pub fn categories(label: &str, names: Vec<String>) -> Axis {
        Axis { ticks: Ticks::Categories(names), ..Axis::linear(label) }
    }

    /// The same axis on `scale`.
    pub fn with_scale(self, scale: Scale) -> Axis {
        Axis { scale, ..self }
    }

    /// The same axis with whole-number ticks only.
    pub fn integer(self) -> Axis {
        Axis { ticks: Ticks::Integer, ..self }
    }

    /// The same axis reaching 0 (linear axes only).
    pub fn from_zero(self) -> Axis {
        Axis { include_zero: true, ..self }
    }
}

/// How a panel draws its series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// A line per series (dashed or dotted by style), markers on a few of its points, its band
    /// beneath it.
    Lines,
    /// A small translucent marker per point (scatter plots).
    Points,
    /// A large marker per point with the series' name beside it. On a log axis a point at a
    /// non-positive value sits at the axis's low end and its label says `(0)`.
    LabelledPoints,
}

/// One chart area: axes, series, how they are drawn, and dashed guide lines.
pub struct Panel<'a> {
    /// Shown above the panel (empty: none).
    pub title: String,
    /// The horizontal axis.
    pub x: Axis,
    /// The vertical axis.
    pub y: Axis,
    /// What is drawn; each series keeps its style across the chart's panels.
    pub series: &'a [Series],
    /// How the series are drawn.
    pub mark: Mark,
    /// Dashed grey lines at these x values (e.g. 1.0: "as builtin").
    pub x_guides: Vec<f64>,
    /// Dashed grey lines at these y values.
    pub y_guides: Vec<f64>,
}

impl<'a> Panel<'a> {
    /// A panel without title or guides.
    pub fn new(x: Axis, y: Axis, series: &'a [Series], mark: Mark) -> Panel<'a> {
        Panel { title: String::new(), x, y, series, mark, x_guides: Vec::new(), y_guides: Vec::new() }
    }

    /// The same panel with `title` above it.
    pub fn titled(self, title: &str) -> Panel<'a> {
        Panel { title: title.into(), ..self }
    }

    /// The same panel with dashed guide lines at these x and y values.
    pub fn guides(self, x: &[f64], y: &[f64]) -> Panel<'a> {
        Panel { x_guides: x.to_vec(), y_guides: y.to_vec(), ..self }
    }
}

/// A chart that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("plot {file}: {what}")]
pub struct PlotError {
    /// The PNG's path.
    pub file: String,
    /// What plotters reported.
    pub what: String,
}

/// How a line is stroked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dash {
    /// An unbroken line.
    Solid,
    /// Long dashes.
    Dashed,
    /// Short dots.
    Dotted,
}

/// The shape drawn at a series' points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marker {
    /// A filled circle.
    Circle,
    /// A filled triangle, point up.
    Triangle,
    /// A filled square.
    Square,
    /// A filled square on its corner.
    Diamond,
    /// An x.
    Cross,
}

/// How one series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Style {
    /// Line, band and marker colour.
    pub color: RGBColor,
    /// How the line is stroked.
    pub dash: Dash,
    /// The shape at the series' points.
    pub marker: Marker,
}

/// The 12 colours (grey and black for the references `none` and `builtin`, then Tableau/d3
/// category-10 less its grey, and navy), each with its line style and marker.
pub const SLOTS: [Style; 12] = [
    Style { color: RGBColor(0x7f, 0x7f, 0x7f), dash: Dash::Solid, marker: Marker::Square }, // grey
    Style { color: RGBColor(0x00, 0x00, 0x00), dash: Dash::Solid, marker: Marker::Circle }, // black
    Style { color: RGBColor(0xd6, 0x27, 0x28), dash: Dash::Solid, marker: Marker::Diamond }, // red
    Style { color: RGBColor(0x1f, 0x77, 0xb4), dash: Dash::Dashed, marker: Marker::Triangle }, // blue
    Style { color: RGBColor(0x2c, 0xa0, 0x2c), dash: Dash::Dotted, marker: Marker::Square }, // green
    Style { color: RGBColor(0xff, 0x7f, 0x0e), dash: Dash::Solid, marker: Marker::Circle }, // orange
    Style { color: RGBColor(0x94, 0x67, 0xbd), dash: Dash::Dashed, marker: Marker::Diamond }, // purple
    Style { color: RGBColor(0x8c, 0x56, 0x4b), dash: Dash::Dotted, marker: Marker::Cross }, // brown
    Style { color: RGBColor(0xe3, 0x77, 0xc2), dash: Dash::Solid, marker: Marker::Triangle }, // pink
    Style { color: RGBColor(0xbc, 0xbd, 0x22), dash: Dash::Dashed, marker: Marker::Square }, // olive
    Style { color: RGBColor(0x17, 0xbe, 0xcf), dash: Dash::Dotted, marker: Marker::Circle }, // cyan
    Style { color: RGBColor(0x1a, 0x23, 0x7e), dash: Dash::Dashed, marker: Marker::Cross }, // navy
];

const DASHES: [Dash; 3] = [Dash::Solid, Dash::Dashed, Dash::Dotted];
const MARKERS: [Marker; 5] = [Marker::Circle, Marker::Triangle, Marker::Square, Marker::Diamond, Marker::Cross];

/// The style of slot `slot`: [`SLOTS`] for the first 12; past them the colours repeat with the
/// next line style and marker (slot 12 + i differs from slot i in both).
pub fn slot_style(slot: usize) -> Style {
    let base = SLOTS[slot % SLOTS.len()];
    let round = slot / SLOTS.len();
    let dash = DASHES[(DASHES.iter().position(|&d| d == base.dash).unwrap_or(0) + round) % DASHES.len()];
    let marker = MARKERS[(MARKERS.iter().position(|&m| m == base.marker).unwrap_or(0) + round) % MARKERS.len()];
    Style { color: base.color, dash, marker }
}

/// 64-bit FNV-1a: a hash of a name that is the same on every machine and in every build.
fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Names with a slot of their own: the references every other model is compared with.
const FIXED: [(&str, usize); 2] = [("none", 0), ("builtin", 1)];

/// The style of each name (a repeated name gets the same style). `none` and `builtin` take their
/// own slots (grey, black); the other names, in sorted order, take the first slot from a hash of
/// the name onwards whose colour no other name uses (grey and black last); once all 12 colours are
/// taken, a free slot among the next 24 (same colours, other line style and marker). The result
/// depends only on the set of names: pass every model of a report to every plot and each model
/// looks alike in all of them.
pub fn styles(names: &[&str]) -> Vec<Style> {
    let n = SLOTS.len();
    let distinct: BTreeSet<&str> = names.iter().copied().collect();
    let mut slot: std::collections::BTreeMap<&str, usize> = std::collections::BTreeMap::new();
    for (name, s) in FIXED {
        if distinct.contains(name) {
            slot.insert(name, s);
        }
    }
    let free = n - FIXED.len();
    for &name in &distinct {
        if slot.contains_key(name) {
            continue;
        }
        let h = fnv1a(name) as usize;
        let used: BTreeSet<usize> = slot.values().copied().collect();
        let colour_free = |s: &usize| !used.iter().any(|&u| u % n == s % n);
        let pick = (0..free)
            .map(|k| FIXED.len() + (h + k) % free)
            .chain(FIXED.iter().map(|&(_, s)| s))
            .find(colour_free)
            .or_else(|| (0..2 * n).map(|k| n + (h + k) % (2 * n)).find(|s| !used.contains(s)))
            .unwrap_or(h % (3 * n));
        slot.insert(name, pick);
    }
    names.iter().map(|name| slot_style(slot[name])).collect()
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let font: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        if plotters::style::register_font("sans-serif", FontStyle::Normal, font).is_err() {
            tracing::warn!("bundled font did not load; plots will lack text");
        }
    });
}

/// Draws `panels` stacked top to bottom into a PNG at `path`, with `title` above them and one
/// legend (every series name of every panel, in order of first appearance) to their right.
pub fn chart(path: &Path, title: &str, panels: &[Panel]) -> Result<(), PlotError> {
    register_font();
    let err = |what: String| PlotError { file: path.display().to_string(), what };
    let mut names: Vec<&str> = Vec::new();
    for p in panels {
        for s in p.series {
            if !names.contains(&s.name.as_str()) {
                names.push(&s.name);
            }
        }
    }
    let style_list = styles(&names);
    let longest = names.iter().map(|n| legend_name(n).chars().count()).max().unwrap_or(0) as u32;
    let legend_w = (70 + 9 * longest).clamp(140, 320);
    let height = if panels.len() <= 1 { 600 } else { 50 + 330 * panels.len() as u32 };
    let width = 900 + legend_w;
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let body = root.titled(title, ("sans-serif", 24)).map_err(|e| err(e.to_string()))?;
    let (plots, legend) = body.split_horizontally(width - legend_w);
    let areas = plots.split_evenly((panels.len().max(1), 1));
    for (panel, area) in panels.iter().zip(&areas) {
        let style_of = |name: &str| style_list[names.iter().position(|n| *n == name).unwrap_or(0)];
        draw_panel(&root, area, panel, &style_of).map_err(err)?;
    }
    let lines = panels.iter().any(|p| p.mark == Mark::Lines);
    draw_legend(&legend, &names, &style_list, lines).map_err(err)?;
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

fn legend_name(name: &str) -> String {
    if name.chars().count() > 28 {
        name.chars().take(27).chain(std::iter::once('…')).collect()
    } else {
        name.to_string()
    }
}

fn transform(scale: Scale, v: f64) -> Option<f64> {
    match scale {
        Scale::Linear => v.is_finite().then_some(v),
        Scale::Log => (v > 0.0 && v.is_finite()).then(|| v.log10()),
    }
}

/// The drawn range of an axis over its (transformed) values.
fn axis_range(axis: &Axis, values: &[f64], pad_low: bool, pad_high: bool) -> (f64, f64) {
    if let Ticks::Categories(c) = &axis.ticks {
        return (-0.5, c.len().max(1) as f64 - 0.5);
    }
    let (mut lo, mut hi) = bounds(values);
    let from_zero = axis.scale == Scale::Linear && axis.include_zero;
    if from_zero {
        lo = lo.min(0.0);
        hi = hi.max(0.0);
    }
    let pad = (hi - lo) * 0.05;
    if pad_high && !(from_zero && hi == 0.0) {
        hi += pad;
    }
    if pad_low && !(from_zero && lo == 0.0) {
        lo -= pad;
    }
    (lo, hi)
}

/// The tick positions (in transformed coordinates) of an axis drawn over `lo..hi`, at most about
/// `most` of them: each category; multiples of a 1-2-5 step (at least 1 on integer axes); on log
/// axes whole decades, or 1-2-5 (then 1..9) times a decade when the range spans few decades.
fn ticks(axis: &Axis, lo: f64, hi: f64, most: usize) -> Vec<f64> {
    let most = most.max(2);
    let multiples = |step: f64| -> Vec<f64> {
        let first = (lo / step).ceil() as i64;
        let last = (hi / step).floor() as i64;
        (first..=last).map(|k| k as f64 * step).collect()
    };
    match (&axis.ticks, axis.scale) {
        (Ticks::Categories(c), _) => (0..c.len()).map(|i| i as f64).filter(|&v| v >= lo && v <= hi).collect(),
        (ticks, Scale::Linear) => {
            let span = (hi - lo).max(f64::MIN_POSITIVE);
            let mut step = nice_step(span / (most - 1) as f64);
            if *ticks == Ticks::Integer {
                step = step.max(1.0);
            }
            multiples(step)
        }
        (ticks, Scale::Log) => {
            let decades = hi - lo;
            let whole = |v: f64| *ticks != Ticks::Integer || v >= 1.0 - 1e-9;
            let times = |mantissas: &[f64]| -> Vec<f64> {
                let mut out = Vec::new();
                for e in lo.floor() as i32..=hi.ceil() as i32 {
                    for m in mantissas {
                        let v = (m * 10f64.powi(e)).log10();
                        if v >= lo - 1e-9 && v <= hi + 1e-9 && whole(10f64.powf(v)) {
                            out.push(v);
                        }
                    }
                }
                out
            };
            let one_two_five = times(&[1.0, 2.0, 5.0]);
            if one_two_five.len() < 3 {
                times(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
            } else if one_two_five.len() <= most && decades <= 3.0 {
                one_two_five
            } else {
                multiples(nice_step(decades / (most - 1) as f64).max(1.0))
            }
        }
    }
}

/// The smallest step of the 1-2-5 sequence (..., 0.1, 0.2, 0.5, 1, 2, 5, 10, ...) at least `raw`.
fn nice_step(raw: f64) -> f64 {
    let raw = if raw > 0.0 && raw.is_finite() { raw } else { 1.0 };
    let decade = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * decade).find(|&s| s >= raw * (1.0 - 1e-9)).unwrap_or(10.0 * decade)
}

/// A number with as few characters as it needs: `0`, `2.5`, `0.001`, `1e-4`, `150000`.
fn short_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() { "0".into() } else { "-".into() };
    }
    if v.abs() < 1e-3 || v.abs() >= 1e7 {
        let s = format!("{v:.1e}");
        return s.replace(".0e", "e");
    }
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// `v` rounded to three significant digits (a log tick's value without floating-point noise).
fn significant(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(2 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

/// The label of a tick at (transformed) position `v`.
fn tick_label(axis: &Axis, v: f64) -> String {
    let near_int = |v: f64| (v - v.round()).abs() < 1e-6;
    match (&axis.ticks, axis.scale) {
        (Ticks::Categories(c), _) => {
            if near_int(v) && v >= 0.0 {
                c.get(v.round() as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        }
        (_, Scale::Log) => short_number(significant(10f64.powf(v))),
        (Ticks::Integer, Scale::Linear) => {
            if near_int(v) {
                format!("{}", v.round() as i64)
            } else {
                String::new()
            }
        }
        (Ticks::Auto, Scale::Linear) => short_number(v),
    }
}

type Root<'b> = DrawingArea<BitMapBackend<'b>, Shift>;

fn draw_panel(root: &Root, area: &Root, p: &Panel, style_of: &dyn Fn(&str) -> Style) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    let tx = |v: f64| transform(p.x.scale, v);
    let ty = |v: f64| transform(p.y.scale, v);
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    let mut floored_x = false;
    let mut floored_y = false;
    for s in p.series {
        for &(x, y) in &s.points {
            match (tx(x), ty(y)) {
                (Some(x), Some(y)) => {
                    xs.push(x);
                    ys.push(y);
                }
                // Labelled points keep their place at a log axis's low end.
                (x, y) if p.mark == Mark::LabelledPoints && (x.is_some() || y.is_some()) => {
                    xs.extend(x);
                    ys.extend(y);
                    floored_x |= x.is_none();
                    floored_y |= y.is_none();
                }
                _ => {}
            }
        }
        for &(x, lo, hi) in s.band.iter().flatten() {
            if let Some(x) = tx(x) {
                xs.push(x);
                ys.extend([lo, hi].into_iter().filter_map(ty));
            }
        }
    }
    xs.extend(p.x_guides.iter().filter_map(|&g| tx(g)));
    ys.extend(p.y_guides.iter().filter_map(|&g| ty(g)));
    let points_mode = p.mark != Mark::Lines;
    let (mut x0, x1) = axis_range(&p.x, &xs, points_mode, points_mode);
    let (mut y0, y1) = axis_range(&p.y, &ys, p.y.scale == Scale::Log || points_mode, true);
    // Room at the low end for points at a non-positive value of a log axis.
    let (x_floor, y_floor) = (x0 - 0.1 * (x1 - x0), y0 - 0.1 * (y1 - y0));
    if floored_x {
        x0 -= 0.15 * (x1 - x0);
    }
    if floored_y {
        y0 -= 0.15 * (y1 - y0);
    }
    let mut x_ticks = ticks(&p.x, x0, x1, 11);
    let mut y_ticks = ticks(&p.y, y0, y1, 9);
    // Points at a non-positive value of a log axis sit at a tick labelled 0.
    let floor_x = floored_x.then_some(x_floor.max(x0));
    let floor_y = floored_y.then_some(y_floor.max(y0));
    x_ticks.extend(floor_x);
    y_ticks.extend(floor_y);

    let mut builder = ChartBuilder::on(area);
    builder.margin(10).margin_right(24).x_label_area_size(52).y_label_area_size(84);
    if !p.title.is_empty() {
        builder.caption(&p.title, ("sans-serif", 18));
    }
    let mut chart =
        builder.build_cartesian_2d(Ticked::new(x0..x1, x_ticks), Ticked::new(y0..y1, y_ticks)).map_err(e)?;
    let x_fmt = |v: &f64| if Some(*v) == floor_x { "0".into() } else { tick_label(&p.x, *v) };
    let y_fmt = |v: &f64| if Some(*v) == floor_y { "0".into() } else { tick_label(&p.y, *v) };
    chart
        .configure_mesh()
        .x_desc(p.x.label.as_str())
        .y_desc(p.y.label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(TRANSPARENT)
        .draw()
        .map_err(e)?;
    if xs.is_empty() || ys.is_empty() {
        let (xr, yr) = chart.plotting_area().get_pixel_range();
        let text =
            TextStyle::from(("sans-serif", 18).into_font()).color(&BLACK).pos(Pos::new(HPos::Center, VPos::Center));
        root.draw(&Text::new("no data", ((xr.start + xr.end) / 2, (yr.start + yr.end) / 2), text)).map_err(e)?;
    }
    let guide = BLACK.mix(0.45).stroke_width(1);
    for g in p.x_guides.iter().filter_map(|&g| tx(g)) {
        chart.draw_series(DashedLineSeries::new(vec![(g, y0), (g, y1)], 6, 4, guide)).map_err(e)?;
    }
    for g in p.y_guides.iter().filter_map(|&g| ty(g)) {
        chart.draw_series(DashedLineSeries::new(vec![(x0, g), (x1, g)], 6, 4, guide)).map_err(e)?;
    }

    match p.mark {
        Mark::Lines => {
            for (index, s) in p.series.iter().enumerate() {
                let style = style_of(&s.name);
                let color = style.color.to_rgba();
                if let Some(band) = &s.band {
                    let upper = band.iter().filter_map(|&(x, _, hi)| Some((tx(x)?, ty(hi)?)));
                    let lower = band.iter().rev().filter_map(|&(x, lo, _)| Some((tx(x)?, ty(lo)?)));
                    let polygon: Vec<(f64, f64)> = upper.chain(lower).collect();
                    if polygon.len() >= 3 {
                        chart
                            .draw_series(std::iter::once(Polygon::new(polygon, color.mix(0.12).filled())))
                            .map_err(e)?;
                    }
                }
                let points: Vec<(f64, f64)> = s.points.iter().filter_map(|&(x, y)| Some((tx(x)?, ty(y)?))).collect();
                let line = color.stroke_width(2);
                let drawn = match style.dash {
                    Dash::Solid => chart.draw_series(LineSeries::new(points.iter().copied(), line)).map(|_| ()),
                    Dash::Dashed => {
                        chart.draw_series(DashedLineSeries::new(points.iter().copied(), 9, 5, line)).map(|_| ())
                    }
                    Dash::Dotted => {
                        chart.draw_series(DashedLineSeries::new(points.iter().copied(), 2, 4, line)).map(|_| ())
                    }
                };
                drawn.map_err(e)?;
                // About ten markers per line, shifted per series so lines on top of each other
                // still show each marker.
                let every = (points.len() / 10).max(1);
                for &(x, y) in points.iter().skip((index * every / 3) % every).step_by(every) {
                    draw_marker(root, chart.backend_coord(&(x, y)), style.marker, 4, color.filled())?;
                }
            }
        }
        Mark::Points => {
            // Round robin over the series, so no model hides another wholesale.
            let longest = p.series.iter().map(|s| s.points.len()).max().unwrap_or(0);
            for i in 0..longest {
                for s in p.series {
                    let Some(&(x, y)) = s.points.get(i) else { continue };
                    if let (Some(x), Some(y)) = (tx(x), ty(y)) {
                        let style = style_of(&s.name);
                        let color = style.color.to_rgba().mix(0.45).filled();
                        draw_marker(root, chart.backend_coord(&(x, y)), style.marker, 3, color)?;
                    }
                }
            }
        }
        Mark::LabelledPoints => {
            let mut placed: Vec<PixelBox> = Vec::new();
            let mut labels = Vec::new();
            for s in p.series {
                for &(x, y) in &s.points {
                    let (px, py) = (tx(x), ty(y));
                    if px.is_none() && py.is_none() {
                        continue;
                    }
                    let at = chart.backend_coord(&(px.or(floor_x).unwrap_or(x0), py.or(floor_y).unwrap_or(y0)));
                    let label = if px.is_none() || py.is_none() { format!("{} (0)", s.name) } else { s.name.clone() };
                    placed.push(PixelBox::around(at, 8));
                    labels.push((s, at, label));
                }
            }
            let text = TextStyle::from(("sans-serif", 15).into_font()).color(&BLACK);
            let (xr, yr) = chart.plotting_area().get_pixel_range();
            let bounds = PixelBox { x0: xr.start, y0: yr.start, x1: xr.end, y1: yr.end };
            for (s, at, label) in &labels {
                let style = style_of(&s.name);
                draw_marker(root, *at, style.marker, 7, style.color.to_rgba().filled())?;
                let (w, h) = root.estimate_text_size(label, &text).map_err(e)?;
                let (spot, moved) = place_label(*at, (w as i32, h as i32), &placed, &bounds);
                if moved {
                    // The point of the label's box nearest the marker, horizontally.
                    let near = (at.0.clamp(spot.x0, spot.x1.max(spot.x0)), (spot.y0 + spot.y1) / 2);
                    root.draw(&PathElement::new(vec![*at, near], BLACK.mix(0.4).stroke_width(1))).map_err(e)?;
                }
                root.draw(&Text::new(label.clone(), (spot.x0, spot.y0), text.clone())).map_err(e)?;
                placed.push(spot);
            }
        }
    }
    Ok(())
}

/// A linear f64 axis with the given tick positions (and no light mesh lines).
struct Ticked {
    inner: RangedCoordf64,
    ticks: Vec<f64>,
}

impl Ticked {
    fn new(range: std::ops::Range<f64>, ticks: Vec<f64>) -> Ticked {
        Ticked { inner: range.into(), ticks }
    }
}

impl Ranged for Ticked {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.clone()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }
}

/// A rectangle in backend pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PixelBox {
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
}

impl PixelBox {
    fn around((x, y): (i32, i32), r: i32) -> PixelBox {
        PixelBox { x0: x - r, y0: y - r, x1: x + r, y1: y + r }
    }

    fn overlaps(&self, o: &PixelBox) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }

    fn inside(&self, o: &PixelBox) -> bool {
        self.x0 >= o.x0 && self.x1 <= o.x1 && self.y0 >= o.y0 && self.y1 <= o.y1
    }
}

/// Where a label of size `(w, h)` for the point at `at` goes: beside it (right, left, above,
/// below) if that spot is free of `taken` boxes and inside `bounds`, else further up or down the
/// right or left side (the bool: moved away, so a leader line should join it to its point).
fn place_label(at: (i32, i32), (w, h): (i32, i32), taken: &[PixelBox], bounds: &PixelBox) -> (PixelBox, bool) {
    let (x, y) = at;
    let r = 10;
    let rect = |x0: i32, y0: i32| PixelBox { x0, y0, x1: x0 + w, y1: y0 + h };
    let own = PixelBox::around(at, 8);
    let mut near = vec![
        rect(x + r, y - h / 2),
        rect(x + r, y - r / 2 - h),
        rect(x + r, y + r / 2),
        rect(x - r - w, y - h / 2),
        rect(x - r - w, y - r / 2 - h),
        rect(x - r - w, y + r / 2),
        rect(x - w / 2, y - r - h),
        rect(x - w / 2, y + r),
    ];
    let beside = near.len();
    for k in 1..=8 {
        let dy = k * (h + 3);
        for x0 in [x + r + 6, x - r - 6 - w] {
            near.push(rect(x0, y - h / 2 - dy));
            near.push(rect(x0, y - h / 2 + dy));
        }
    }
    let free = |b: &PixelBox| b.inside(bounds) && taken.iter().all(|t| *t == own || !t.overlaps(b));
    match near.iter().position(free) {
        Some(i) => (near[i], i >= beside),
        None => (near.iter().copied().find(|b| b.inside(bounds)).unwrap_or(near[0]), false),
    }
}

/// A marker of `size` pixels (radius) centred at backend pixel `at`.
fn draw_marker(area: &Root, at: (i32, i32), marker: Marker, size: i32, style: ShapeStyle) -> Result<(), String> {
    let (x, y) = at;
    let s = size;
    match marker {
        Marker::Circle => area.draw(&Circle::new((x, y), s, style)),
        Marker::Square => area.draw(&Rectangle::new([(x - s, y - s), (x + s, y + s)], style)),
        Marker::Triangle => {
            area.draw(&Polygon::new(vec![(x, y - s - 1), (x + s + 1, y + s), (x - s - 1, y + s)], style))
        }
        Marker::Diamond => {
            area.draw(&Polygon::new(vec![(x, y - s - 1), (x + s + 1, y), (x, y + s + 1), (x - s - 1, y)], style))
        }
        Marker::Cross => area.draw(&Cross::new((x, y), s, ShapeStyle { filled: false, stroke_width: 2, ..style })),
    }
    .map_err(|e| e.to_string())
}

/// The legend: per name a line sample (when the chart has lines) with its marker, and the name.
fn draw_legend(area: &Root, names: &[&str], styles: &[Style], lines: bool) -> Result<(), String> {
    let (_, h) = area.dim_in_pixel();
    let step = ((h as i32 - 50) / names.len().max(1) as i32).clamp(12, 24);
    let text = TextStyle::from(("sans-serif", 15).into_font()).color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
    let top = 40;
    for (i, (name, style)) in names.iter().zip(styles).enumerate() {
        let y = top + step * i as i32;
        let x = 8;
        let color = style.color.to_rgba();
        let line = color.stroke_width(2);
        let sample = vec![(x, y), (x + 40, y)];
        if lines {
            match style.dash {
                Dash::Solid => area.draw(&PathElement::new(sample, line)),
                Dash::Dashed => area.draw(&DashedPathElement::new(sample, 9, 5, line)),
                Dash::Dotted => area.draw(&DashedPathElement::new(sample, 2, 4, line)),
            }
            .map_err(|e| e.to_string())?;
        }
        draw_marker(area, (x + 20, y), style.marker, 5, color.filled())?;
        area.draw(&Text::new(legend_name(name), (x + 50, y), text.clone())).map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn bounds(v: &[f64]) -> (f64, f64) {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    match (lo.is_finite(), hi.is_finite()) {
        (true, true) if hi > lo => (lo, hi),
        (true, true) => (lo - 0.5, hi + 0.5),
        _ => (0.0, 1.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn references_keep_their_style_whatever_else_is_drawn() {
        let a = styles(&["builtin", "none", "unet"]);
        let b = styles(&["blend:0.5", "unet", "copy", "builtin", "none", "x", "y", "z"]);
        assert_eq!(a[0], Style { color: RGBColor(0, 0, 0), dash: Dash::Solid, marker: Marker::Circle });
        assert_eq!(a[0], b[3]);
        assert_eq!(a[1].color, RGBColor(0x7f, 0x7f, 0x7f), "none is grey");
        assert_eq!(a[1], b[4]);
        // Alone with the references, a name gets the slot of its hash.
        assert_eq!(a[2], styles(&["unet"])[0]);
        assert_ne!(styles(&["unet"])[0].color, RGBColor(0, 0, 0), "black is builtin's while any other is free");
    }

    #[test]
    fn styles_depend_on_the_set_of_names_not_their_order() {
        let names = ["copy", "blend:0.5", "blend:0.75", "noise:0.5", "builtin", "smooth-error"];
        let forward = styles(&names);
        let mut reversed_names = names;
        reversed_names.reverse();
        let mut reversed = styles(&reversed_names);
        reversed.reverse();
        assert_eq!(forward, reversed);
        // A repeated name gets the same style.
        let twice = styles(&["x", "y", "x"]);
        assert_eq!(twice[0], twice[2]);
    }

    #[test]
    fn up_to_twelve_names_get_twelve_colours_and_more_get_distinct_line_styles() {
        let names: Vec<String> = (0..12).map(|i| format!("model-{i}")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let colours: BTreeSet<(u8, u8, u8)> = styles(&refs).iter().map(|s| (s.color.0, s.color.1, s.color.2)).collect();
        assert_eq!(colours.len(), 12);
        let names: Vec<String> = (0..36).map(|i| format!("ablation:{i}")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let looks: BTreeSet<(u8, u8, u8, u8)> =
            styles(&refs).iter().map(|s| (s.color.0, s.color.1, s.color.2, s.dash as u8)).collect();
        assert_eq!(looks.len(), 36, "colour and line style tell 36 series apart");
    }

    #[test]
    fn tick_labels_are_short_and_whole_on_count_axes() {
        assert_eq!(short_number(14.0), "14");
        assert_eq!(short_number(0.25), "0.25");
        assert_eq!(short_number(1e-6), "1e-6");
        assert_eq!(short_number(-0.0), "0");
        let counts = Axis::counts("sweeps");
        assert_eq!(tick_label(&counts, 1000.0), "1000");
        assert_eq!(tick_label(&counts, 2.5), "");
        let log = Axis::log("MSE");
        assert_eq!(tick_label(&log, -3.0), "0.001");
        assert_eq!(tick_label(&log, 3.0), "1000");
        assert_eq!(tick_label(&log, -8.0), "1e-8");
        assert_eq!(tick_label(&log, 2f64.log10()), "2");
        assert_eq!(tick_label(&log, 0.5f64.log10()), "0.5");
        let bins = Axis::categories("bin", vec!["0".into(), "1".into(), "2-3".into()]);
        assert_eq!(tick_label(&bins, 2.0), "2-3");
        assert_eq!(tick_label(&bins, 1.5), "");
    }

    #[test]
    fn ticks_are_whole_on_count_axes_and_decades_or_1_2_5_on_log_axes() {
        let labels = |axis: &Axis, lo: f64, hi: f64, most: usize| -> Vec<String> {
            ticks(axis, lo, hi, most).into_iter().map(|v| tick_label(axis, v)).collect()
        };
        assert_eq!(labels(&Axis::counts("n"), 0.0, 3.2, 11), ["0", "1", "2", "3"]);
        assert_eq!(
            labels(&Axis::counts("n"), 0.0, 1000.0, 11),
            ["0", "100", "200", "300", "400", "500", "600", "700", "800", "900", "1000"]
        );
        assert_eq!(labels(&Axis::linear("share"), 0.0, 1.05, 9), ["0", "0.2", "0.4", "0.6", "0.8", "1"]);
        let log = Axis::log("MSE");
        assert_eq!(labels(&log, -6.2, 0.1, 11), ["1e-6", "1e-5", "1e-4", "0.001", "0.01", "0.1", "1"]);
        assert_eq!(labels(&log, -12.0, 0.0, 7), ["1e-12", "1e-10", "1e-8", "1e-6", "1e-4", "0.01", "1"]);
        assert_eq!(labels(&log, -1.05, 0.4, 9), ["0.1", "0.2", "0.5", "1", "2"]);
        assert_eq!(labels(&log, -0.2, 0.2, 9), ["0.7", "0.8", "0.9", "1", "2"][..4]);
        assert_eq!(labels(&Axis::log("sweeps").integer(), -0.5, 1.2, 9), ["1", "2", "5", "10"]);
        assert_eq!(labels(&Axis::categories("bin", vec!["a".into(), "b".into()]), -0.5, 1.5, 9), ["a", "b"]);
    }
}
