//! Baking a scenario's features into the world: holes into the ground, walls, poles, trees, boxes
//! and cars as solids.

use super::*;

impl World {
    pub(super) fn bake_hole(&mut self, hl: &crate::scenario::HoleSpec) {
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
    pub(super) fn for_vertices(
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
    pub(super) fn ground_range(&self, pts: &[[f64; 2]]) -> (f64, f64) {
        let mut r = (f64::INFINITY, f64::NEG_INFINITY);
        for p in pts {
            let h = self
                .ground_height(p[0], p[1])
                .unwrap_or_else(|| self.base.height(p[0], p[1]));
            r = (r.0.min(h), r.1.max(h));
        }
        r
    }

    pub(super) fn obb_ground_range(&self, o: &Obb) -> (f64, f64) {
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

    pub(super) fn push(
        &mut self,
        shape: Shape,
        z0_m: f64,
        z1_m: f64,
        kind: SolidKind,
        feature: u32,
    ) {
        self.solids.push(Solid {
            shape,
            z0_m,
            z1_m,
            kind,
            feature,
        });
    }

    pub(super) fn new_feature(&mut self) -> u32 {
        self.next_feature += 1;
        self.next_feature - 1
    }

    pub(super) fn add_wall(&mut self, s: &crate::scenario::WallSpec) {
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

    pub(super) fn add_pole(&mut self, p: &crate::scenario::PoleSpec) {
        let f = self.new_feature();
        let (lo, _) = self.ground_range(&[[p.x_m, p.y_m]]);
        let shape = Shape::Cylinder {
            cx: p.x_m,
            cy: p.y_m,
            r: p.radius_m,
        };
        self.push(shape, lo - 0.1, lo + p.height_m, SolidKind::Pole, f);
    }

    pub(super) fn add_tree(&mut self, t: &crate::scenario::TreeSpec) {
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

    pub(super) fn add_box(&mut self, b: &crate::scenario::BoxSpec) {
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

    pub(super) fn add_car(&mut self, c: &crate::scenario::CarSpec) {
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
}
