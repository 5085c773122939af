//! Ground-truth traversability labels: what the mapper is scored against.
//!
//! For a lattice cell C (square `[cx*s, (cx+1)*s) x [cy*s, (cy+1)*s)`, s = cell size), with the
//! ground height field's vertices (5 cm spacing) and the profile's `max_step_m`, `max_slope_deg`,
//! `height_m` and `clearance_m`:
//!
//! - **inside vertices**: height-field vertices whose position lies in the closed square of C.
//! - **step_m** = the largest |h(p) - h(q)| over 4-adjacent vertex pairs (p, q) with p inside
//!   C (q may lie in a neighbouring cell, so a curb on the cell border counts for both cells).
//!   STEP when `step_m >= max_step_m - step_tolerance_m` (tolerance 1 cm for the terrain slope
//!   across the 5 cm vertex spacing): a 10 cm curb is a step, a 5 cm one is not.
//! - **slope_deg** = the tilt of the least-squares plane through the vertices within
//!   `slope_margin_m` (0.2 m) of C. SLOPE when `slope_deg > max_slope_deg`.
//! - **HOLE** when an inside vertex belongs to a hole (any depth: the floor of a hole is not a
//!   place the robot can be; its rim is also a step).
//! - **OBSTACLE** when a static solid's footprint overlaps C's square and its vertical extent
//!   overlaps `[min ground - 0.05, max ground + height_m + clearance_m]` over C's inside
//!   vertices. Canopies and overhangs higher than that are not obstacles. Walkers are dynamic
//!   and never labelled.
//! - **OUTSIDE** when C is not fully inside the world: state `Unknown`.
//!
//! A cell is `Obstacle` when any reason is set (except OUTSIDE), else `Traversable`. Labels are
//! per cell, not inflated by the robot footprint: the mapper's own `Obstacle` cells (before its
//! inflation to `Inflated`) are what these compare with; the footprint enters through inflation.
//! Platform drop-offs are steps (their edge jump exceeds `max_step_m`).

use crate::world::{Obb, World, FLAG_HOLE};
use common::grid::{CellState, Lattice};
use common::robot::RobotProfile;

/// Reason bit: a step of `max_step_m` or more at or inside the cell.
pub const REASON_STEP: u8 = 1;
/// Reason bit: local slope above `max_slope_deg`.
pub const REASON_SLOPE: u8 = 2;
/// Reason bit: a solid occupies the cell below the robot's height plus clearance.
pub const REASON_OBSTACLE: u8 = 4;
/// Reason bit: the cell lies in a hole.
pub const REASON_HOLE: u8 = 8;
/// Reason bit: the cell is not fully inside the world.
pub const REASON_OUTSIDE: u8 = 16;

/// Thresholds of the label definition (from a [`RobotProfile`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LabelParams {
    /// Highest climbable step, metres.
    pub max_step_m: f64,
    /// Tolerance below `max_step_m` still counted as a step, metres.
    pub step_tolerance_m: f64,
    /// Steepest climbable slope, degrees.
    pub max_slope_deg: f64,
    /// Robot height, metres.
    pub robot_height_m: f64,
    /// Clearance above the robot height, metres.
    pub clearance_m: f64,
    /// Margin around the cell for the slope plane fit, metres.
    pub slope_margin_m: f64,
}

impl LabelParams {
    /// The thresholds of a robot profile.
    pub fn from_profile(p: &RobotProfile) -> Self {
        Self {
            max_step_m: p.max_step_m,
            step_tolerance_m: 0.01,
            max_slope_deg: p.max_slope_deg,
            robot_height_m: p.height_m,
            clearance_m: p.clearance_m,
            slope_margin_m: 0.2,
        }
    }
}

impl Default for LabelParams {
    fn default() -> Self {
        Self::from_profile(&RobotProfile::default())
    }
}

/// The truth of one cell.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct TruthCell {
    /// `Traversable`, `Obstacle`, or `Unknown` outside the world.
    pub state: CellState,
    /// `REASON_*` bits.
    pub reasons: u8,
    /// Largest vertex-to-vertex height jump at the cell, metres.
    pub step_m: f32,
    /// Local slope, degrees.
    pub slope_deg: f32,
    /// Mean ground height, metres.
    pub height_m: f32,
}

/// Truth labels of a rectangular window of lattice cells.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthGrid {
    /// The lattice.
    pub lattice: Lattice,
    /// Global index of the first column.
    pub cx0: i64,
    /// Global index of the first row.
    pub cy0: i64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major cells (row = y).
    pub cells: Vec<TruthCell>,
}

impl TruthGrid {
    /// The cell at global index (cx, cy), if inside the window.
    pub fn get(&self, cx: i64, cy: i64) -> Option<&TruthCell> {
        let i = cx - self.cx0;
        let j = cy - self.cy0;
        if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
            return None;
        }
        self.cells.get(j as usize * self.width + i as usize)
    }

    /// The cell holding map point (x, y).
    pub fn at(&self, x_m: f64, y_m: f64) -> Option<&TruthCell> {
        let (cx, cy) = self.lattice.cell_of(x_m, y_m);
        self.get(cx, cy)
    }
}

impl World {
    /// Truth labels for the `width` x `height` cells starting at global cell (cx0, cy0).
    pub fn truth_labels(
        &self,
        lattice: &Lattice,
        cx0: i64,
        cy0: i64,
        width: usize,
        height: usize,
        params: &LabelParams,
    ) -> TruthGrid {
        let s = lattice.cell_size_f64();
        let g = &self.ground;
        let (gx0, gy0, nx, ny) = g.grid();
        let res = g.resolution_m();
        let gx1 = gx0 + (nx - 1) as f64 * res;
        let gy1 = gy0 + (ny - 1) as f64 * res;
        let mut cells = vec![TruthCell::default(); width * height];
        // Vertex index range of the closed interval [a, b] along one axis.
        let span = |a: f64, b: f64, o: f64, n: usize| -> Option<(usize, usize)> {
            let i0 = ((a - o) / res - 1e-9).ceil().max(0.0);
            let i1 = ((b - o) / res + 1e-9).floor().min((n - 1) as f64);
            (i1 >= i0).then_some((i0 as usize, i1 as usize))
        };
        for j in 0..height {
            for i in 0..width {
                let (cx, cy) = (cx0 + i as i64, cy0 + j as i64);
                let (x0, y0) = ((cx as f64) * s, (cy as f64) * s);
                let (x1, y1) = (x0 + s, y0 + s);
                let c = &mut cells[j * width + i];
                if x0 < gx0 - 1e-9 || y0 < gy0 - 1e-9 || x1 > gx1 + 1e-9 || y1 > gy1 + 1e-9 {
                    c.state = CellState::Unknown;
                    c.reasons = REASON_OUTSIDE;
                    continue;
                }
                let (Some((i0, i1)), Some((j0, j1))) =
                    (span(x0, x1, gx0, nx), span(y0, y1, gy0, ny))
                else {
                    c.state = CellState::Unknown;
                    c.reasons = REASON_OUTSIDE;
                    continue;
                };
                let mut step = 0.0f64;
                let mut sum = 0.0;
                let mut n = 0usize;
                let mut hole = false;
                for vj in j0..=j1 {
                    for vi in i0..=i1 {
                        let h = g.vertex(vi, vj);
                        sum += h;
                        n += 1;
                        hole |= g.vertex_flags(vi, vj) & FLAG_HOLE != 0;
                        if vi + 1 < nx {
                            step = step.max((g.vertex(vi + 1, vj) - h).abs());
                        }
                        if vi > 0 {
                            step = step.max((g.vertex(vi - 1, vj) - h).abs());
                        }
                        if vj + 1 < ny {
                            step = step.max((g.vertex(vi, vj + 1) - h).abs());
                        }
                        if vj > 0 {
                            step = step.max((g.vertex(vi, vj - 1) - h).abs());
                        }
                    }
                }
                c.step_m = step as f32;
                c.height_m = (sum / n.max(1) as f64) as f32;
                c.slope_deg = slope_deg(
                    self,
                    x0 - params.slope_margin_m,
                    y0 - params.slope_margin_m,
                    x1 + params.slope_margin_m,
                    y1 + params.slope_margin_m,
                ) as f32;
                if step >= params.max_step_m - params.step_tolerance_m {
                    c.reasons |= REASON_STEP;
                }
                if c.slope_deg as f64 > params.max_slope_deg {
                    c.reasons |= REASON_SLOPE;
                }
                if hole {
                    c.reasons |= REASON_HOLE;
                }
            }
        }
        // Obstacles: rasterise each solid over the cells its bounds cover.
        for solid in self.solids() {
            let (bx, by, br) = solid.bounds();
            let (ci0, cj0) = lattice.cell_of(bx - br, by - br);
            let (ci1, cj1) = lattice.cell_of(bx + br, by + br);
            for cy in cj0.max(cy0)..=cj1.min(cy0 + height as i64 - 1) {
                for cx in ci0.max(cx0)..=ci1.min(cx0 + width as i64 - 1) {
                    let k = (cy - cy0) as usize * width + (cx - cx0) as usize;
                    if cells[k].reasons & REASON_OUTSIDE != 0 {
                        continue;
                    }
                    let sq = Obb {
                        cx: (cx as f64 + 0.5) * s,
                        cy: (cy as f64 + 0.5) * s,
                        hx: 0.5 * s,
                        hy: 0.5 * s,
                        yaw: 0.0,
                    };
                    if !solid.overlaps(&sq) {
                        continue;
                    }
                    let (lo, hi) = ground_minmax(self, &sq);
                    if solid.z0_m <= hi + params.robot_height_m + params.clearance_m
                        && solid.z1_m >= lo - 0.05
                    {
                        cells[k].reasons |= REASON_OBSTACLE;
                    }
                }
            }
        }
        for c in &mut cells {
            if c.reasons & REASON_OUTSIDE == 0 {
                c.state = if c.reasons != 0 {
                    CellState::Obstacle
                } else {
                    CellState::Traversable
                };
            }
        }
        TruthGrid {
            lattice: *lattice,
            cx0,
            cy0,
            width,
            height,
            cells,
        }
    }
}

fn ground_minmax(w: &World, sq: &Obb) -> (f64, f64) {
    let mut r = (f64::INFINITY, f64::NEG_INFINITY);
    let n = 4;
    for a in 0..=n {
        for b in 0..=n {
            let x = sq.cx - sq.hx + 2.0 * sq.hx * a as f64 / n as f64;
            let y = sq.cy - sq.hy + 2.0 * sq.hy * b as f64 / n as f64;
            if let Some(h) = w.ground_height(x, y) {
                r = (r.0.min(h), r.1.max(h));
            }
        }
    }
    r
}

/// Tilt of the least-squares plane through the height-field vertices in a box, degrees.
fn slope_deg(w: &World, x0: f64, y0: f64, x1: f64, y1: f64) -> f64 {
    let g = &w.ground;
    let (gx0, gy0, nx, ny) = g.grid();
    let res = g.resolution_m();
    let i0 = ((x0 - gx0) / res).ceil().max(0.0) as usize;
    let j0 = ((y0 - gy0) / res).ceil().max(0.0) as usize;
    let i1 = (((x1 - gx0) / res).floor().max(0.0) as usize).min(nx - 1);
    let j1 = (((y1 - gy0) / res).floor().max(0.0) as usize).min(ny - 1);
    if i1 <= i0 || j1 <= j0 {
        return 0.0;
    }
    let (mx, my) = (0.5 * (i0 + i1) as f64, 0.5 * (j0 + j1) as f64);
    let (mut sxx, mut syy, mut sxy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for j in j0..=j1 {
        for i in i0..=i1 {
            let x = (i as f64 - mx) * res;
            let y = (j as f64 - my) * res;
            let z = g.vertex(i, j);
            sxx += x * x;
            syy += y * y;
            sxy += x * y;
            sxz += x * z;
            syz += y * z;
        }
    }
    // Coordinates are centred (sum x = sum y = 0), so the plane's offset decouples: 2x2 for the gradient.
    let det = sxx * syy - sxy * sxy;
    if det.abs() < 1e-12 {
        return 0.0;
    }
    let a = (sxz * syy - syz * sxy) / det;
    let b = (syz * sxx - sxz * sxy) / det;
    a.hypot(b).atan().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;

    fn world(features: &str) -> World {
        let sc = Scenario::from_toml_str(
            &format!(
                r#"
name = "labels"
[datum]
lat_deg = 48.0
lon_deg = 16.0
h_m = 200.0
[extent]
x_min_m = -10.0
x_max_m = 30.0
y_min_m = -10.0
y_max_m = 10.0
[terrain]
undulation_amplitude_m = 0.05
undulation_wavelength_m = 20.0
{features}
"#
            ),
            "test",
        )
        .unwrap();
        World::new(&sc)
    }

    fn label(w: &World, x: f64, y: f64) -> TruthCell {
        let lat = Lattice::default();
        let (cx, cy) = lat.cell_of(x, y);
        let g = w.truth_labels(&lat, cx - 1, cy - 1, 3, 3, &LabelParams::default());
        *g.get(cx, cy).unwrap()
    }

    #[test]
    fn steps_five_cm_traversable_ten_and_more_not() {
        let w = world(
            r#"
[[step]]
rect = { center_m = [0.0, -5.0], size_m = [4.0, 4.0] }
height_m = 0.05
[[step]]
rect = { center_m = [10.0, -5.0], size_m = [4.0, 4.0] }
height_m = 0.10
[[step]]
rect = { center_m = [20.0, -5.0], size_m = [4.0, 4.0] }
height_m = 0.15
"#,
        );
        // Edges at x = -2, 8, 18 (west sides).
        let c5 = label(&w, -2.0, -5.0);
        assert_eq!(c5.state, CellState::Traversable, "{c5:?}");
        assert!((c5.step_m - 0.05).abs() < 0.01, "{c5:?}");
        for x in [8.0, 18.0] {
            let c = label(&w, x, -5.0);
            assert_eq!(c.state, CellState::Obstacle, "{c:?}");
            assert!(c.reasons & REASON_STEP != 0);
        }
        // Also the cell on the other side of the border (curb on a cell border counts for both).
        assert_eq!(label(&w, 7.9, -5.0).state, CellState::Obstacle);
        // Top of the curb, away from edges: traversable.
        assert_eq!(label(&w, 10.0, -5.0).state, CellState::Traversable);
        assert_eq!(label(&w, 4.0, 5.0).state, CellState::Traversable);
    }

    #[test]
    fn ramps_fifteen_yes_thirty_no() {
        let w = world(
            r#"
[[ramp]]
x_m = 0.0
y_m = 0.0
yaw_deg = 0.0
slope_deg = 15.0
width_m = 3.0
length_m = 4.0
landing_m = 2.0
[[ramp]]
x_m = 12.0
y_m = 0.0
yaw_deg = 0.0
slope_deg = 30.0
width_m = 3.0
length_m = 3.0
landing_m = 2.0
"#,
        );
        let c15 = label(&w, 2.0, 0.1);
        assert_eq!(c15.state, CellState::Traversable, "{c15:?}");
        assert!((c15.slope_deg - 15.0).abs() < 1.5, "{c15:?}");
        let c30 = label(&w, 13.5, 0.1);
        assert_eq!(c30.state, CellState::Obstacle, "{c30:?}");
        assert!(c30.reasons & REASON_SLOPE != 0);
        // The ramp's side is a drop of ~0.5 m: a step.
        assert!(label(&w, 2.5, 1.5).reasons & REASON_STEP != 0);
    }

    #[test]
    fn canopy_is_not_an_obstacle_but_trunk_is() {
        let w = world(
            r#"
[[tree]]
x_m = 5.0
y_m = 0.0
trunk_radius_m = 0.2
canopy_base_m = 2.2
canopy_radius_m = 3.0
canopy_height_m = 3.0
"#,
        );
        assert_eq!(label(&w, 5.0, 0.0).state, CellState::Obstacle);
        assert_eq!(label(&w, 7.0, 0.5).state, CellState::Traversable);
        assert_eq!(label(&w, 3.5, -1.5).state, CellState::Traversable);
    }

    #[test]
    fn platform_edge_and_hole_not_traversable() {
        let w = world(
            r#"
[[platform]]
rect = { center_m = [5.0, 0.0], size_m = [6.0, 6.0] }
height_m = 1.0
[[hole]]
rect = { center_m = [20.0, 0.0], size_m = [1.0, 1.0] }
depth_m = 0.5
"#,
        );
        assert_eq!(label(&w, 5.0, 0.0).state, CellState::Traversable);
        let edge = label(&w, 8.0, 0.0);
        assert_eq!(edge.state, CellState::Obstacle);
        assert!(edge.step_m > 0.9, "{edge:?}");
        let hole = label(&w, 20.0, 0.0);
        assert!(hole.reasons & REASON_HOLE != 0, "{hole:?}");
        assert_eq!(label(&w, -9.99, 0.0).state, CellState::Traversable);
        let out = label(&w, -10.1, 0.0);
        assert_eq!(out.state, CellState::Unknown);
    }
}
