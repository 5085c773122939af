//! The simulated world: a ground height field (terrain plus curbs, stairs, ramps, platforms and
//! holes baked in), analytic solids (walls, poles, trees, boxes, cars) and walkers.
//!
//! Ray casting: solids are tested analytically (slab tests against vertical cylinders, yawed boxes
//! and ellipsoids); the ground is marched with a 2D DDA through a three-level max-height pyramid
//! (5 cm cells, 20 cm blocks, 1.6 m blocks) so rays skip space far above the ground, and the
//! surface inside a fine cell is bilinear in the four vertex heights.

use crate::scenario::{Rect, Scenario, WalkMode, WalkerSpec};
use nalgebra::{Point3, Vector3};

/// Vertex flag: paved (no grass on returns).
pub const FLAG_PAVED: u8 = 1;
/// Vertex flag: inside a hole.
pub const FLAG_HOLE: u8 = 2;

/// Fine cells per level-1 block side, and level-1 blocks per level-2 block side.
const MIP_FACTORS: [usize; 2] = [4, 8];

/// The ground surface sampled on a regular vertex grid.
#[derive(Clone, Debug)]
pub struct HeightField {
    x0_m: f64,
    y0_m: f64,
    res_m: f64,
    nx: usize,
    ny: usize,
    h_m: Vec<f32>,
    flags: Vec<u8>,
    /// Max-height pyramid; level k (1-based) block covers `cells_per_block[k]` fine cells.
    mips: Vec<Mip>,
    max_h_m: f64,
}

#[derive(Clone, Debug)]
struct Mip {
    cells: usize,
    nbx: usize,
    nby: usize,
    max_m: Vec<f32>,
}

impl HeightField {
    fn new(x0_m: f64, y0_m: f64, res_m: f64, nx: usize, ny: usize) -> Self {
        Self {
            x0_m,
            y0_m,
            res_m,
            nx,
            ny,
            h_m: vec![0.0; nx * ny],
            flags: vec![0; nx * ny],
            mips: Vec::new(),
            max_h_m: 0.0,
        }
    }

    /// Vertex spacing, metres.
    pub fn resolution_m(&self) -> f64 {
        self.res_m
    }

    /// (x, y) of the first vertex and the number of vertices along x and y.
    pub fn grid(&self) -> (f64, f64, usize, usize) {
        (self.x0_m, self.y0_m, self.nx, self.ny)
    }

    /// Height of vertex (i, j), metres.
    pub fn vertex(&self, i: usize, j: usize) -> f64 {
        self.h_m[j * self.nx + i] as f64
    }

    /// Flags of vertex (i, j) (`FLAG_*`).
    pub fn vertex_flags(&self, i: usize, j: usize) -> u8 {
        self.flags[j * self.nx + i]
    }

    /// Bilinear ground height at (x, y); `None` outside the grid.
    pub fn height(&self, x_m: f64, y_m: f64) -> Option<f64> {
        let fx = (x_m - self.x0_m) / self.res_m;
        let fy = (y_m - self.y0_m) / self.res_m;
        if !(fx >= 0.0 && fy >= 0.0 && fx <= (self.nx - 1) as f64 && fy <= (self.ny - 1) as f64) {
            return None;
        }
        let i = (fx as usize).min(self.nx - 2);
        let j = (fy as usize).min(self.ny - 2);
        Some(self.bilinear(i, j, fx - i as f64, fy - j as f64))
    }

    /// Flags of the vertex nearest (x, y) (0 outside).
    pub fn flags_at(&self, x_m: f64, y_m: f64) -> u8 {
        match self.nearest(x_m, y_m) {
            Some((i, j)) => self.flags[j * self.nx + i],
            None => 0,
        }
    }

    fn nearest(&self, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
        let fx = ((x_m - self.x0_m) / self.res_m).round();
        let fy = ((y_m - self.y0_m) / self.res_m).round();
        if fx >= 0.0 && fy >= 0.0 && fx < self.nx as f64 && fy < self.ny as f64 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    #[inline]
    fn bilinear(&self, i: usize, j: usize, u: f64, v: f64) -> f64 {
        let k = j * self.nx + i;
        let h00 = self.h_m[k] as f64;
        let h10 = self.h_m[k + 1] as f64;
        let h01 = self.h_m[k + self.nx] as f64;
        let h11 = self.h_m[k + self.nx + 1] as f64;
        h00 + (h10 - h00) * u + (h01 - h00) * v + (h00 - h10 - h01 + h11) * u * v
    }

    /// Index ranges of vertices inside an axis-aligned box (clamped to the grid).
    fn vertex_range(
        &self,
        xmin: f64,
        ymin: f64,
        xmax: f64,
        ymax: f64,
    ) -> Option<(usize, usize, usize, usize)> {
        let i0 = ((xmin - self.x0_m) / self.res_m).ceil().max(0.0);
        let j0 = ((ymin - self.y0_m) / self.res_m).ceil().max(0.0);
        let i1 = ((xmax - self.x0_m) / self.res_m)
            .floor()
            .min((self.nx - 1) as f64);
        let j1 = ((ymax - self.y0_m) / self.res_m)
            .floor()
            .min((self.ny - 1) as f64);
        if i1 < i0 || j1 < j0 {
            return None;
        }
        Some((i0 as usize, j0 as usize, i1 as usize, j1 as usize))
    }

    /// Rebuilds the max-height pyramid (after the field changed).
    fn build_mips(&mut self) {
        self.mips.clear();
        let cells_x = self.nx - 1;
        let cells_y = self.ny - 1;
        let mut cells = 1usize;
        for &f in &MIP_FACTORS {
            cells *= f;
            let nbx = cells_x.div_ceil(cells);
            let nby = cells_y.div_ceil(cells);
            let mut max_m = vec![f32::NEG_INFINITY; nbx * nby];
            for bj in 0..nby {
                for bi in 0..nbx {
                    // Vertices of the block, including its far edge (shared with the next block).
                    let i0 = bi * cells;
                    let j0 = bj * cells;
                    let i1 = (i0 + cells).min(self.nx - 1);
                    let j1 = (j0 + cells).min(self.ny - 1);
                    let mut m = f32::NEG_INFINITY;
                    for j in j0..=j1 {
                        let row = &self.h_m[j * self.nx + i0..=j * self.nx + i1];
                        for &h in row {
                            m = m.max(h);
                        }
                    }
                    max_m[bj * nbx + bi] = m;
                }
            }
            self.mips.push(Mip {
                cells,
                nbx,
                nby,
                max_m,
            });
        }
        self.max_h_m = self.h_m.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b)) as f64;
    }

    /// First intersection of the ray `o + t d` (t in `[0, t_max]`) with the ground.
    pub fn raycast(&self, o: &Point3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<f64> {
        // Clip to the grid rectangle.
        let xmax = self.x0_m + (self.nx - 1) as f64 * self.res_m;
        let ymax = self.y0_m + (self.ny - 1) as f64 * self.res_m;
        let (mut ta, mut tb) = (0.0f64, t_max);
        for (oc, dc, lo, hi) in [(o.x, d.x, self.x0_m, xmax), (o.y, d.y, self.y0_m, ymax)] {
            if dc.abs() < 1e-12 {
                if oc < lo || oc > hi {
                    return None;
                }
            } else {
                let t1 = (lo - oc) / dc;
                let t2 = (hi - oc) / dc;
                ta = ta.max(t1.min(t2));
                tb = tb.min(t1.max(t2));
            }
        }
        // Above the highest vertex and rising: nothing to hit.
        if d.z > 1e-12 {
            tb = tb.min((self.max_h_m - o.z) / d.z);
        } else if o.z > self.max_h_m && d.z > -1e-12 {
            return None;
        }
        if ta >= tb {
            return None;
        }
        self.march(self.mips.len(), o, d, ta, tb, None)
    }

    /// 2D DDA at one pyramid level over `[ta, tb]`; `parent` limits cell indices to its children.
    fn march(
        &self,
        lvl: usize,
        o: &Point3<f64>,
        d: &Vector3<f64>,
        ta: f64,
        tb: f64,
        parent: Option<(usize, usize, usize)>,
    ) -> Option<f64> {
        let (cells, nbx, nby) = if lvl == 0 {
            (1, self.nx - 1, self.ny - 1)
        } else {
            let m = &self.mips[lvl - 1];
            (m.cells, m.nbx, m.nby)
        };
        let s = self.res_m * cells as f64;
        let tm = ta + (tb - ta) * 1e-6;
        let px = o.x + d.x * tm - self.x0_m;
        let py = o.y + d.y * tm - self.y0_m;
        let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (0i64, 0i64, nbx as i64 - 1, nby as i64 - 1);
        if let Some((pi, pj, f)) = parent {
            lo_x = (pi * f) as i64;
            lo_y = (pj * f) as i64;
            hi_x = hi_x.min(lo_x + f as i64 - 1);
            hi_y = hi_y.min(lo_y + f as i64 - 1);
        }
        let mut ix = ((px / s).floor() as i64).clamp(lo_x, hi_x);
        let mut iy = ((py / s).floor() as i64).clamp(lo_y, hi_y);
        let (step_x, mut tmax_x, tdel_x) = axis_setup(o.x - self.x0_m, d.x, s, ix);
        let (step_y, mut tmax_y, tdel_y) = axis_setup(o.y - self.y0_m, d.y, s, iy);
        let mut t0 = ta;
        loop {
            let t1 = tmax_x.min(tmax_y).min(tb);
            if t1 > t0 {
                if lvl == 0 {
                    if let Some(t) = self.cell_hit(ix as usize, iy as usize, o, d, t0, t1) {
                        return Some(t);
                    }
                } else {
                    let m = &self.mips[lvl - 1];
                    let zmin = o.z + d.z * if d.z < 0.0 { t1 } else { t0 };
                    if zmin <= m.max_m[iy as usize * m.nbx + ix as usize] as f64 {
                        let f = MIP_FACTORS[lvl - 1];
                        if let Some(t) =
                            self.march(lvl - 1, o, d, t0, t1, Some((ix as usize, iy as usize, f)))
                        {
                            return Some(t);
                        }
                    }
                }
            }
            if t1 >= tb {
                return None;
            }
            if tmax_x < tmax_y {
                ix += step_x;
                t0 = tmax_x;
                tmax_x += tdel_x;
            } else {
                iy += step_y;
                t0 = tmax_y;
                tmax_y += tdel_y;
            }
            if ix < lo_x || ix > hi_x || iy < lo_y || iy > hi_y {
                return None;
            }
        }
    }

    /// Crossing of the ray with the bilinear surface of fine cell (i, j) within `[t0, t1]`.
    #[inline]
    fn cell_hit(
        &self,
        i: usize,
        j: usize,
        o: &Point3<f64>,
        d: &Vector3<f64>,
        t0: f64,
        t1: f64,
    ) -> Option<f64> {
        let inv = 1.0 / self.res_m;
        let cx = self.x0_m + i as f64 * self.res_m;
        let cy = self.y0_m + j as f64 * self.res_m;
        let uv = |t: f64| {
            (
                ((o.x + d.x * t - cx) * inv).clamp(0.0, 1.0),
                ((o.y + d.y * t - cy) * inv).clamp(0.0, 1.0),
            )
        };
        let (u0, v0) = uv(t0);
        let f0 = o.z + d.z * t0 - self.bilinear(i, j, u0, v0);
        if f0 <= 0.0 {
            return Some(t0);
        }
        let (u1, v1) = uv(t1);
        let f1 = o.z + d.z * t1 - self.bilinear(i, j, u1, v1);
        if f1 <= 0.0 {
            return Some(t0 + (t1 - t0) * f0 / (f0 - f1));
        }
        None
    }
}

fn axis_setup(o: f64, d: f64, s: f64, i: i64) -> (i64, f64, f64) {
    if d > 1e-12 {
        (1, ((i + 1) as f64 * s - o) / d, s / d)
    } else if d < -1e-12 {
        (-1, (i as f64 * s - o) / d, -s / d)
    } else {
        (0, f64::INFINITY, f64::INFINITY)
    }
}

/// What a solid is (for intensities, labels and collision reports).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum SolidKind {
    /// Wall segment.
    Wall,
    /// Pole.
    Pole,
    /// Tree trunk.
    Trunk,
    /// Tree canopy.
    Canopy,
    /// Box.
    Box,
    /// Car body or cabin.
    Car,
}

/// The 2D footprint of a solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// Vertical cylinder.
    Cylinder {
        /// Centre x, metres.
        cx: f64,
        /// Centre y, metres.
        cy: f64,
        /// Radius, metres.
        r: f64,
    },
    /// Box yawed about z.
    Box {
        /// Centre x, metres.
        cx: f64,
        /// Centre y, metres.
        cy: f64,
        /// Half length along its x, metres.
        hx: f64,
        /// Half width along its y, metres.
        hy: f64,
        /// Yaw, radians.
        yaw: f64,
    },
    /// Ellipsoid with a vertical axis, between the solid's `z0` and `z1`.
    Ellipsoid {
        /// Centre x, metres.
        cx: f64,
        /// Centre y, metres.
        cy: f64,
        /// Horizontal radius, metres.
        r: f64,
    },
}

/// A static obstacle: a footprint extruded between two heights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Solid {
    /// Footprint.
    pub shape: Shape,
    /// Bottom, metres (map frame).
    pub z0_m: f64,
    /// Top, metres.
    pub z1_m: f64,
    /// What it is.
    pub kind: SolidKind,
    /// Index of the scenario feature (or added obstacle) it came from.
    pub feature: u32,
}

impl Solid {
    /// Bounding circle (centre x, centre y, radius).
    pub fn bounds(&self) -> (f64, f64, f64) {
        match self.shape {
            Shape::Cylinder { cx, cy, r } | Shape::Ellipsoid { cx, cy, r } => (cx, cy, r),
            Shape::Box { cx, cy, hx, hy, .. } => (cx, cy, hx.hypot(hy)),
        }
    }

    /// Entry distance of the ray `o + t d` (t >= 0), if it hits.
    #[inline]
    pub fn ray(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<f64> {
        let (mut tin, mut tout) = (0.0f64, f64::INFINITY);
        match self.shape {
            Shape::Ellipsoid { cx, cy, r } => {
                let rz = 0.5 * (self.z1_m - self.z0_m);
                let cz = 0.5 * (self.z1_m + self.z0_m);
                let q = Vector3::new((o.x - cx) / r, (o.y - cy) / r, (o.z - cz) / rz);
                let e = Vector3::new(d.x / r, d.y / r, d.z / rz);
                let a = e.norm_squared();
                let b = q.dot(&e);
                let c = q.norm_squared() - 1.0;
                let disc = b * b - a * c;
                if disc < 0.0 || a < 1e-18 {
                    return None;
                }
                let sq = disc.sqrt();
                let t1 = (-b + sq) / a;
                if t1 < 0.0 {
                    return None;
                }
                return Some(((-b - sq) / a).max(0.0));
            }
            Shape::Cylinder { cx, cy, r } => {
                let ox = o.x - cx;
                let oy = o.y - cy;
                let a = d.x * d.x + d.y * d.y;
                let c = ox * ox + oy * oy - r * r;
                if a < 1e-18 {
                    if c > 0.0 {
                        return None;
                    }
                } else {
                    let b = ox * d.x + oy * d.y;
                    let disc = b * b - a * c;
                    if disc < 0.0 {
                        return None;
                    }
                    let sq = disc.sqrt();
                    tin = (-b - sq) / a;
                    tout = (-b + sq) / a;
                }
            }
            Shape::Box {
                cx,
                cy,
                hx,
                hy,
                yaw,
            } => {
                let (s, c) = yaw.sin_cos();
                let ox = o.x - cx;
                let oy = o.y - cy;
                let lx = c * ox + s * oy;
                let ly = -s * ox + c * oy;
                let dx = c * d.x + s * d.y;
                let dy = -s * d.x + c * d.y;
                if !slab(lx, dx, -hx, hx, &mut tin, &mut tout)
                    || !slab(ly, dy, -hy, hy, &mut tin, &mut tout)
                {
                    return None;
                }
            }
        }
        if !slab(o.z, d.z, self.z0_m, self.z1_m, &mut tin, &mut tout) {
            return None;
        }
        if tin > tout || tout < 0.0 {
            return None;
        }
        Some(tin.max(0.0))
    }

    /// Whether the footprint overlaps an oriented rectangle.
    pub fn overlaps(&self, r: &Obb) -> bool {
        match self.shape {
            Shape::Cylinder { cx, cy, r: rad } | Shape::Ellipsoid { cx, cy, r: rad } => {
                r.distance_to(cx, cy) <= rad
            }
            Shape::Box {
                cx,
                cy,
                hx,
                hy,
                yaw,
            } => r.overlaps(&Obb {
                cx,
                cy,
                hx,
                hy,
                yaw,
            }),
        }
    }
}

#[inline]
fn slab(o: f64, d: f64, lo: f64, hi: f64, tin: &mut f64, tout: &mut f64) -> bool {
    if d.abs() < 1e-15 {
        return o >= lo && o <= hi;
    }
    let t1 = (lo - o) / d;
    let t2 = (hi - o) / d;
    let (a, b) = if t1 < t2 { (t1, t2) } else { (t2, t1) };
    *tin = tin.max(a);
    *tout = tout.min(b);
    *tin <= *tout
}

/// An oriented rectangle in the plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obb {
    /// Centre x, metres.
    pub cx: f64,
    /// Centre y, metres.
    pub cy: f64,
    /// Half extent along its x, metres.
    pub hx: f64,
    /// Half extent along its y, metres.
    pub hy: f64,
    /// Yaw, radians.
    pub yaw: f64,
}

impl Obb {
    /// Distance from a point to the rectangle (0 inside).
    pub fn distance_to(&self, x: f64, y: f64) -> f64 {
        let (s, c) = self.yaw.sin_cos();
        let dx = x - self.cx;
        let dy = y - self.cy;
        let lx = (c * dx + s * dy).abs() - self.hx;
        let ly = (-s * dx + c * dy).abs() - self.hy;
        lx.max(0.0).hypot(ly.max(0.0))
    }

    /// Whether the point is inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (s, c) = self.yaw.sin_cos();
        let dx = x - self.cx;
        let dy = y - self.cy;
        (c * dx + s * dy).abs() <= self.hx && (-s * dx + c * dy).abs() <= self.hy
    }

    /// Separating-axis overlap test.
    pub fn overlaps(&self, o: &Obb) -> bool {
        let axes = |b: &Obb| {
            let (s, c) = b.yaw.sin_cos();
            [(c, s), (-s, c)]
        };
        let proj = |b: &Obb, ax: (f64, f64)| {
            let [(c0, s0), (c1, s1)] = axes(b);
            b.hx * (c0 * ax.0 + s0 * ax.1).abs() + b.hy * (c1 * ax.0 + s1 * ax.1).abs()
        };
        let dx = o.cx - self.cx;
        let dy = o.cy - self.cy;
        for ax in axes(self).into_iter().chain(axes(o)) {
            let dist = (dx * ax.0 + dy * ax.1).abs();
            if dist > proj(self, ax) + proj(o, ax) {
                return false;
            }
        }
        true
    }

    /// The axis-aligned bounds (xmin, ymin, xmax, ymax).
    pub fn aabb(&self) -> (f64, f64, f64, f64) {
        let (s, c) = self.yaw.sin_cos();
        let ex = self.hx * c.abs() + self.hy * s.abs();
        let ey = self.hx * s.abs() + self.hy * c.abs();
        (self.cx - ex, self.cy - ey, self.cx + ex, self.cy + ey)
    }

    fn from_rect(r: &Rect) -> Obb {
        Obb {
            cx: r.center_m[0],
            cy: r.center_m[1],
            hx: 0.5 * r.size_m[0],
            hy: 0.5 * r.size_m[1],
            yaw: r.yaw_deg.to_radians(),
        }
    }
}

/// A pedestrian on a polyline.
#[derive(Clone, Debug)]
pub struct Walker {
    points: Vec<[f64; 2]>,
    /// Cumulative length at each vertex (loop: includes the closing segment).
    cum_m: Vec<f64>,
    speed_mps: f64,
    mode: WalkMode,
    phase_m: f64,
    /// Body radius, metres.
    pub radius_m: f64,
    /// Body height, metres.
    pub height_m: f64,
}

impl Walker {
    fn new(spec: &WalkerSpec) -> Self {
        let mut points = spec.points.clone();
        if spec.mode == WalkMode::Loop {
            points.push(spec.points[0]);
        }
        let mut cum_m = vec![0.0];
        for w in points.windows(2) {
            let l = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            cum_m.push(cum_m.last().copied().unwrap_or(0.0) + l);
        }
        Self {
            points,
            cum_m,
            speed_mps: spec.speed_mps,
            mode: spec.mode,
            phase_m: spec.phase_m,
            radius_m: spec.radius_m,
            height_m: spec.height_m,
        }
    }

    /// Position (x, y) at time `t_s`.
    pub fn position(&self, t_s: f64) -> [f64; 2] {
        let total = self.cum_m.last().copied().unwrap_or(0.0);
        if total <= 1e-9 {
            return self.points[0];
        }
        let s = self.phase_m + self.speed_mps * t_s;
        let s = match self.mode {
            WalkMode::Loop => s.rem_euclid(total),
            WalkMode::PingPong => {
                let u = s.rem_euclid(2.0 * total);
                if u > total {
                    2.0 * total - u
                } else {
                    u
                }
            }
        };
        let k = self
            .cum_m
            .partition_point(|&c| c <= s)
            .clamp(1, self.points.len() - 1);
        let l = self.cum_m[k] - self.cum_m[k - 1];
        let f = if l > 1e-12 {
            (s - self.cum_m[k - 1]) / l
        } else {
            0.0
        };
        let a = self.points[k - 1];
        let b = self.points[k];
        [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f]
    }
}

/// A walker's state at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkerState {
    /// Index in the scenario's `[[walker]]` list.
    pub id: usize,
    /// Position x, metres (map frame).
    pub x_m: f64,
    /// Position y, metres.
    pub y_m: f64,
    /// Ground height under the walker, metres.
    pub z_m: f64,
    /// Body radius, metres.
    pub radius_m: f64,
    /// Body height, metres.
    pub height_m: f64,
}

impl WalkerState {
    /// The walker as a solid cylinder.
    pub fn solid(&self) -> Solid {
        Solid {
            shape: Shape::Cylinder {
                cx: self.x_m,
                cy: self.y_m,
                r: self.radius_m,
            },
            z0_m: self.z_m - 0.05,
            z1_m: self.z_m + self.height_m,
            kind: SolidKind::Box,
            feature: self.id as u32,
        }
    }
}

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HitKind {
    /// The ground; `grass` when the surface is unpaved.
    Ground {
        /// Unpaved surface (returns get grass noise).
        grass: bool,
    },
    /// A static solid (index into [`World::solids`]).
    Solid(usize),
    /// A walker (scenario index).
    Walker(usize),
}

/// A ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, metres.
    pub range_m: f64,
    /// What was hit.
    pub kind: HitKind,
}

/// Obstacles that can be added at run time (teach and repeat: a parked car, a fallen tree, an
/// open manhole).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Obstacle {
    /// A box.
    Box(crate::scenario::BoxSpec),
    /// A parked car.
    Car(crate::scenario::CarSpec),
    /// A pole.
    Pole(crate::scenario::PoleSpec),
    /// A tree (standing).
    Tree(crate::scenario::TreeSpec),
    /// A wall (a fallen trunk is a low wall).
    Wall(crate::scenario::WallSpec),
    /// A hole in the ground.
    Hole(crate::scenario::HoleSpec),
}

/// The world: ground, solids and walkers.
#[derive(Clone, Debug)]
pub struct World {
    /// The ground.
    pub ground: HeightField,
    solids: Vec<Solid>,
    walkers: Vec<Walker>,
    /// Grass amplitude of returns off unpaved ground, metres.
    pub grass_amplitude_m: f64,
    base: BaseTerrain,
    next_feature: u32,
}

/// The procedural terrain before features: a sum of three sines.
#[derive(Clone, Copy, Debug)]
struct BaseTerrain {
    waves: [(f64, f64, f64, f64); 3],
}

impl BaseTerrain {
    fn new(amplitude_m: f64, wavelength_m: f64, seed: u64) -> Self {
        // A tiny LCG: the phases only need to differ per seed, not to be statistically good.
        let mut s = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let amps = [1.0, 0.5, 0.25];
        let norm = amplitude_m / 1.75;
        let mut waves = [(0.0, 0.0, 0.0, 0.0); 3];
        for (k, w) in waves.iter_mut().enumerate() {
            let dir = next() * std::f64::consts::TAU;
            let lambda = wavelength_m / [1.0, 1.7, 2.9][k];
            let kk = std::f64::consts::TAU / lambda;
            *w = (
                kk * dir.cos(),
                kk * dir.sin(),
                next() * std::f64::consts::TAU,
                amps[k] * norm,
            );
        }
        Self { waves }
    }

    fn height(&self, x: f64, y: f64) -> f64 {
        self.waves
            .iter()
            .map(|&(kx, ky, ph, a)| a * (kx * x + ky * y + ph).sin())
            .sum()
    }
}

fn seg_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

fn polyline_bounds(pts: &[[f64; 2]], pad: f64) -> (f64, f64, f64, f64) {
    let mut b = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    for p in pts {
        b = (b.0.min(p[0]), b.1.min(p[1]), b.2.max(p[0]), b.3.max(p[1]));
    }
    (b.0 - pad, b.1 - pad, b.2 + pad, b.3 + pad)
}

impl World {
    /// Builds the world of a scenario (bakes the ground, places solids and walkers).
    pub fn new(sc: &Scenario) -> Self {
        let e = &sc.extent;
        let res = sc.terrain.resolution_m;
        let nx = ((e.x_max_m - e.x_min_m) / res).ceil() as usize + 1;
        let ny = ((e.y_max_m - e.y_min_m) / res).ceil() as usize + 1;
        let mut hf = HeightField::new(e.x_min_m, e.y_min_m, res, nx.max(2), ny.max(2));
        let base = BaseTerrain::new(
            sc.terrain.undulation_amplitude_m,
            sc.terrain.undulation_wavelength_m,
            sc.terrain.seed,
        );
        for j in 0..hf.ny {
            let y = hf.y0_m + j as f64 * res;
            for i in 0..hf.nx {
                let x = hf.x0_m + i as f64 * res;
                hf.h_m[j * hf.nx + i] = base.height(x, y) as f32;
            }
        }
        let mut w = World {
            ground: hf,
            solids: Vec::new(),
            walkers: sc.walker.iter().map(Walker::new).collect(),
            grass_amplitude_m: sc.terrain.grass_amplitude_m,
            base,
            next_feature: 0,
        };
        for p in &sc.path {
            let (x0, y0, x1, y1) = polyline_bounds(&p.points, p.width_m);
            w.for_vertices(x0, y0, x1, y1, |_, x, y, _, fl| {
                if p.points
                    .windows(2)
                    .any(|s| seg_distance([x, y], s[0], s[1]) <= 0.5 * p.width_m)
                {
                    *fl |= FLAG_PAVED;
                }
            });
        }
        for s in &sc.step {
            if let Some(r) = &s.rect {
                let o = Obb::from_rect(r);
                let (x0, y0, x1, y1) = o.aabb();
                w.for_vertices(x0, y0, x1, y1, |b, x, y, h, fl| {
                    if o.contains(x, y) {
                        *h = (b + s.height_m) as f32;
                        *fl |= FLAG_PAVED;
                    }
                });
            } else if let Some(pts) = &s.points {
                let (x0, y0, x1, y1) = polyline_bounds(pts, s.width_m);
                w.for_vertices(x0, y0, x1, y1, |b, x, y, h, fl| {
                    if pts
                        .windows(2)
                        .any(|q| seg_distance([x, y], q[0], q[1]) <= 0.5 * s.width_m)
                    {
                        *h = (b + s.height_m) as f32;
                        *fl |= FLAG_PAVED;
                    }
                });
            }
        }
        for p in &sc.platform {
            let o = Obb::from_rect(&p.rect);
            let (x0, y0, x1, y1) = o.aabb();
            w.for_vertices(x0, y0, x1, y1, |b, x, y, h, fl| {
                if o.contains(x, y) {
                    *h = (b + p.height_m) as f32;
                    *fl |= FLAG_PAVED;
                }
            });
        }
        for s in &sc.stairs {
            let run = s.steps as f64 * s.step_depth_m;
            let len = run + s.landing_m;
            let yaw = s.yaw_deg.to_radians();
            let o = Obb {
                cx: s.x_m + 0.5 * len * yaw.cos(),
                cy: s.y_m + 0.5 * len * yaw.sin(),
                hx: 0.5 * len,
                hy: 0.5 * s.width_m,
                yaw,
            };
            let (x0, y0, x1, y1) = o.aabb();
            let (sn, cs) = yaw.sin_cos();
            w.for_vertices(x0, y0, x1, y1, |b, x, y, h, fl| {
                if o.contains(x, y) {
                    let u = (x - s.x_m) * cs + (y - s.y_m) * sn;
                    let k = ((u / s.step_depth_m).floor() as i64 + 1).clamp(1, s.steps as i64);
                    let v = b + k as f64 * s.step_height_m;
                    *h = h.max(v as f32);
                    *fl |= FLAG_PAVED;
                }
            });
        }
        for r in &sc.ramp {
            let len = r.length_m + r.landing_m;
            let yaw = r.yaw_deg.to_radians();
            let grade = r.slope_deg.to_radians().tan();
            let o = Obb {
                cx: r.x_m + 0.5 * len * yaw.cos(),
                cy: r.y_m + 0.5 * len * yaw.sin(),
                hx: 0.5 * len,
                hy: 0.5 * r.width_m,
                yaw,
            };
            let (x0, y0, x1, y1) = o.aabb();
            let (sn, cs) = yaw.sin_cos();
            w.for_vertices(x0, y0, x1, y1, |b, x, y, h, fl| {
                if o.contains(x, y) {
                    let u = ((x - r.x_m) * cs + (y - r.y_m) * sn).clamp(0.0, r.length_m);
                    *h = h.max((b + u * grade) as f32);
                    *fl |= FLAG_PAVED;
                }
            });
        }
        for hl in &sc.hole {
            w.bake_hole(hl);
        }
        w.ground.build_mips();
        for s in &sc.wall {
            w.add_wall(s);
        }
        for p in &sc.pole {
            w.add_pole(p);
        }
        for t in &sc.tree {
            w.add_tree(t);
        }
        for b in &sc.boxes {
            w.add_box(b);
        }
        for c in &sc.car {
            w.add_car(c);
        }
        w
    }

    fn bake_hole(&mut self, hl: &crate::scenario::HoleSpec) {
        let o = Obb::from_rect(&hl.rect);
        let (x0, y0, x1, y1) = o.aabb();
        self.for_vertices(x0, y0, x1, y1, |_, x, y, h, fl| {
            if o.contains(x, y) {
                *h -= hl.depth_m as f32;
                *fl |= FLAG_HOLE;
            }
        });
    }

    /// Calls `f(base_height, x, y, &mut height, &mut flags)` for vertices in a box.
    fn for_vertices(
        &mut self,
        x0: f64,
        y0: f64,
        x1: f64,
        y1: f64,
        mut f: impl FnMut(f64, f64, f64, &mut f32, &mut u8),
    ) {
        let Some((i0, j0, i1, j1)) = self.ground.vertex_range(x0, y0, x1, y1) else {
            return;
        };
        let g = &mut self.ground;
        for j in j0..=j1 {
            let y = g.y0_m + j as f64 * g.res_m;
            for i in i0..=i1 {
                let x = g.x0_m + i as f64 * g.res_m;
                let k = j * g.nx + i;
                f(self.base.height(x, y), x, y, &mut g.h_m[k], &mut g.flags[k]);
            }
        }
    }

    /// Lowest and highest ground under a set of points (outside the grid: the base terrain).
    fn ground_range(&self, pts: &[[f64; 2]]) -> (f64, f64) {
        let mut r = (f64::INFINITY, f64::NEG_INFINITY);
        for p in pts {
            let h = self
                .ground_height(p[0], p[1])
                .unwrap_or_else(|| self.base.height(p[0], p[1]));
            r = (r.0.min(h), r.1.max(h));
        }
        r
    }

    fn obb_ground_range(&self, o: &Obb) -> (f64, f64) {
        let (s, c) = o.yaw.sin_cos();
        let mut pts = vec![[o.cx, o.cy]];
        for (a, b) in [
            (-1.0, -1.0),
            (1.0, -1.0),
            (1.0, 1.0),
            (-1.0, 1.0),
            (0.0, 1.0),
            (0.0, -1.0),
            (1.0, 0.0),
            (-1.0, 0.0),
        ] {
            let lx = a * o.hx;
            let ly = b * o.hy;
            pts.push([o.cx + c * lx - s * ly, o.cy + s * lx + c * ly]);
        }
        self.ground_range(&pts)
    }

    fn push(&mut self, shape: Shape, z0_m: f64, z1_m: f64, kind: SolidKind, feature: u32) {
        self.solids.push(Solid {
            shape,
            z0_m,
            z1_m,
            kind,
            feature,
        });
    }

    fn new_feature(&mut self) -> u32 {
        self.next_feature += 1;
        self.next_feature - 1
    }

    fn add_wall(&mut self, s: &crate::scenario::WallSpec) {
        let f = self.new_feature();
        // Pieces of at most 4 m keep bounding circles tight for the sensors' candidate lists.
        let mut pieces = Vec::new();
        for seg in s.points.windows(2) {
            let (a, b) = (seg[0], seg[1]);
            let n = ((a[0] - b[0]).hypot(a[1] - b[1]) / 4.0).ceil().max(1.0) as usize;
            for k in 0..n {
                let f0 = k as f64 / n as f64;
                let f1 = (k + 1) as f64 / n as f64;
                let lerp = |f: f64| [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])];
                pieces.push((lerp(f0), lerp(f1)));
            }
        }
        for (a, b) in pieces {
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len < 1e-6 {
                continue;
            }
            let o = Obb {
                cx: 0.5 * (a[0] + b[0]),
                cy: 0.5 * (a[1] + b[1]),
                hx: 0.5 * len + 0.5 * s.thickness_m,
                hy: 0.5 * s.thickness_m,
                yaw: (b[1] - a[1]).atan2(b[0] - a[0]),
            };
            let mut pts: Vec<[f64; 2]> = (0..=((len / 0.5).ceil() as usize))
                .map(|k| {
                    let t = (k as f64 * 0.5 / len).min(1.0);
                    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
                })
                .collect();
            pts.push(b);
            let (lo, hi) = self.ground_range(&pts);
            self.push(
                Shape::Box {
                    cx: o.cx,
                    cy: o.cy,
                    hx: o.hx,
                    hy: o.hy,
                    yaw: o.yaw,
                },
                lo - 0.1,
                hi + s.height_m,
                SolidKind::Wall,
                f,
            );
        }
    }

    fn add_pole(&mut self, p: &crate::scenario::PoleSpec) {
        let f = self.new_feature();
        let (lo, _) = self.ground_range(&[[p.x_m, p.y_m]]);
        let shape = Shape::Cylinder {
            cx: p.x_m,
            cy: p.y_m,
            r: p.radius_m,
        };
        self.push(shape, lo - 0.1, lo + p.height_m, SolidKind::Pole, f);
    }

    fn add_tree(&mut self, t: &crate::scenario::TreeSpec) {
        let f = self.new_feature();
        let (g, _) = self.ground_range(&[[t.x_m, t.y_m]]);
        let cyl = Shape::Cylinder {
            cx: t.x_m,
            cy: t.y_m,
            r: t.trunk_radius_m,
        };
        self.push(
            cyl,
            g - 0.1,
            g + t.canopy_base_m + 0.5 * t.canopy_height_m,
            SolidKind::Trunk,
            f,
        );
        let ell = Shape::Ellipsoid {
            cx: t.x_m,
            cy: t.y_m,
            r: t.canopy_radius_m,
        };
        self.push(
            ell,
            g + t.canopy_base_m,
            g + t.canopy_base_m + t.canopy_height_m,
            SolidKind::Canopy,
            f,
        );
    }

    fn add_box(&mut self, b: &crate::scenario::BoxSpec) {
        let f = self.new_feature();
        let o = Obb::from_rect(&b.rect);
        let (lo, hi) = self.obb_ground_range(&o);
        let shape = Shape::Box {
            cx: o.cx,
            cy: o.cy,
            hx: o.hx,
            hy: o.hy,
            yaw: o.yaw,
        };
        // Top measured from the highest ground under it, so a box on a slope keeps its height.
        self.push(shape, lo - 0.1, hi + b.height_m, SolidKind::Box, f);
    }

    fn add_car(&mut self, c: &crate::scenario::CarSpec) {
        let f = self.new_feature();
        let yaw = c.yaw_deg.to_radians();
        let body = Obb {
            cx: c.x_m,
            cy: c.y_m,
            hx: 0.5 * c.length_m,
            hy: 0.5 * c.width_m,
            yaw,
        };
        let (lo, hi) = self.obb_ground_range(&body);
        let g = 0.5 * (lo + hi);
        self.push(
            Shape::Box {
                cx: c.x_m,
                cy: c.y_m,
                hx: body.hx,
                hy: body.hy,
                yaw,
            },
            g + 0.2,
            g + 1.0,
            SolidKind::Car,
            f,
        );
        // Cabin, set back a little from the centre like a saloon's.
        let off = -0.05 * c.length_m;
        self.push(
            Shape::Box {
                cx: c.x_m + off * yaw.cos(),
                cy: c.y_m + off * yaw.sin(),
                hx: 0.28 * c.length_m,
                hy: 0.45 * c.width_m,
                yaw,
            },
            g + 1.0,
            g + c.height_m,
            SolidKind::Car,
            f,
        );
        // Wheels: four short cylinders so the gap under the body is not empty at the wheels.
        for (a, b) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            let lx = a * 0.32 * c.length_m;
            let ly = b * 0.4 * c.width_m;
            let shape = Shape::Cylinder {
                cx: c.x_m + yaw.cos() * lx - yaw.sin() * ly,
                cy: c.y_m + yaw.sin() * lx + yaw.cos() * ly,
                r: 0.32,
            };
            self.push(shape, g - 0.05, g + 0.6, SolidKind::Car, f);
        }
    }

    /// Adds obstacles at run time (they appear in ray casts, labels and collisions from now on).
    pub fn add_obstacles(&mut self, obstacles: &[Obstacle]) {
        let mut ground_changed = false;
        for o in obstacles {
            match o {
                Obstacle::Box(b) => self.add_box(b),
                Obstacle::Car(c) => self.add_car(c),
                Obstacle::Pole(p) => self.add_pole(p),
                Obstacle::Tree(t) => self.add_tree(t),
                Obstacle::Wall(w) => self.add_wall(w),
                Obstacle::Hole(h) => {
                    self.bake_hole(h);
                    ground_changed = true;
                }
            }
        }
        if ground_changed {
            self.ground.build_mips();
        }
    }

    /// Ground height (terrain and ground features) at (x, y); `None` outside the world.
    pub fn ground_height(&self, x_m: f64, y_m: f64) -> Option<f64> {
        self.ground.height(x_m, y_m)
    }

    /// The static solids.
    pub fn solids(&self) -> &[Solid] {
        &self.solids
    }

    /// Body radius of walker `i` (0 when there is none), metres.
    pub fn walker_radius(&self, i: usize) -> f64 {
        self.walkers.get(i).map_or(0.0, |w| w.radius_m)
    }

    /// Where walker `i` is after walking `t_s` seconds of its script, if it exists.
    pub fn walker_position(&self, i: usize, t_s: f64) -> Option<[f64; 2]> {
        self.walkers.get(i).map(|w| w.position(t_s))
    }

    /// Number of walkers.
    pub fn walker_count(&self) -> usize {
        self.walkers.len()
    }

    /// Walkers at time `t_s`, in scenario order, as if none had ever stopped.
    pub fn walkers_at(&self, t_s: f64) -> Vec<WalkerState> {
        self.walkers_at_clocks(&vec![t_s; self.walkers.len()])
    }

    /// Walkers with their own clocks: walker `i` is where its script puts it after walking for
    /// `clocks[i]` seconds (a walker that waited for the robot is behind its script).
    pub fn walkers_at_clocks(&self, clocks: &[f64]) -> Vec<WalkerState> {
        self.walkers
            .iter()
            .zip(clocks)
            .enumerate()
            .map(|(id, (w, &t_s))| {
                let [x, y] = w.position(t_s);
                WalkerState {
                    id,
                    x_m: x,
                    y_m: y,
                    z_m: self.ground_height(x, y).unwrap_or(0.0),
                    radius_m: w.radius_m,
                    height_m: w.height_m,
                }
            })
            .collect()
    }

    /// Ray cast against ground, every solid and the walkers at `t_s` (`dir` need not be unit).
    /// Sensors use a faster path with per-sweep candidate lists; this one is for tests and tools.
    pub fn raycast(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        max_range_m: f64,
        t_s: f64,
    ) -> Option<Hit> {
        let d = dir.normalize();
        let walkers: Vec<Solid> = self
            .walkers_at(t_s)
            .iter()
            .map(WalkerState::solid)
            .collect();
        let all: Vec<u32> = (0..self.solids.len() as u32).collect();
        let wk: Vec<u32> = (0..walkers.len() as u32).collect();
        self.raycast_candidates(origin, &d, max_range_m, &all, &walkers, &wk)
    }

    /// Ray cast testing only the listed solids (`solid_ids`) and walker cylinders (`walker_ids`
    /// into `walkers`); `d` must be unit length.
    pub(crate) fn raycast_candidates(
        &self,
        o: &Point3<f64>,
        d: &Vector3<f64>,
        max_range_m: f64,
        solid_ids: &[u32],
        walkers: &[Solid],
        walker_ids: &[u32],
    ) -> Option<Hit> {
        let mut best = max_range_m;
        let mut kind = None;
        for &i in solid_ids {
            if let Some(t) = self.solids[i as usize].ray(o, d) {
                if t < best {
                    best = t;
                    kind = Some(HitKind::Solid(i as usize));
                }
            }
        }
        for &i in walker_ids {
            if let Some(t) = walkers[i as usize].ray(o, d) {
                if t < best {
                    best = t;
                    kind = Some(HitKind::Walker(walkers[i as usize].feature as usize));
                }
            }
        }
        if let Some(t) = self.ground.raycast(o, d, best) {
            let p = o + d * t;
            let grass = self.ground.flags_at(p.x, p.y) & FLAG_PAVED == 0;
            return Some(Hit {
                range_m: t,
                kind: HitKind::Ground { grass },
            });
        }
        kind.map(|k| Hit {
            range_m: best,
            kind: k,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;

    pub(crate) fn flat_with_wall() -> Scenario {
        Scenario::from_toml_str(
            r#"
name = "flat-wall"
[datum]
lat_deg = 48.0
lon_deg = 16.0
h_m = 200.0
[extent]
x_min_m = -20.0
x_max_m = 20.0
y_min_m = -20.0
y_max_m = 20.0
[terrain]
undulation_amplitude_m = 0.0
grass_amplitude_m = 0.0
[[wall]]
points = [[10.0, -15.0], [10.0, 15.0]]
thickness_m = 0.2
height_m = 3.0
"#,
            "test",
        )
        .unwrap()
    }

    #[test]
    fn ground_and_wall_ranges_match_geometry() {
        let w = World::new(&flat_with_wall());
        let o = Point3::new(0.0, 0.0, 0.75);
        // Down at -15 deg: flat ground at z = 0 -> range = 0.75 / sin(15 deg).
        for az in [0.3f64, 1.0, 2.0, 3.0, -2.5] {
            let el = (-15f64).to_radians();
            let d = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
            let want = 0.75 / 15f64.to_radians().sin();
            assert!(
                (h.range_m - want).abs() < 1e-3,
                "az {az}: {} vs {want}",
                h.range_m
            );
            assert!(matches!(h.kind, HitKind::Ground { .. }));
        }
        // Horizontal towards the wall face at x = 9.9.
        for az in [-0.5f64, 0.0, 0.7] {
            let d = Vector3::new(az.cos(), az.sin(), 0.0);
            let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
            let want = 9.9 / az.cos();
            assert!((h.range_m - want).abs() < 1e-6, "{} vs {want}", h.range_m);
            assert!(matches!(h.kind, HitKind::Solid(_)));
        }
        // Up and away from the wall: nothing.
        assert!(w
            .raycast(&o, &Vector3::new(-1.0, 0.0, 0.1), 100.0, 0.0)
            .is_none());
        // Grazing rays (-1 deg) hit the flat ground at 0.75 / tan(1 deg) = 43 m, beyond the world edge.
        let d = Vector3::new(-(1f64.to_radians().cos()), 0.0, -(1f64.to_radians().sin()));
        assert!(w.raycast(&o, &d, 100.0, 0.0).is_none());
        let d = Vector3::new(0.0, -1.0, -(3f64.to_radians().tan()));
        let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
        assert!((h.range_m * 3f64.to_radians().sin() - 0.75).abs() < 1e-3);
    }

    #[test]
    fn ground_raycast_matches_brute_force_on_rough_terrain() {
        let mut sc = flat_with_wall();
        sc.terrain.undulation_amplitude_m = 0.8;
        sc.terrain.undulation_wavelength_m = 6.0;
        sc.step.push(crate::scenario::StepSpec {
            rect: Some(Rect {
                center_m: [3.0, 2.0],
                size_m: [2.0, 4.0],
                yaw_deg: 20.0,
            }),
            points: None,
            width_m: 0.3,
            height_m: 0.15,
        });
        let w = World::new(&sc);
        let o = Point3::new(0.3, -0.2, 1.2);
        for k in 0..200 {
            let az = k as f64 * 0.0314;
            let el = -0.02 - (k % 16) as f64 * 0.02;
            let d = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let fast = w.ground.raycast(&o, &d, 60.0);
            // Brute force: tiny steps until below the surface.
            let mut t = 0.0;
            let mut slow = None;
            while t < 60.0 {
                let p = o + d * t;
                match w.ground_height(p.x, p.y) {
                    Some(h) if p.z <= h => {
                        slow = Some(t);
                        break;
                    }
                    None => break,
                    _ => {}
                }
                t += 0.002;
            }
            match (fast, slow) {
                (Some(a), Some(b)) => assert!((a - b).abs() < 0.01, "ray {k}: {a} vs {b}"),
                (None, None) => {}
                other => panic!("ray {k}: {other:?}"),
            }
        }
    }

    #[test]
    fn walkers_move_at_walking_speed() {
        let mut sc = flat_with_wall();
        sc.walker.push(WalkerSpec {
            points: vec![[0.0, 0.0], [10.0, 0.0]],
            speed_mps: 1.3,
            mode: WalkMode::PingPong,
            phase_m: 0.0,
            radius_m: 0.25,
            height_m: 1.75,
        });
        let w = World::new(&sc);
        let a = w.walkers_at(1.0)[0];
        let b = w.walkers_at(2.0)[0];
        assert!(((b.x_m - a.x_m).hypot(b.y_m - a.y_m) - 1.3).abs() < 1e-9);
        // Ping-pong: after 10 m it comes back.
        let c = w.walkers_at(12.0 / 1.3)[0];
        assert!((c.x_m - 8.0).abs() < 1e-9, "{}", c.x_m);
    }

    #[test]
    fn obb_overlap() {
        let a = Obb {
            cx: 0.0,
            cy: 0.0,
            hx: 1.0,
            hy: 0.5,
            yaw: 0.0,
        };
        let mut b = Obb {
            cx: 1.6,
            cy: 0.0,
            hx: 0.5,
            hy: 0.5,
            yaw: std::f64::consts::FRAC_PI_4,
        };
        assert!(a.overlaps(&b));
        b.cx = 1.75;
        assert!(!a.overlaps(&b));
    }
}
