//! Plane geometry of routes: distances, the nearest waypoint, pushing a point out of obstacles,
//! resampling a polyline.

use super::Waypoint;
use planning::smooth::point_free;
use planning::{CellXY, PlanGrid};

pub(super) fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

pub(super) fn nearest(wps: &[Waypoint], p: (f64, f64)) -> usize {
    wps.iter()
        .enumerate()
        .min_by(|a, b| dist(a.1.p, p).total_cmp(&dist(b.1.p, p)))
        .map(|(i, _)| i)
        .unwrap_or(0)
}

/// Moves `p` out of non-traversable cells by a local search on a ring of growing radius, towards
/// the free cell that is nearest (the steepest direction of the clearance field); None when
/// nothing is free within `max_m`.
pub(super) fn push_free(grid: &PlanGrid, p: (f64, f64), max_m: f64) -> Option<(f64, f64)> {
    let step = grid.cell_size_m();
    let rings = (max_m / step).ceil() as i32;
    for k in 1..=rings {
        let r = f64::from(k) * step;
        let n = (8 * k) as usize;
        let best = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                (p.0 + r * a.cos(), p.1 + r * a.sin())
            })
            .find(|q| point_free(grid, *q));
        if best.is_some() {
            return best;
        }
    }
    None
}

/// Cell path -> waypoints every `spacing_m`, starting at `from` and ending at `to` exactly; the
/// corners of the A* path are kept so the detour never cuts through a blocked cell.
pub(super) fn resample(
    grid: &PlanGrid,
    cells: &[CellXY],
    spacing_m: f64,
    from: (f64, f64),
    to: (f64, f64),
) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = cells.iter().map(|c| grid.cell_center_m(*c)).collect();
    if let Some(f) = pts.first_mut() {
        *f = from;
    }
    if let Some(l) = pts.last_mut() {
        *l = to;
    }
    // Keep direction changes, then thin straight runs to the spacing.
    let mut out = vec![pts[0]];
    let mut since = 0.0;
    for i in 1..pts.len() {
        since += dist(pts[i - 1], pts[i]);
        let corner = i + 1 < pts.len() && {
            let (a, b, c) = (pts[i - 1], pts[i], pts[i + 1]);
            ((b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0)).abs() > 1e-9
        };
        if since >= spacing_m || corner || i + 1 == pts.len() {
            out.push(pts[i]);
            since = 0.0;
        }
    }
    out
}
