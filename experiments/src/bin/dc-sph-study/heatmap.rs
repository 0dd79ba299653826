//! PNG heat-maps of one grid channel, the right way up: image rows run top-down, grid rows bottom-up
//! (row 0 is the lowest y), so the image flips rows here and nowhere else. The thesis's plots
//! came out flipped for exactly this reason (its Fig. 7.2).

use anyhow::{Context, Result};
use sph::GridGeometry;
use std::path::Path;

/// Pixels of one channel: `scale x scale` pixels per node, a black-red-yellow-white ramp from the
/// channel's minimum to its maximum, and `marks` (world points, e.g. the particles) drawn as cyan
/// dots. Returns `(width, height, rgb)` with image row 0 at the top (= the grid's highest row).
pub fn heatmap_rgb(
    geometry: &GridGeometry,
    channel: &[f32],
    marks: &[[f32; 2]],
    scale: usize,
) -> (usize, usize, Vec<u8>) {
    let (gw, gh) = (geometry.width, geometry.height);
    let (iw, ih) = (gw * scale, gh * scale);
    let lo = channel.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = channel.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    let mut rgb = vec![0u8; iw * ih * 3];
    for py in 0..ih {
        let row = gh - 1 - py / scale;
        for px in 0..iw {
            let col = px / scale;
            let t = (channel[geometry.node_index(row, col)] - lo) / span;
            rgb[(py * iw + px) * 3..][..3].copy_from_slice(&ramp(t));
        }
    }
    for &[x, y] in marks {
        let [c, r] = geometry.grid_coords(x, y);
        let (px, py) = ((c + 0.5) * scale as f32, (gh as f32 - 0.5 - r) * scale as f32);
        for dy in -1..=1i32 {
            for dx in -1..=1i32 {
                let (qx, qy) = (px as i64 + dx as i64, py as i64 + dy as i64);
                if qx >= 0 && qy >= 0 && (qx as usize) < iw && (qy as usize) < ih {
                    rgb[(qy as usize * iw + qx as usize) * 3..][..3].copy_from_slice(&[0, 220, 255]);
                }
            }
        }
    }
    (iw, ih, rgb)
}

/// Black -> red -> yellow -> white for `t` in [0, 1].
fn ramp(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0) * 3.0;
    let ch = |v: f32| (v.clamp(0.0, 1.0) * 255.0) as u8;
    [ch(t), ch(t - 1.0), ch(t - 2.0)]
}

/// Writes [`heatmap_rgb`] to a PNG file.
pub fn write_heatmap(
    path: &Path,
    geometry: &GridGeometry,
    channel: &[f32],
    marks: &[[f32; 2]],
    scale: usize,
) -> Result<()> {
    let (w, h, rgb) = heatmap_rgb(geometry, channel, marks, scale);
    let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().context("writing the PNG header")?;
    writer.write_image_data(&rgb).context("writing the PNG data")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sph::Bounds;

    #[test]
    fn high_rows_are_drawn_at_the_top_of_the_image() {
        let g = GridGeometry::from_bounds(Bounds::new([0.0, 0.0], [2.0, 2.0]).unwrap(), 1.0, 1).unwrap();
        let mut v = vec![0.0; g.nodes()];
        v[g.node_index(2, 0)] = 1.0; // top-left in world terms: low x, high y
        let (w, _, rgb) = heatmap_rgb(&g, &v, &[], 2);
        assert_eq!(&rgb[..3], &[255, 255, 255], "image top-left is the bright node");
        let bottom_left = (5 * w) * 3;
        assert_eq!(&rgb[bottom_left..bottom_left + 3], &[0, 0, 0]);
    }
}
