//! PNG line charts (plotters, bitmap backend, a bundled font so no system font library is needed).

use plotters::prelude::*;
use std::path::Path;

/// One model's curve, optionally with a band (x, low, high) drawn beneath it.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub band: Option<Vec<(f64, f64, f64)>>,
}

/// How the y axis is drawn.
#[derive(Clone, Copy, PartialEq)]
pub enum YScale {
    Linear,
    /// log10 of the values; non-positive values are left out.
    Log,
}

#[derive(Debug, thiserror::Error)]
#[error("plot {file}: {what}")]
pub struct PlotError {
    pub file: String,
    pub what: String,
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

/// Draws `series` into a PNG at `path`.
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    y_scale: YScale,
) -> Result<(), PlotError> {
    register_font();
    let err = |what: String| PlotError { file: path.display().to_string(), what };
    let ty = |y: f64| match y_scale {
        YScale::Linear => Some(y),
        YScale::Log => (y > 0.0 && y.is_finite()).then(|| y.log10()),
    };
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for s in series {
        for &(x, y) in &s.points {
            if let Some(y) = ty(y).filter(|y| y.is_finite()) {
                xs.push(x);
                ys.push(y);
            }
        }
        for &(x, lo, hi) in s.band.iter().flatten() {
            xs.push(x);
            ys.extend([lo, hi].into_iter().filter_map(ty).filter(|y| y.is_finite()));
        }
    }
    let (x0, x1) = bounds(&xs);
    let (mut y0, mut y1) = bounds(&ys);
    if y_scale == YScale::Linear && y0 > 0.0 {
        y0 = 0.0;
    }
    let pad = (y1 - y0) * 0.05;
    y1 += pad;
    if y_scale == YScale::Log {
        y0 -= pad;
    }

    let root = BitMapBackend::new(path, (1000, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 24))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(e.to_string()))?;
    let y_fmt = |v: &f64| match y_scale {
        YScale::Linear => format!("{v:.3}"),
        YScale::Log => format!("1e{v:.1}"),
    };
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .y_label_formatter(&y_fmt)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (i, s) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        if let Some(band) = &s.band {
            let upper: Vec<(f64, f64)> = band.iter().filter_map(|&(x, _, hi)| ty(hi).map(|y| (x, y))).collect();
            let lower: Vec<(f64, f64)> = band.iter().rev().filter_map(|&(x, lo, _)| ty(lo).map(|y| (x, y))).collect();
            let polygon: Vec<(f64, f64)> = upper.into_iter().chain(lower).collect();
            if polygon.len() >= 3 {
                chart
                    .draw_series(std::iter::once(Polygon::new(polygon, color.mix(0.15).filled())))
                    .map_err(|e| err(e.to_string()))?;
            }
        }
        let points: Vec<(f64, f64)> = s.points.iter().filter_map(|&(x, y)| ty(y).map(|y| (x, y))).collect();
        chart
            .draw_series(LineSeries::new(points, color.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))?;
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
