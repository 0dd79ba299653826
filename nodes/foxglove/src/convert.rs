//! Bus frames -> Foxglove well-known messages, as pure functions (no channels, no clock).
//!
//! Coordinates: the scene lives in the `box` frame (the simulator's world coordinates, metres, y
//! up); `z` is 0 for the scene, slightly below for grids so they never cover the bodies.

use crate::Error;
use foxglove::bytes::Bytes;
use foxglove::messages::{
    line_primitive, packed_element_field::NumericType, ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive,
    FrameTransform, Grid, KeyValuePair, LinePrimitive, PackedElementField, Point3, Pose, Quaternion, RawImage,
    SceneEntity, SceneUpdate, Timestamp, Vector2, Vector3,
};
use msgs::StepStats;
use msgs::{Body, Contact, GridHeader, Shape, SolveStatsHeader, StepHeader, MAX_GRID_CHANNELS};
use std::sync::LazyLock;

/// Frame of the scene and the grids: the simulator's world coordinates.
pub const SCENE_FRAME: &str = "box";
/// Fixed frame of the 3D panel; `box` is placed in it with its centre at the origin.
pub const WORLD_FRAME: &str = "world";
/// Height of the grids below the scene plane, in metres.
pub const GRID_Z: f64 = -0.05;

/// How the scene is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneStyle {
    /// Arrow length per unit of normal impulse, in metres per N·s.
    pub impulse_scale: f32,
    /// Longest arrow, in metres (a hard impact would otherwise cross the box).
    pub max_arrow: f32,
}

impl Default for SceneStyle {
    fn default() -> Self {
        SceneStyle { impulse_scale: 1.0, max_arrow: 2.0 }
    }
}

/// A [`Timestamp`] from nanoseconds since the Unix epoch.
pub fn timestamp(ns: u64) -> Timestamp {
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

/// Rotation by `angle` radians about z.
pub fn yaw(angle: f32) -> Quaternion {
    let half = f64::from(angle) * 0.5;
    Quaternion { x: 0.0, y: 0.0, z: half.sin(), w: half.cos() }
}

fn pose(x: f32, y: f32, z: f64, angle: f32) -> Pose {
    Pose { position: Some(Vector3 { x: x.into(), y: y.into(), z }), orientation: Some(yaw(angle)) }
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Option<Color> {
    Some(Color { r, g, b, a })
}

fn step_metadata(step: &StepHeader) -> Vec<KeyValuePair> {
    vec![
        KeyValuePair { key: "run_id".into(), value: step.run_id.to_string() },
        KeyValuePair { key: "simulation".into(), value: step.simulation.to_string() },
        KeyValuePair { key: "step".into(), value: step.step.to_string() },
    ]
}

fn entity(id: &str, step: &StepHeader, time_ns: u64) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(time_ns)),
        frame_id: SCENE_FRAME.into(),
        id: id.into(),
        frame_locked: true,
        metadata: step_metadata(step),
        ..Default::default()
    }
}

/// Entity ids of a scene update, one entity per kind of thing (a 10,000-body scene stays a handful
/// of entities).
pub mod entity_ids {
    pub const WALLS: &str = "walls";
    /// Balls as flat cylinders (discs), with a line from the centre marking their orientation.
    pub const BALLS: &str = "balls";
    pub const BOXES: &str = "boxes";
    /// Polygons as the outline of their bounding circle (body messages carry no vertices).
    pub const POLYGONS: &str = "polygons";
    /// Contact normals as arrows from the contact point, length proportional to the normal impulse.
    pub const CONTACTS: &str = "contacts";
}

/// The scene of one step: walls, balls (discs with an orientation mark), boxes, polygons and contact
/// normals as arrows scaled by their normal impulse. Bodies with an unknown shape code are skipped.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(length > 0)` on purpose: NaN draws nothing
pub fn scene_update(
    step: &StepHeader,
    bodies: &[Body],
    contacts: &[Contact],
    style: &SceneStyle,
    time_ns: u64,
) -> SceneUpdate {
    let mut walls = entity(entity_ids::WALLS, step, time_ns);
    let mut balls = entity(entity_ids::BALLS, step, time_ns);
    let mut boxes = entity(entity_ids::BOXES, step, time_ns);
    let mut polygons = entity(entity_ids::POLYGONS, step, time_ns);
    let mut marks = Vec::with_capacity(bodies.len() * 2);
    for b in bodies {
        let size =
            |depth: f64| Some(Vector3 { x: 2.0 * f64::from(b.size[0]), y: 2.0 * f64::from(b.size[1]), z: depth });
        match Shape::from_u32(b.shape) {
            Some(Shape::Wall) => walls.cubes.push(CubePrimitive {
                pose: Some(pose(b.x, b.y, 0.0, b.angle)),
                size: size(0.1),
                color: color(0.45, 0.47, 0.5, 1.0),
            }),
            Some(Shape::Box) => boxes.cubes.push(CubePrimitive {
                pose: Some(pose(b.x, b.y, 0.0, b.angle)),
                size: size(0.05),
                color: color(0.95, 0.6, 0.2, 0.9),
            }),
            Some(Shape::Ball) => {
                balls.cylinders.push(CylinderPrimitive {
                    pose: Some(pose(b.x, b.y, 0.0, b.angle)),
                    size: size(0.05),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color: color(0.25, 0.55, 0.9, 0.9),
                });
                let (s, c) = b.angle.sin_cos();
                let r = b.size[0];
                marks.push(Point3 { x: b.x.into(), y: b.y.into(), z: 0.03 });
                marks.push(Point3 { x: (b.x + r * c).into(), y: (b.y + r * s).into(), z: 0.03 });
            }
            Some(Shape::Polygon) => {
                const SIDES: usize = 16;
                let r = b.size[0];
                polygons.lines.push(LinePrimitive {
                    r#type: line_primitive::Type::LineLoop as i32,
                    pose: Some(pose(b.x, b.y, 0.0, b.angle)),
                    thickness: f64::from(r) * 0.1,
                    points: (0..SIDES)
                        .map(|i| {
                            let a = i as f64 * std::f64::consts::TAU / SIDES as f64;
                            Point3 { x: f64::from(r) * a.cos(), y: f64::from(r) * a.sin(), z: 0.0 }
                        })
                        .collect(),
                    color: color(0.6, 0.3, 0.8, 1.0),
                    ..Default::default()
                });
            }
            None => {}
        }
    }
    if !marks.is_empty() {
        let thickness =
            bodies.iter().filter(|b| b.shape == Shape::Ball as u32).map(|b| b.size[0]).fold(f32::INFINITY, f32::min);
        balls.lines.push(LinePrimitive {
            r#type: line_primitive::Type::LineList as i32,
            pose: Some(pose(0.0, 0.0, 0.0, 0.0)),
            thickness: f64::from(thickness) * 0.15,
            points: marks,
            color: color(0.05, 0.1, 0.25, 1.0),
            ..Default::default()
        });
    }

    let mut arrows = entity(entity_ids::CONTACTS, step, time_ns);
    for c in contacts {
        let length = (c.normal_impulse.max(0.0) * style.impulse_scale).min(style.max_arrow);
        if !(length > 0.0) {
            continue; // no impulse (or NaN): nothing to draw
        }
        let shaft = f64::from(length);
        arrows.arrows.push(ArrowPrimitive {
            pose: Some(pose(c.x, c.y, 0.06, c.ny.atan2(c.nx))),
            shaft_length: shaft * 0.8,
            shaft_diameter: (shaft * 0.08).clamp(0.005, 0.05),
            head_length: shaft * 0.2,
            head_diameter: (shaft * 0.2).clamp(0.015, 0.12),
            color: color(0.9, 0.15, 0.15, 1.0),
        });
    }
    SceneUpdate { deletions: Vec::new(), entities: vec![walls, balls, boxes, polygons, arrows] }
}

/// Centre of the scene: the middle of the walls' bounding box (of all bodies without walls).
pub fn scene_center(bodies: &[Body]) -> Option<[f32; 2]> {
    let walls = bodies.iter().filter(|b| b.shape == Shape::Wall as u32);
    let pick: Vec<&Body> = if walls.clone().next().is_some() { walls.collect() } else { bodies.iter().collect() };
    let mut lo = [f32::INFINITY; 2];
    let mut hi = [f32::NEG_INFINITY; 2];
    for b in pick {
        let r = b.size[0].hypot(b.size[1]);
        lo = [lo[0].min(b.x - r), lo[1].min(b.y - r)];
        hi = [hi[0].max(b.x + r), hi[1].max(b.y + r)];
    }
    let c = [(lo[0] + hi[0]) * 0.5, (lo[1] + hi[1]) * 0.5];
    (c[0].is_finite() && c[1].is_finite()).then_some(c)
}

/// Places the `box` frame in `world` with the scene's centre at the world origin.
pub fn frame_transform(center: [f32; 2], time_ns: u64) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(time_ns)),
        parent_frame_id: WORLD_FRAME.into(),
        child_frame_id: SCENE_FRAME.into(),
        translation: Some(Vector3 { x: (-center[0]).into(), y: (-center[1]).into(), z: 0.0 }),
        rotation: Some(yaw(0.0)),
    }
}

/// Checks a grid frame's geometry against its items; `topic` names it in the error.
pub fn check_grid(topic: &str, h: &GridHeader, items: &[f32]) -> Result<(), Error> {
    let bad = |what: String| Err(Error::BadGrid { topic: topic.to_string(), what });
    if h.channels == 0 || h.channels as usize > MAX_GRID_CHANNELS {
        return bad(format!("{} channels (1..={MAX_GRID_CHANNELS} allowed)", h.channels));
    }
    if h.width == 0 || h.height == 0 {
        return bad(format!("empty grid {}x{}", h.width, h.height));
    }
    let expected = (h.channels as u64) * u64::from(h.width) * u64::from(h.height);
    if expected != items.len() as u64 {
        return bad(format!(
            "{} values for {} channels of {}x{} (expected {expected})",
            items.len(),
            h.channels,
            h.width,
            h.height
        ));
    }
    if !(h.spacing.is_finite() && h.spacing > 0.0) {
        return bad(format!("spacing {}", h.spacing));
    }
    Ok(())
}

/// A grid as a `foxglove.Grid`: one FLOAT32 field per channel (named as the channel), cells centred
/// on the grid's nodes, interleaved per cell as Foxglove wants them.
pub fn grid(topic: &str, h: &GridHeader, items: &[f32], time_ns: u64) -> Result<Grid, Error> {
    check_grid(topic, h, items)?;
    let channels = h.channels as usize;
    let cells = h.width as usize * h.height as usize;
    let mut data = Vec::with_capacity(cells * channels * 4);
    for cell in 0..cells {
        for c in 0..channels {
            data.extend_from_slice(&items[c * cells + cell].to_le_bytes());
        }
    }
    let cell_stride = 4 * channels as u32;
    let half = h.spacing * 0.5;
    Ok(Grid {
        timestamp: Some(timestamp(time_ns)),
        frame_id: SCENE_FRAME.into(),
        pose: Some(Pose {
            position: Some(Vector3 { x: (h.origin[0] - half).into(), y: (h.origin[1] - half).into(), z: GRID_Z }),
            orientation: Some(yaw(0.0)),
        }),
        column_count: h.width,
        cell_size: Some(Vector2 { x: h.spacing.into(), y: h.spacing.into() }),
        row_stride: cell_stride * h.width,
        cell_stride,
        fields: (0..channels)
            .map(|c| PackedElementField {
                name: channel_name(h, c),
                offset: 4 * c as u32,
                r#type: NumericType::Float32 as i32,
            })
            .collect(),
        data: Bytes::from(data),
    })
}

/// The name of channel `c`, or `c<index>` when the header leaves it empty.
pub fn channel_name(h: &GridHeader, c: usize) -> String {
    match h.channel_name(c) {
        "" => format!("c{c}"),
        name => name.to_string(),
    }
}

/// One channel of a grid as an `rgb8` heat map: row 0 of the image is the top of the scene (the
/// grid's last row). Values with both signs use a diverging map (blue - white - red) symmetric
/// about 0; non-negative values a sequential one (black - red - yellow - white). Non-finite values
/// are drawn magenta.
pub fn heat_image(topic: &str, h: &GridHeader, items: &[f32], c: usize, time_ns: u64) -> Result<RawImage, Error> {
    check_grid(topic, h, items)?;
    if c >= h.channels as usize {
        return Err(Error::BadGrid { topic: topic.to_string(), what: format!("no channel {c} of {}", h.channels) });
    }
    let (w, ht) = (h.width as usize, h.height as usize);
    let values = &items[c * w * ht..(c + 1) * w * ht];
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let diverging = lo < 0.0 && hi > 0.0;
    let scale = if diverging { lo.abs().max(hi) } else { hi.max(lo.abs()) };
    let mut data = Vec::with_capacity(w * ht * 3);
    for row in (0..ht).rev() {
        for &v in &values[row * w..(row + 1) * w] {
            let rgb = if !v.is_finite() {
                [255, 0, 255]
            } else if scale <= 0.0 || !scale.is_finite() {
                [0, 0, 0]
            } else if diverging {
                diverging_rgb(v / scale)
            } else {
                sequential_rgb(v.abs() / scale)
            };
            data.extend_from_slice(&rgb);
        }
    }
    Ok(RawImage {
        timestamp: Some(timestamp(time_ns)),
        frame_id: SCENE_FRAME.into(),
        width: h.width,
        height: h.height,
        encoding: "rgb8".into(),
        step: 3 * h.width,
        data: Bytes::from(data),
    })
}

fn to_u8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// `t` in [0, 1]: black -> red -> yellow -> white.
fn sequential_rgb(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    [to_u8(t * 3.0), to_u8(t * 3.0 - 1.0), to_u8(t * 3.0 - 2.0)]
}

/// `t` in [-1, 1]: blue -> white -> red.
fn diverging_rgb(t: f32) -> [u8; 3] {
    let t = t.clamp(-1.0, 1.0);
    if t < 0.0 {
        [to_u8(1.0 + t), to_u8(1.0 + t), 255]
    } else {
        [255, to_u8(1.0 - t), to_u8(1.0 - t)]
    }
}

/// A JSON schema of the object `value` is an example of (field names and JSON types).
fn schema_of(title: &str, description: &str, value: &serde_json::Value, extra: serde_json::Value) -> String {
    use serde_json::Value;
    let mut props = serde_json::Map::new();
    for (key, v) in value.as_object().expect("an object") {
        let ty = match v {
            Value::String(_) => "string",
            Value::Bool(_) => "boolean",
            Value::Number(n) if n.is_u64() || n.is_i64() => "integer",
            Value::Number(_) => "number",
            Value::Array(_) => "array",
            Value::Object(_) => "object",
            Value::Null => "null",
        };
        props.insert(key.clone(), serde_json::json!({ "type": ty }));
    }
    props.extend(extra.as_object().cloned().unwrap_or_default());
    serde_json::json!({ "title": title, "description": description, "type": "object", "properties": props }).to_string()
}

/// JSON schema of [`solve_stats_json`], for Foxglove's Plot panel and message path completion;
/// derived from `msgs::StepStats`, the one definition of the statistics.
pub static SOLVE_STATS_SCHEMA: LazyLock<String> = LazyLock::new(|| {
    let sample = serde_json::to_value(StepStats::default()).expect("statistics serialise");
    let residuals = serde_json::json!({
        "residuals": {"type": "array", "items": {"type": "number"}, "description": "largest impulse change after each sweep"}
    });
    schema_of("dc.SolveStats", "Contact solver statistics of one simulation step", &sample, residuals)
});

/// A solver statistics frame as JSON (see [`SOLVE_STATS_SCHEMA`]): `msgs::StepStats` (run id as
/// text: it exceeds 2^53) plus the residuals; non-finite numbers become null.
pub fn solve_stats_json(h: &SolveStatsHeader, residuals: &[f32]) -> serde_json::Value {
    let mut v = serde_json::to_value(StepStats::from_header(h)).expect("statistics serialise");
    v["residuals"] = serde_json::json!(residuals);
    v
}

/// A `metrics/step` frame as JSON: the step, its model, `[cumulative sweeps, sweeps]`.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct MetricsStep {
    #[serde(with = "msgs::id_text")]
    pub run_id: u64,
    pub simulation: u32,
    pub step: u32,
    pub model: String,
    pub cumulative_sweeps: Option<f32>,
    pub sweeps: Option<f32>,
}

/// JSON schema of [`metrics_step_json`].
pub static METRICS_STEP_SCHEMA: LazyLock<String> = LazyLock::new(|| {
    let sample = MetricsStep { cumulative_sweeps: Some(0.5), sweeps: Some(0.5), ..MetricsStep::default() };
    schema_of(
        "dc.MetricsStep",
        "Per-step summary of the metrics node: sweeps of the step and cumulative sweeps of its model",
        &serde_json::to_value(sample).expect("serialises"),
        serde_json::json!({}),
    )
});

/// A `metrics/step` frame (the statistics header and `[cumulative sweeps, sweeps]`) as JSON.
pub fn metrics_step_json(h: &SolveStatsHeader, items: &[f32]) -> serde_json::Value {
    let m = MetricsStep {
        run_id: h.step.run_id,
        simulation: h.step.simulation,
        step: h.step.step,
        model: msgs::name16_str(&h.model).to_string(),
        cumulative_sweeps: items.first().copied(),
        sweeps: items.get(1).copied(),
    };
    serde_json::to_value(m).expect("serialises")
}

/// A control message as JSON: its header and typed details.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ControlJson {
    #[serde(with = "msgs::id_text")]
    pub run_id: u64,
    pub simulation: u32,
    pub step: u32,
    pub kind: String,
    pub count: u32,
    /// The typed details (`msgs::control`) as a JSON object, null when there are none.
    pub details: serde_json::Value,
    /// Why the details could not be read, if they could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub details_error: Option<String>,
}

/// JSON schema of [`control_json`].
pub static CONTROL_SCHEMA: LazyLock<String> = LazyLock::new(|| {
    let sample = ControlJson { details: serde_json::json!({}), ..ControlJson::default() };
    schema_of(
        "dc.Control",
        "Run and simulation start / end, node down / up",
        &serde_json::to_value(sample).expect("serialises"),
        serde_json::json!({}),
    )
});

/// A control message as JSON.
pub fn control_json(c: &msgs::Control, details: &[u8]) -> serde_json::Value {
    let kind = match c.kind() {
        Some(k) => format!("{k:?}"),
        None => format!("unknown({})", c.kind),
    };
    let (details, details_error) = match msgs::control::details_of(c, details) {
        Ok(msgs::ControlDetails::None) => (serde_json::Value::Null, None),
        Ok(d) => (serde_json::to_value(&d).expect("details serialise"), None),
        Err(e) => (serde_json::Value::Null, Some(e.to_string())),
    };
    let json = ControlJson {
        run_id: c.step.run_id,
        simulation: c.step.simulation,
        step: c.step.step,
        kind,
        count: c.count,
        details,
        details_error,
    };
    serde_json::to_value(json).expect("serialises")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ball(id: u32, x: f32, y: f32, r: f32) -> Body {
        Body { id, shape: Shape::Ball as u32, size: [r, r], x, y, ..Default::default() }
    }

    fn wall(id: u32, x: f32, y: f32, hx: f32, hy: f32) -> Body {
        Body { id, shape: Shape::Wall as u32, size: [hx, hy], x, y, ..Default::default() }
    }

    #[test]
    fn scene_has_one_disc_per_ball_and_one_arrow_per_pushing_contact() {
        let bodies = [
            wall(0, 5.0, -0.5, 6.0, 0.5),
            ball(1, 1.0, 0.5, 0.5),
            ball(2, 2.0, 0.5, 0.5),
            Body {
                id: 3,
                shape: Shape::Box as u32,
                size: [0.5, 0.25],
                x: 3.0,
                y: 0.25,
                angle: 0.3,
                ..Default::default()
            },
        ];
        let push = Contact { x: 1.0, y: 0.0, nx: 0.0, ny: 1.0, normal_impulse: 0.5, ..Default::default() };
        let idle = Contact { normal_impulse: 0.0, ..push };
        let scene = scene_update(&StepHeader::default(), &bodies, &[push, idle], &SceneStyle::default(), 0);
        let by_id = |id: &str| scene.entities.iter().find(|e| e.id == id).unwrap();
        assert_eq!(by_id(entity_ids::BALLS).cylinders.len(), 2);
        assert_eq!(by_id(entity_ids::WALLS).cubes.len(), 1);
        assert_eq!(by_id(entity_ids::BOXES).cubes.len(), 1);
        let arrows = &by_id(entity_ids::CONTACTS).arrows;
        assert_eq!(arrows.len(), 1, "a contact without impulse draws no arrow");
        // Normal +y: a quarter turn about z; length = 0.5 N·s x 1 m/(N·s).
        let q = arrows[0].pose.unwrap().orientation.unwrap();
        assert!((q.z - (std::f64::consts::FRAC_PI_4).sin()).abs() < 1e-6);
        assert!((arrows[0].shaft_length + arrows[0].head_length - 0.5).abs() < 1e-6);
        // The box keeps its orientation.
        let qb = by_id(entity_ids::BOXES).cubes[0].pose.unwrap().orientation.unwrap();
        assert!((qb.z - 0.15f64.sin()).abs() < 1e-6);
    }

    #[test]
    fn grid_fields_interleave_channels_per_cell() {
        let mut g = msgs::Grid::zeros(StepHeader::default(), [1.0, 2.0], 0.5, 3, 2, &["normal", "tangent"]);
        g.channel_data_mut(0)[4] = 7.0; // row 1, col 1
        g.channel_data_mut(1)[4] = -3.0;
        let fg = grid("grid/contacts", &g.header, &g.items, 0).unwrap();
        assert_eq!(fg.column_count, 3);
        assert_eq!((fg.cell_stride, fg.row_stride), (8, 24));
        assert_eq!(fg.fields.iter().map(|f| f.name.as_str()).collect::<Vec<_>>(), ["normal", "tangent"]);
        assert_eq!(fg.data.len(), 3 * 2 * 8);
        let at = |off: usize| f32::from_le_bytes(fg.data[off..off + 4].try_into().unwrap());
        assert_eq!(at(24 + 8), 7.0);
        assert_eq!(at(24 + 8 + 4), -3.0);
        let p = fg.pose.unwrap().position.unwrap();
        assert_eq!((p.x, p.y), (0.75, 1.75), "cells are centred on the nodes");
    }

    #[test]
    fn bad_grids_are_errors_naming_the_topic() {
        let g = msgs::Grid::zeros(StepHeader::default(), [0.0, 0.0], 0.5, 3, 2, &["a"]);
        let e = grid("grid/bodies", &g.header, &g.items[..5], 0).unwrap_err().to_string();
        assert!(e.contains("grid/bodies") && e.contains("expected 6"), "{e}");
        let mut h = g.header;
        h.channels = 99;
        assert!(heat_image("grid/x", &h, &g.items, 0, 0).is_err());
    }

    #[test]
    fn heat_image_puts_the_top_row_first_and_diverges_about_zero() {
        let mut g = msgs::Grid::zeros(StepHeader::default(), [0.0, 0.0], 1.0, 2, 2, &["t"]);
        g.items.copy_from_slice(&[-1.0, 0.0, 0.0, 1.0]); // row 0: -1 0, row 1: 0 1
        let img = heat_image("grid/contacts", &g.header, &g.items, 0, 0).unwrap();
        assert_eq!((img.width, img.height, img.step), (2, 2, 6));
        assert_eq!(&img.data[..6], &[255, 255, 255, 255, 0, 0], "top row is grid row 1");
        assert_eq!(&img.data[6..], &[0, 0, 255, 255, 255, 255]);
    }

    #[test]
    fn stats_json_matches_its_schema_fields() {
        let schema: serde_json::Value = serde_json::from_str(&SOLVE_STATS_SCHEMA).unwrap();
        let step = msgs::StepHeader { run_id: 1796139974837132098, simulation: 1, step: 2 };
        let h = SolveStatsHeader { step, sweeps: 12, model: msgs::name16("builtin"), ..Default::default() };
        let v = solve_stats_json(&h, &[0.5, 0.1]);
        let props = schema["properties"].as_object().unwrap();
        for (key, value) in v.as_object().unwrap() {
            let ty = props.get(key).unwrap_or_else(|| panic!("`{key}` is missing from the schema"))["type"]
                .as_str()
                .unwrap();
            let ok = match ty {
                "string" => value.is_string(),
                "integer" => value.is_u64(),
                "number" => value.is_number(),
                "boolean" => value.is_boolean(),
                "array" => value.is_array(),
                _ => false,
            };
            assert!(ok, "`{key}` = {value} is not of its schema type {ty}");
        }
        assert_eq!(v["sweeps"], 12);
        assert_eq!(v["model"], "builtin");
        // Ids beyond 2^53 travel as text, or a JavaScript client rounds them.
        assert_eq!(v["run_id"], "1796139974837132098");
        let m: serde_json::Value = serde_json::from_str(&METRICS_STEP_SCHEMA).unwrap();
        assert_eq!(m["properties"]["sweeps"]["type"], "number");
        assert_eq!(metrics_step_json(&h, &[3.0, 1.0])["run_id"], "1796139974837132098");
        let c: serde_json::Value = serde_json::from_str(&CONTROL_SCHEMA).unwrap();
        assert_eq!(c["properties"]["run_id"]["type"], "string");
    }

    #[test]
    fn control_json_has_typed_details() {
        let n = msgs::NodeNotice {
            node: "sph".into(),
            host: "a".into(),
            publishes: vec!["grid/contacts".into()],
            status: "signal 9".into(),
        };
        let m = msgs::ControlMsg::node_notice(false, &n);
        let v = control_json(&m.header, &m.items);
        assert_eq!(v["kind"], "NodeDown");
        assert_eq!(v["details"]["NodeDown"]["node"], "sph");
        let v = control_json(&m.header, b"\xffjunk");
        assert!(v["details_error"].as_str().unwrap().contains("NodeDown"), "{v}");
    }

    #[test]
    fn scene_center_is_the_middle_of_the_walls() {
        let bodies = [wall(0, 0.0, 5.0, 0.5, 5.0), wall(1, 10.0, 5.0, 0.5, 5.0), ball(2, 3.0, 1.0, 0.5)];
        let c = scene_center(&bodies).unwrap();
        assert!((c[0] - 5.0).abs() < 1e-5 && (c[1] - 5.0).abs() < 1e-5, "{c:?}");
        assert_eq!(scene_center(&[]), None);
    }
}
