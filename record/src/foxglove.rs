//! Foxglove messages (JSON, as the schemas in [`crate::schemas::foxglove`] describe them) built
//! from terranav's types. Bytes fields are base64 (the schemas say `contentEncoding: base64`);
//! numbers that are not finite are written as JSON null (which JSON cannot do otherwise).

use base64::Engine;
use common::grid::{CellState, Tile, TileIndex};
use serde_json::{json, Value};
use std::collections::BTreeMap;

/// `foxglove.NumericType` codes.
pub mod numeric {
    /// Unsigned 8-bit integer.
    pub const UINT8: u8 = 1;
    /// Unsigned 16-bit integer.
    pub const UINT16: u8 = 3;
    /// 32-bit float.
    pub const FLOAT32: u8 = 7;
    /// 64-bit float.
    pub const FLOAT64: u8 = 8;
}

/// `foxglove.LogLevel` codes.
pub mod level {
    /// Info.
    pub const INFO: u8 = 2;
    /// Warning.
    pub const WARNING: u8 = 3;
    /// Error.
    pub const ERROR: u8 = 4;
}

/// Base64 as the schemas mean it (standard alphabet, padded).
pub fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// Bytes of a base64 field.
pub fn unb64(s: &str) -> Result<Vec<u8>, base64::DecodeError> {
    base64::engine::general_purpose::STANDARD.decode(s)
}

/// A number, or null when it is not finite.
pub fn num(x: f64) -> Value {
    serde_json::Number::from_f64(x).map_or(Value::Null, Value::Number)
}

/// A `time` of Unix nanoseconds.
pub fn time(unix_ns: u64) -> Value {
    json!({"sec": unix_ns / 1_000_000_000, "nsec": unix_ns % 1_000_000_000})
}

/// A `foxglove.Pose` from a position and a quaternion `[x, y, z, w]`.
pub fn pose(p: [f64; 3], q: [f64; 4]) -> Value {
    json!({
        "position": {"x": num(p[0]), "y": num(p[1]), "z": num(p[2])},
        "orientation": {"x": num(q[0]), "y": num(q[1]), "z": num(q[2]), "w": num(q[3])},
    })
}

/// The quaternion `[x, y, z, w]` of yaw, pitch, roll (Z-Y-X).
pub fn quaternion_ypr(yaw: f64, pitch: f64, roll: f64) -> [f64; 4] {
    let q = nalgebra::UnitQuaternion::from_euler_angles(roll, pitch, yaw);
    [q.i, q.j, q.k, q.w]
}

/// A `foxglove.PackedElementField`.
pub fn field(name: &str, offset: u32, ty: u8) -> Value {
    json!({"name": name, "offset": offset, "type": ty})
}

/// A `foxglove.PointCloud` of packed points in `frame_id`.
pub fn point_cloud(
    unix_ns: u64,
    frame_id: &str,
    stride: u32,
    fields: Vec<Value>,
    data: &[u8],
) -> Value {
    json!({
        "timestamp": time(unix_ns),
        "frame_id": frame_id,
        "pose": pose([0.0; 3], [0.0, 0.0, 0.0, 1.0]),
        "point_stride": stride,
        "fields": fields,
        "data": b64(data),
    })
}

/// A `foxglove.FrameTransform`: `child` in `parent`.
pub fn frame_transform(unix_ns: u64, parent: &str, child: &str, t: [f64; 3], q: [f64; 4]) -> Value {
    json!({
        "timestamp": time(unix_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": num(t[0]), "y": num(t[1]), "z": num(t[2])},
        "rotation": {"x": num(q[0]), "y": num(q[1]), "z": num(q[2]), "w": num(q[3])},
    })
}

/// A `foxglove.LocationFix` with unknown covariance.
pub fn location_fix(unix_ns: u64, frame_id: &str, lat_deg: f64, lon_deg: f64, h_m: f64) -> Value {
    json!({
        "timestamp": time(unix_ns),
        "frame_id": frame_id,
        "latitude": num(lat_deg),
        "longitude": num(lon_deg),
        "altitude": num(h_m),
        "position_covariance": vec![0.0f64; 9],
        "position_covariance_type": 0,
    })
}

/// A `foxglove.PoseInFrame`.
pub fn pose_in_frame(unix_ns: u64, frame_id: &str, p: [f64; 3], q: [f64; 4]) -> Value {
    json!({"timestamp": time(unix_ns), "frame_id": frame_id, "pose": pose(p, q)})
}

/// A `foxglove.Log`.
pub fn log(unix_ns: u64, level: u8, name: &str, message: &str) -> Value {
    json!({
        "timestamp": time(unix_ns),
        "level": level,
        "message": message,
        "name": name,
        "file": "",
        "line": 0,
    })
}

/// An RGBA colour.
pub fn color(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({"r": r, "g": g, "b": b, "a": a})
}

fn entity(unix_ns: u64, frame_id: &str, id: &str) -> serde_json::Map<String, Value> {
    let v = json!({
        "timestamp": time(unix_ns),
        "frame_id": frame_id,
        "id": id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": false,
        "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [],
        "lines": [], "triangles": [], "texts": [], "models": [],
    });
    match v {
        Value::Object(m) => m,
        _ => unreachable!("json! of an object"),
    }
}

/// A `foxglove.SceneUpdate` replacing entity `id` by a line strip through `points` (map frame,
/// metres), or deleting it when `points` is empty.
pub fn scene_line(
    unix_ns: u64,
    frame_id: &str,
    id: &str,
    points: &[[f64; 3]],
    rgba: Value,
    thickness_m: f64,
) -> Value {
    if points.is_empty() {
        return scene_delete(unix_ns, id);
    }
    let mut e = entity(unix_ns, frame_id, id);
    e.insert(
        "lines".into(),
        json!([{
            "type": 0,
            "pose": pose([0.0; 3], [0.0, 0.0, 0.0, 1.0]),
            "thickness": thickness_m,
            "scale_invariant": false,
            "points": points.iter().map(|p| json!({"x": num(p[0]), "y": num(p[1]), "z": num(p[2])})).collect::<Vec<_>>(),
            "color": rgba,
            "colors": [],
            "indices": [],
        }]),
    );
    json!({"deletions": [], "entities": [Value::Object(e)]})
}

/// A `foxglove.SceneUpdate` replacing entity `id` by a marker post at `p` with a label.
pub fn scene_marker(
    unix_ns: u64,
    frame_id: &str,
    id: &str,
    p: [f64; 3],
    rgba: Value,
    label: &str,
) -> Value {
    let mut e = entity(unix_ns, frame_id, id);
    e.insert(
        "cylinders".into(),
        json!([{
            "pose": pose([p[0], p[1], p[2] + 0.5], [0.0, 0.0, 0.0, 1.0]),
            "size": {"x": 0.4, "y": 0.4, "z": 1.0},
            "bottom_scale": 1.0,
            "top_scale": 1.0,
            "color": rgba.clone(),
        }]),
    );
    e.insert(
        "texts".into(),
        json!([{
            "pose": pose([p[0], p[1], p[2] + 1.3], [0.0, 0.0, 0.0, 1.0]),
            "billboard": true,
            "font_size": 14.0,
            "scale_invariant": true,
            "color": rgba,
            "text": label,
        }]),
    );
    json!({"deletions": [], "entities": [Value::Object(e)]})
}

/// A `foxglove.SceneUpdate` deleting entity `id`.
pub fn scene_delete(unix_ns: u64, id: &str) -> Value {
    json!({"deletions": [{"timestamp": time(unix_ns), "type": 0, "id": id}], "entities": []})
}

/// Bytes per cell of [`tiles_grid`]: cost (u8), class (u8), elevation (f32 metres, NaN unknown).
pub const GRID_CELL_STRIDE: u32 = 6;

/// The class code of a cell state in [`tiles_grid`] (0 unknown, 1 traversable, 2 obstacle,
/// 3 inflated).
pub fn class_code(s: CellState) -> u8 {
    s as u8
}

/// One `foxglove.Grid` (in `frame_id`, the map frame) covering `tiles` (all on one lattice): per
/// cell the planner cost, the class and the elevation, row 0 southmost, column 0 westmost; cells
/// no tile covers are unknown. `None` without tiles.
pub fn tiles_grid<'a>(
    unix_ns: u64,
    frame_id: &str,
    tiles: impl IntoIterator<Item = &'a Tile>,
) -> Option<Value> {
    let by_index: BTreeMap<TileIndex, &Tile> = tiles.into_iter().map(|t| (t.index, t)).collect();
    let first = by_index.values().next()?;
    let lattice = first.lattice;
    let n = lattice.tile_cells as usize;
    let (mut tx0, mut ty0, mut tx1, mut ty1) = (i32::MAX, i32::MAX, i32::MIN, i32::MIN);
    for i in by_index.keys() {
        tx0 = tx0.min(i.tx);
        ty0 = ty0.min(i.ty);
        tx1 = tx1.max(i.tx);
        ty1 = ty1.max(i.ty);
    }
    let cols = (tx1 - tx0 + 1) as usize * n;
    let rows = (ty1 - ty0 + 1) as usize * n;
    let stride = GRID_CELL_STRIDE as usize;
    let mut data = vec![0u8; cols * rows * stride];
    for chunk in data.chunks_exact_mut(stride) {
        chunk[2..6].copy_from_slice(&f32::NAN.to_le_bytes());
    }
    for (i, t) in &by_index {
        if t.lattice != lattice || t.cells.len() != n * n {
            continue;
        }
        let c0 = (i.tx - tx0) as usize * n;
        let r0 = (i.ty - ty0) as usize * n;
        for r in 0..n {
            for c in 0..n {
                let cell = &t.cells[r * n + c];
                let at = ((r0 + r) * cols + c0 + c) * stride;
                data[at] = cell.cost;
                data[at + 1] = class_code(cell.state);
                if cell.state != CellState::Unknown {
                    let h = f32::from(cell.height_cm) / 100.0;
                    data[at + 2..at + 6].copy_from_slice(&h.to_le_bytes());
                }
            }
        }
    }
    let s = lattice.cell_size_f64();
    let origin = [
        f64::from(tx0) * n as f64 * s,
        f64::from(ty0) * n as f64 * s,
        0.0,
    ];
    Some(json!({
        "timestamp": time(unix_ns),
        "frame_id": frame_id,
        "pose": pose(origin, [0.0, 0.0, 0.0, 1.0]),
        "column_count": cols,
        "cell_size": {"x": s, "y": s},
        "row_stride": cols * stride,
        "cell_stride": stride,
        "fields": [
            field("cost", 0, numeric::UINT8),
            field("class", 1, numeric::UINT8),
            field("elevation", 2, numeric::FLOAT32),
        ],
        "data": b64(&data),
    }))
}

/// A `terranav.Tile` message: `tile` as `encoded` by the tile codec.
pub fn tile_message(unix_ns: u64, tile: &Tile, encoded: &[u8]) -> Value {
    json!({
        "timestamp": time(unix_ns),
        "tx": tile.index.tx,
        "ty": tile.index.ty,
        "version": tile.version,
        "cell_size_m": tile.lattice.cell_size_m,
        "tile_cells": tile.lattice.tile_cells,
        "data": b64(encoded),
    })
}

/// JSON bytes of a message.
pub fn bytes(v: &Value) -> Vec<u8> {
    serde_json::to_vec(v).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::grid::{Cell, Lattice};

    #[test]
    fn a_grid_covers_its_tiles_with_unknown_between() {
        let l = Lattice::default();
        let mut a = Tile::new(TileIndex { tx: -1, ty: 0 }, l);
        *a.get_mut(0, 0) = Cell {
            state: CellState::Obstacle,
            cost: 254,
            height_cm: 37,
            hits: 3,
            stamp_s: 5,
            rev: 0,
        };
        let b = Tile::new(TileIndex { tx: 1, ty: 1 }, l);
        let g = tiles_grid(7, "map", [&a, &b]).unwrap();
        assert_eq!(g["column_count"], 3 * 64);
        assert_eq!(g["pose"]["position"]["x"], -12.8);
        let data = unb64(g["data"].as_str().unwrap()).unwrap();
        assert_eq!(data.len(), 3 * 64 * 2 * 64 * 6);
        assert_eq!(&data[..2], &[254, 2]);
        assert_eq!(f32::from_le_bytes(data[2..6].try_into().unwrap()), 0.37);
        assert!(f32::from_le_bytes(data[8..12].try_into().unwrap()).is_nan());
    }

    #[test]
    fn numbers_that_are_not_finite_are_null() {
        assert_eq!(num(f64::NAN), Value::Null);
        assert_eq!(num(0.1 + 0.2), json!(0.30000000000000004));
    }
}
