//! Grid geometry: the one place where world coordinates and grid indices meet.
//!
//! Convention (that of `msgs::GridHeader`): x runs along columns, y along rows; node `(row, col)`
//! sits at `origin + (col, row) * spacing`; row 0 is the *lowest* y. The thesis read its grids
//! transposed and flipped (it plotted with the image convention, row 0 at the top, and indexed
//! `[x][y]`); every conversion here goes through [`GridGeometry`] so that cannot happen twice.

use crate::error::SphError;
use msgs::{Body, GridHeader, Shape, StepHeader};
use std::str::FromStr;

/// An axis-aligned world rectangle the grid must cover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Lower-left corner (smallest x and y).
    pub min: [f32; 2],
    /// Upper-right corner (largest x and y).
    pub max: [f32; 2],
}

impl Bounds {
    /// The thesis's scene: the interior of the 15 x 15 box, (0, 0) to (15, 15).
    pub const THESIS_BOX: Bounds = Bounds { min: [0.0, 0.0], max: [15.0, 15.0] };

    /// A rectangle from its corners; fails unless both are finite and `min < max` on both axes.
    pub fn new(min: [f32; 2], max: [f32; 2]) -> Result<Bounds, SphError> {
        let finite = min.iter().chain(max.iter()).all(|v| v.is_finite());
        if !finite || min[0] >= max[0] || min[1] >= max[1] {
            return Err(SphError::BadParameter(format!(
                "bounds need finite corners with min < max, got min {min:?} max {max:?}"
            )));
        }
        Ok(Bounds { min, max })
    }

    /// The interior of the box formed by the scene's walls (bodies of shape `Wall`).
    ///
    /// Each wall's axis-aligned box (rotation included) is classified by where it lies relative to
    /// the centre of all walls: a wall entirely left of the centre bounds the interior by its right
    /// face, and so on. When a side has no such wall (a rotated drum whose walls straddle the
    /// centre lines, an open scene) the outer box of all walls is used instead, which still covers
    /// every body inside. `None` without walls.
    pub fn from_walls(bodies: &[Body]) -> Option<Bounds> {
        let boxes: Vec<[f32; 4]> = bodies
            .iter()
            .filter(|b| Shape::from_u32(b.shape) == Some(Shape::Wall))
            .map(wall_aabb)
            .filter(|a| a.iter().all(|v| v.is_finite()))
            .collect();
        if boxes.is_empty() {
            return None;
        }
        let outer = boxes.iter().fold([f32::MAX, f32::MAX, f32::MIN, f32::MIN], |o, a| {
            [o[0].min(a[0]), o[1].min(a[1]), o[2].max(a[2]), o[3].max(a[3])]
        });
        let cx = boxes.iter().map(|a| 0.5 * (a[0] + a[2])).sum::<f32>() / boxes.len() as f32;
        let cy = boxes.iter().map(|a| 0.5 * (a[1] + a[3])).sum::<f32>() / boxes.len() as f32;
        let side = |keep: &dyn Fn(&[f32; 4]) -> Option<f32>, pick: fn(f32, f32) -> f32, dflt: f32| {
            boxes.iter().filter_map(keep).reduce(pick).unwrap_or(dflt)
        };
        let x0 = side(&|a| (a[2] <= cx).then_some(a[2]), f32::max, outer[0]);
        let x1 = side(&|a| (a[0] >= cx).then_some(a[0]), f32::min, outer[2]);
        let y0 = side(&|a| (a[3] <= cy).then_some(a[3]), f32::max, outer[1]);
        let y1 = side(&|a| (a[1] >= cy).then_some(a[1]), f32::min, outer[3]);
        Bounds::new([x0, y0], [x1, y1]).or_else(|_| Bounds::new([outer[0], outer[1]], [outer[2], outer[3]])).ok()
    }
}

/// Axis-aligned box `[x0, y0, x1, y1]` of a rotated wall (half extents in `size`).
fn wall_aabb(b: &Body) -> [f32; 4] {
    let (s, c) = b.angle.sin_cos();
    let ex = (c * b.size[0]).abs() + (s * b.size[1]).abs();
    let ey = (s * b.size[0]).abs() + (c * b.size[1]).abs();
    [b.x - ex, b.y - ey, b.x + ex, b.y + ey]
}

impl FromStr for Bounds {
    type Err = SphError;
    /// Parses `x0,y0,x1,y1`.
    fn from_str(s: &str) -> Result<Bounds, SphError> {
        let v: Vec<f32> = s
            .split(',')
            .map(|t| t.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|e| SphError::BadParameter(format!("bounds `{s}`: {e}")))?;
        match v[..] {
            [x0, y0, x1, y1] => Bounds::new([x0, y0], [x1, y1]),
            _ => Err(SphError::BadParameter(format!("bounds `{s}`: expected x0,y0,x1,y1"))),
        }
    }
}

/// Where the nodes of a grid are: origin, spacing and size (the geometric part of a `GridHeader`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    /// World position of node (row 0, col 0), the lower-left node.
    pub origin: [f32; 2],
    /// Distance between neighbouring nodes (the thesis's `res`).
    pub spacing: f32,
    /// Number of columns (nodes along x).
    pub width: usize,
    /// Number of rows (nodes along y).
    pub height: usize,
}

/// The most nodes a grid may have along either axis (the thesis's is 121, a U-Net's 128).
pub const MAX_GRID_SIDE: usize = 4096;

impl GridGeometry {
    /// A grid whose nodes cover `bounds` with `spacing` between them: node (0, 0) on the lower-left
    /// corner, `ceil(extent / spacing) + 1` nodes per axis (15 / 0.125 + 1 = 121 for the thesis).
    ///
    /// `pad_multiple` > 1 rounds width and height up to a multiple of it (121 -> 128 for a U-Net
    /// with 2^levels = 8 or 128) by adding nodes on the high-x / high-y side, so the nodes over the
    /// scene keep their positions and the extra nodes simply lie outside the box.
    pub fn from_bounds(bounds: Bounds, spacing: f32, pad_multiple: usize) -> Result<GridGeometry, SphError> {
        if !(spacing > 0.0 && spacing.is_finite()) {
            return Err(SphError::BadParameter(format!("grid spacing (res) must be > 0, got {spacing}")));
        }
        if pad_multiple > MAX_GRID_SIDE {
            return Err(SphError::BadParameter(format!(
                "pad-to {pad_multiple} is above the grid limit {MAX_GRID_SIDE}"
            )));
        }
        // Nodes per axis in f64 (a huge extent or a tiny spacing must not overflow), with a
        // tolerance so that 15 / 0.125 = 120.0000x does not become 121 cells.
        let pad = pad_multiple.max(1);
        let side = |extent: f32, axis: &str| -> Result<usize, SphError> {
            let cells = ((extent as f64 / spacing as f64) - 1e-4).ceil().max(0.0);
            let nodes = ((cells + 1.0) / pad as f64).ceil() * pad as f64;
            if nodes.is_nan() || nodes > MAX_GRID_SIDE as f64 {
                return Err(SphError::BadParameter(format!(
                    "a grid spacing (res) of {spacing} over {extent} (along {axis}) needs {nodes} nodes, above the limit \
                     {MAX_GRID_SIDE} x {MAX_GRID_SIDE} (raise the spacing or narrow the bounds)"
                )));
            }
            Ok(nodes as usize)
        };
        let width = side(bounds.max[0] - bounds.min[0], "x")?;
        let height = side(bounds.max[1] - bounds.min[1], "y")?;
        Ok(GridGeometry { origin: bounds.min, spacing, width, height })
    }

    /// The geometry of a received grid.
    pub fn from_header(header: &GridHeader) -> GridGeometry {
        GridGeometry {
            origin: header.origin,
            spacing: header.spacing,
            width: header.width as usize,
            height: header.height as usize,
        }
    }

    /// A header with this geometry, `step` and the channel names (at most `msgs::MAX_GRID_CHANNELS`).
    pub fn header(&self, step: StepHeader, channels: &[&str]) -> Result<GridHeader, SphError> {
        if channels.len() > msgs::MAX_GRID_CHANNELS {
            return Err(SphError::TooManyChannels(channels.len()));
        }
        let mut channel_names = [[0u8; 16]; msgs::MAX_GRID_CHANNELS];
        for (slot, name) in channel_names.iter_mut().zip(channels) {
            *slot = msgs::name16(name);
        }
        Ok(GridHeader {
            step,
            origin: self.origin,
            spacing: self.spacing,
            width: self.width as u32,
            height: self.height as u32,
            channels: channels.len() as u32,
            channel_names,
        })
    }

    /// Number of nodes (values per channel).
    pub fn nodes(&self) -> usize {
        self.width * self.height
    }

    /// Index of node `(row, col)` within one channel: `row * width + col`.
    pub fn node_index(&self, row: usize, col: usize) -> usize {
        row * self.width + col
    }

    /// World position `(x, y)` of node `(row, col)`.
    pub fn node_position(&self, row: usize, col: usize) -> [f32; 2] {
        [self.origin[0] + col as f32 * self.spacing, self.origin[1] + row as f32 * self.spacing]
    }

    /// Continuous grid coordinates `(col, row)` of a world point: node `(r, c)` maps to `(c, r)`.
    pub fn grid_coords(&self, x: f32, y: f32) -> [f32; 2] {
        [(x - self.origin[0]) / self.spacing, (y - self.origin[1]) / self.spacing]
    }

    /// The nearest node `(row, col)` of a point inside the grid, `None` outside.
    pub fn nearest_node(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        if !self.contains(x, y) {
            return None;
        }
        let [c, r] = self.grid_coords(x, y);
        Some(((r.round() as usize).min(self.height - 1), (c.round() as usize).min(self.width - 1)))
    }

    /// Whether `(x, y)` lies in the rectangle spanned by the nodes (edges included).
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let [c, r] = self.grid_coords(x, y);
        // NaN fails every comparison, so non-finite points are outside.
        (0.0..=(self.width.max(1) - 1) as f32).contains(&c) && (0.0..=(self.height.max(1) - 1) as f32).contains(&r)
    }

    /// Whether `(x, y)` lies within `margin` (world units) of the node rectangle.
    pub fn contains_within(&self, x: f32, y: f32, margin: f32) -> bool {
        let [c, r] = self.grid_coords(x, y);
        let m = margin / self.spacing;
        (-m..=(self.width.max(1) - 1) as f32 + m).contains(&c)
            && (-m..=(self.height.max(1) - 1) as f32 + m).contains(&r)
    }

    /// World position of every node, row-major (the order of a channel's values).
    pub fn node_positions(&self) -> Vec<[f32; 2]> {
        (0..self.height)
            .flat_map(|row| (0..self.width).map(move |col| (row, col)))
            .map(|(row, col)| self.node_position(row, col))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_box_gives_a_121_node_grid_and_pads_to_128() {
        let g = GridGeometry::from_bounds(Bounds::THESIS_BOX, 0.125, 1).unwrap();
        assert_eq!((g.width, g.height), (121, 121));
        assert_eq!(g.node_position(120, 120), [15.0, 15.0]);
        let p = GridGeometry::from_bounds(Bounds::THESIS_BOX, 0.125, 128).unwrap();
        assert_eq!((p.width, p.height), (128, 128));
        // Padding adds nodes on the high side: the scene's nodes keep their places.
        assert_eq!(p.node_position(120, 120), [15.0, 15.0]);
        assert_eq!(p.origin, [0.0, 0.0]);
    }

    #[test]
    fn x_runs_along_columns_and_y_along_rows() {
        let g = GridGeometry::from_bounds(Bounds::new([1.0, 2.0], [3.0, 5.0]).unwrap(), 0.5, 1).unwrap();
        assert_eq!((g.width, g.height), (5, 7));
        assert_eq!(g.node_position(0, 0), [1.0, 2.0]);
        // One row up moves y, one column right moves x.
        assert_eq!(g.node_position(1, 0), [1.0, 2.5]);
        assert_eq!(g.node_position(0, 1), [1.5, 2.0]);
        assert_eq!(g.nearest_node(2.9, 2.1), Some((0, 4)));
        assert_eq!(g.nearest_node(1.1, 4.9), Some((6, 0)));
        assert_eq!(g.node_index(6, 0), 30);
        assert!(!g.contains(0.9, 3.0) && !g.contains(2.0, 5.1) && !g.contains(f32::NAN, 3.0));
    }

    #[test]
    fn bounds_come_from_the_walls_inner_faces() {
        // The simulator's box: 15 x 15 interior, walls 1 thick around it.
        let wall = |x: f32, y: f32, hx: f32, hy: f32| Body {
            shape: Shape::Wall as u32,
            size: [hx, hy],
            x,
            y,
            ..Default::default()
        };
        let walls = [
            wall(7.5, -0.5, 8.5, 0.5),
            wall(7.5, 15.5, 8.5, 0.5),
            wall(-0.5, 7.5, 0.5, 8.5),
            wall(15.5, 7.5, 0.5, 8.5),
            Body { shape: Shape::Ball as u32, x: 30.0, y: 30.0, ..Default::default() },
        ];
        let b = Bounds::from_walls(&walls).unwrap();
        for (got, want) in b.min.iter().chain(&b.max).zip([0.0, 0.0, 15.0, 15.0]) {
            assert!((got - want).abs() < 1e-5, "{b:?}");
        }
        assert_eq!(Bounds::from_walls(&walls[4..]), None);
    }

    #[test]
    fn bounds_parse_from_four_numbers() {
        assert_eq!("0,0,15,15".parse::<Bounds>().unwrap(), Bounds::THESIS_BOX);
        assert!("0,0,15".parse::<Bounds>().is_err());
        assert!("5,0,1,15".parse::<Bounds>().is_err());
    }
}
