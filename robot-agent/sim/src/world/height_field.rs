//! The ground height field: a vertex grid with a three-level max-height pyramid for ray marching.

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
    pub(super) x0_m: f64,
    pub(super) y0_m: f64,
    pub(super) res_m: f64,
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) h_m: Vec<f32>,
    pub(super) flags: Vec<u8>,
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
    pub(super) fn new(x0_m: f64, y0_m: f64, res_m: f64, nx: usize, ny: usize) -> Self {
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

    pub(super) fn nearest(&self, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
        let fx = ((x_m - self.x0_m) / self.res_m).round();
        let fy = ((y_m - self.y0_m) / self.res_m).round();
        if fx >= 0.0 && fy >= 0.0 && fx < self.nx as f64 && fy < self.ny as f64 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    #[inline]
    pub(super) fn bilinear(&self, i: usize, j: usize, u: f64, v: f64) -> f64 {
        let k = j * self.nx + i;
        let h00 = self.h_m[k] as f64;
        let h10 = self.h_m[k + 1] as f64;
        let h01 = self.h_m[k + self.nx] as f64;
        let h11 = self.h_m[k + self.nx + 1] as f64;
        h00 + (h10 - h00) * u + (h01 - h00) * v + (h00 - h10 - h01 + h11) * u * v
    }

    /// Index ranges of vertices inside an axis-aligned box (clamped to the grid).
    pub(super) fn vertex_range(
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
    pub(super) fn build_mips(&mut self) {
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
    pub(super) fn march(
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
    pub(super) fn cell_hit(
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
