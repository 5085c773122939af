//! Analytic solids (walls, poles, trees, boxes, cars, walker bodies) and their ray and overlap tests.

use crate::scenario::Rect;
use nalgebra::{Point3, Vector3};

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

    /// The horizontal footprint: a disc (centre, radius) or an oriented box.
    fn footprint(&self) -> Footprint {
        match self.shape {
            Shape::Cylinder { cx, cy, r } | Shape::Ellipsoid { cx, cy, r } => {
                Footprint::Disc { cx, cy, r }
            }
            Shape::Box {
                cx,
                cy,
                hx,
                hy,
                yaw,
            } => Footprint::Box(Obb {
                cx,
                cy,
                hx,
                hy,
                yaw,
            }),
        }
    }

    /// Horizontal distance from (x, y) to the footprint, metres (0 inside).
    pub fn footprint_distance(&self, x: f64, y: f64) -> f64 {
        match self.footprint() {
            Footprint::Disc { cx, cy, r } => ((x - cx).hypot(y - cy) - r).max(0.0),
            Footprint::Box(o) => o.distance_to(x, y),
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
        match self.footprint() {
            Footprint::Disc { cx, cy, r: rad } => r.distance_to(cx, cy) <= rad,
            Footprint::Box(o) => r.overlaps(&o),
        }
    }
}

/// A solid's horizontal footprint ([`Solid::footprint`]).
enum Footprint {
    Disc { cx: f64, cy: f64, r: f64 },
    Box(Obb),
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

    pub(super) fn from_rect(r: &Rect) -> Obb {
        Obb {
            cx: r.center_m[0],
            cy: r.center_m[1],
            hx: 0.5 * r.size_m[0],
            hy: 0.5 * r.size_m[1],
            yaw: r.yaw_deg.to_radians(),
        }
    }
}
