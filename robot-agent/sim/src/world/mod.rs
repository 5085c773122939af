//! The simulated world: a ground height field (terrain plus curbs, stairs, ramps, platforms and
//! holes baked in), analytic solids (walls, poles, trees, boxes, cars) and walkers.
//!
//! Ray casting: solids are tested analytically (slab tests against vertical cylinders, yawed boxes
//! and ellipsoids); the ground is marched with a 2D DDA through a three-level max-height pyramid
//! (5 cm cells, 20 cm blocks, 1.6 m blocks) so rays skip space far above the ground, and the
//! surface inside a fine cell is bilinear in the four vertex heights.

mod build;
mod height_field;
mod solid;
#[cfg(test)]
mod tests;
mod walker;

pub use height_field::{HeightField, FLAG_HOLE, FLAG_PAVED};
pub use solid::{Obb, Shape, Solid, SolidKind};
pub use walker::{Walker, WalkerState};

use crate::scenario::Scenario;
use nalgebra::{Point3, Vector3};

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
