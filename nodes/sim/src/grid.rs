//! Grid to particle: bilinear sampling of a `msgs::Grid` channel at world points.

use msgs::GridHeader;

/// Samples one channel (row-major, `width * height` values) of a grid bilinearly at `(x, y)`.
///
/// Convention of `msgs::GridHeader`: x runs along columns, y along rows, node `(row, col)` sits at
/// `origin + (col, row) * spacing`. Points outside the grid take the value at the nearest edge
/// (clamped), so contacts on the walls still get a warm start.
pub fn sample_bilinear(header: &GridHeader, channel: &[f32], x: f32, y: f32) -> f32 {
    let w = header.width as usize;
    let h = header.height as usize;
    if w == 0 || h == 0 || channel.len() < w * h || !(header.spacing > 0.0) {
        return 0.0;
    }
    let fx = ((x - header.origin[0]) / header.spacing).clamp(0.0, (w - 1) as f32);
    let fy = ((y - header.origin[1]) / header.spacing).clamp(0.0, (h - 1) as f32);
    // NaN coordinates clamp to NaN; treat them as the origin rather than reading out of bounds.
    let (fx, fy) = (if fx.is_nan() { 0.0 } else { fx }, if fy.is_nan() { 0.0 } else { fy });
    let c0 = (fx.floor() as usize).min(w.saturating_sub(2));
    let r0 = (fy.floor() as usize).min(h.saturating_sub(2));
    let c1 = (c0 + 1).min(w - 1);
    let r1 = (r0 + 1).min(h - 1);
    let tx = fx - c0 as f32;
    let ty = fy - r0 as f32;
    let at = |r: usize, c: usize| channel[r * w + c];
    let bottom = at(r0, c0) * (1.0 - tx) + at(r0, c1) * tx;
    let top = at(r1, c0) * (1.0 - tx) + at(r1, c1) * tx;
    bottom * (1.0 - ty) + top * ty
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::{Grid, StepHeader};

    fn ramp() -> Grid {
        // value = 10 * x + y at node (row, col) with x = 1 + 0.5 col, y = 2 + 0.5 row.
        let mut g = Grid::zeros(StepHeader::default(), [1.0, 2.0], 0.5, 4, 3, &["normal"]);
        for row in 0..3 {
            for col in 0..4 {
                let (x, y) = (1.0 + 0.5 * col as f32, 2.0 + 0.5 * row as f32);
                g.channel_data_mut(0)[row * 4 + col] = 10.0 * x + y;
            }
        }
        g
    }

    #[test]
    fn bilinear_sampling_is_exact_on_a_linear_field() {
        let g = ramp();
        for &(x, y) in &[(1.0, 2.0), (1.3, 2.2), (2.5, 3.0), (2.49, 2.99), (1.75, 2.6)] {
            let v = sample_bilinear(&g.header, g.channel_data(0), x, y);
            assert!((v - (10.0 * x + y)).abs() < 1e-4, "({x}, {y}) -> {v}");
        }
    }

    #[test]
    fn points_outside_the_grid_clamp_to_the_edge() {
        let g = ramp();
        let v = sample_bilinear(&g.header, g.channel_data(0), -5.0, 100.0);
        assert!((v - (10.0 * 1.0 + 3.0)).abs() < 1e-5, "{v}");
        let v = sample_bilinear(&g.header, g.channel_data(0), 9.0, 2.25);
        assert!((v - (10.0 * 2.5 + 2.25)).abs() < 1e-4, "{v}");
    }
}
