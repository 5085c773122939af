//! The VLP-16 sweep model (per-laser timing, intensities by surface) and the depth-camera frame.

use super::{DepthConfig, LidarConfig};
use crate::world::{HitKind, Solid, SolidKind, World};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::SmallRng;
use rand::Rng;
use rand_distr::StandardNormal;
use sensing::Point;

fn intensity(kind: HitKind, world: &World) -> f32 {
    match kind {
        HitKind::Ground { grass: true } => 15.0,
        HitKind::Ground { grass: false } => 35.0,
        HitKind::Walker(_) => 45.0,
        HitKind::Solid(i) => match world.solids()[i].kind {
            SolidKind::Wall => 80.0,
            SolidKind::Pole => 120.0,
            SolidKind::Trunk => 55.0,
            SolidKind::Canopy => 25.0,
            SolidKind::Box => 70.0,
            SolidKind::Car => 150.0,
        },
    }
}

/// Candidate solids per map-frame azimuth bucket, rebuilt for each short chunk of a sweep.
struct Buckets {
    n: usize,
    lists: Vec<Vec<u32>>,
    walker_lists: Vec<Vec<u32>>,
    all: Vec<u32>,
    all_walkers: Vec<u32>,
}

impl Buckets {
    fn new(n: usize) -> Self {
        Self {
            n,
            lists: vec![Vec::new(); n],
            walker_lists: vec![Vec::new(); n],
            all: Vec::new(),
            all_walkers: Vec::new(),
        }
    }

    fn fill(
        &mut self,
        o: &Point3<f64>,
        solids: &[Solid],
        walkers: &[Solid],
        max_range_m: f64,
        pad_m: f64,
    ) {
        for l in &mut self.lists {
            l.clear();
        }
        for l in &mut self.walker_lists {
            l.clear();
        }
        self.all.clear();
        self.all_walkers.clear();
        let bw = std::f64::consts::TAU / self.n as f64;
        for (is_walker, set) in [(false, solids), (true, walkers)] {
            for (i, s) in set.iter().enumerate() {
                let (cx, cy, r) = s.bounds();
                let r = r + pad_m;
                let d = (cx - o.x).hypot(cy - o.y);
                if d - r > max_range_m {
                    continue;
                }
                if d <= r {
                    if is_walker {
                        &mut self.all_walkers
                    } else {
                        &mut self.all
                    }
                    .push(i as u32);
                    continue;
                }
                let a = (cy - o.y).atan2(cx - o.x) + std::f64::consts::PI;
                let half = (r / d).asin();
                let b0 = ((a - half) / bw).floor() as i64 - 1;
                let b1 = ((a + half) / bw).floor() as i64 + 1;
                for b in b0..=b1 {
                    let k = b.rem_euclid(self.n as i64) as usize;
                    if is_walker {
                        &mut self.walker_lists[k]
                    } else {
                        &mut self.lists[k]
                    }
                    .push(i as u32);
                }
            }
        }
    }

    fn bucket(&self, d: &Vector3<f64>) -> usize {
        let a = d.y.atan2(d.x) + std::f64::consts::PI;
        ((a / std::f64::consts::TAU * self.n as f64) as usize).min(self.n - 1)
    }
}

/// The spinning LiDAR's sweep state.
pub(crate) struct Lidar {
    cfg: LidarConfig,
    extrinsic: Isometry3<f64>,
    /// Per column: (cos az, sin az) in the sensor frame (clockwise rotation).
    az: Vec<(f64, f64)>,
    /// Per laser id: (cos el, sin el, ring).
    el: Vec<(f64, f64, u16)>,
    /// Time between two lasers' firings in a column, seconds.
    laser_dt_s: f64,
    rev_start_s: f64,
    next_col: usize,
    points: Vec<Point>,
    buckets: Buckets,
    scratch_ids: Vec<u32>,
    scratch_walkers: Vec<u32>,
}

impl Lidar {
    pub(crate) fn new(cfg: &LidarConfig, extrinsic: Isometry3<f64>) -> Self {
        let n = cfg.columns.max(1);
        let az = (0..n)
            .map(|j| {
                let a = -std::f64::consts::TAU * j as f64 / n as f64;
                (a.cos(), a.sin())
            })
            .collect();
        let elevations = cfg.model.elevations_deg();
        // Rings number the lasers bottom to top, as drivers publish them.
        let mut order: Vec<usize> = (0..elevations.len()).collect();
        order.sort_by(|&a, &b| elevations[a].total_cmp(&elevations[b]));
        let mut ring = vec![0u16; elevations.len()];
        for (r, &id) in order.iter().enumerate() {
            ring[id] = r as u16;
        }
        let el: Vec<(f64, f64, u16)> = elevations
            .iter()
            .enumerate()
            .map(|(id, e)| (e.to_radians().cos(), e.to_radians().sin(), ring[id]))
            .collect();
        let lasers = el.len();
        Self {
            cfg: cfg.clone(),
            extrinsic,
            az,
            el,
            rev_start_s: 0.0,
            next_col: 0,
            points: Vec::with_capacity(n * lasers),
            laser_dt_s: cfg.model.laser_dt_s(),
            buckets: Buckets::new(720),
            scratch_ids: Vec::new(),
            scratch_walkers: Vec::new(),
        }
    }

    fn col_dt(&self) -> f64 {
        1.0 / (self.cfg.rate_hz * self.az.len() as f64)
    }

    /// Casts the columns whose firing time lies in `[t0, t1)`, the base moving from `base0` to
    /// `base1`; returns the scan completed in this interval, if any.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn sweep(
        &mut self,
        world: &World,
        walkers: &[Solid],
        t0: f64,
        t1: f64,
        base0: &Isometry3<f64>,
        base1: &Isometry3<f64>,
        rng: &mut SmallRng,
    ) -> Option<sensing::Scan> {
        let mut done = None;
        let cdt = self.col_dt();
        let s0 = base0 * self.extrinsic;
        let s1 = base1 * self.extrinsic;
        let o_mid = Point3::from((s0.translation.vector + s1.translation.vector) * 0.5);
        // Pad bounding circles by the sensor's motion in the chunk plus a walker's (1.3 m/s x 20 ms).
        let pad = (s1.translation.vector - s0.translation.vector).norm() + 0.1;
        self.buckets
            .fill(&o_mid, world.solids(), walkers, self.cfg.max_range_m, pad);
        let span = (t1 - t0).max(1e-12);
        loop {
            let tc = self.rev_start_s + self.next_col as f64 * cdt;
            if tc >= t1 {
                break;
            }
            let f = ((tc - t0) / span).clamp(0.0, 1.0);
            let pose = s0.lerp_slerp(&s1, f);
            let o = Point3::from(pose.translation.vector);
            let rot = pose.rotation.to_rotation_matrix();
            let up_s = rot.inverse() * Vector3::z();
            let (ca, sa) = self.az[self.next_col];
            for (id, &(ce, se, ring)) in self.el.iter().enumerate() {
                let ds = Vector3::new(ce * ca, ce * sa, se);
                let dm = rot * ds;
                let b = self.buckets.bucket(&dm);
                self.scratch_ids.clear();
                self.scratch_ids.extend_from_slice(&self.buckets.lists[b]);
                self.scratch_ids.extend_from_slice(&self.buckets.all);
                self.scratch_walkers.clear();
                self.scratch_walkers
                    .extend_from_slice(&self.buckets.walker_lists[b]);
                self.scratch_walkers
                    .extend_from_slice(&self.buckets.all_walkers);
                let Some(hit) = world.raycast_candidates(
                    &o,
                    &dm,
                    self.cfg.max_range_m,
                    &self.scratch_ids,
                    walkers,
                    &self.scratch_walkers,
                ) else {
                    continue;
                };
                let n: f64 = rng.sample(StandardNormal);
                let r = hit.range_m + n * self.cfg.range_noise_sigma_m;
                if r < self.cfg.min_range_m || r > self.cfg.max_range_m {
                    continue;
                }
                let mut p = ds * r;
                if let HitKind::Ground { grass: true } = hit.kind {
                    p += up_s * (rng.random::<f64>() * world.grass_amplitude_m);
                }
                self.points.push(Point {
                    x: p.x as f32,
                    y: p.y as f32,
                    z: p.z as f32,
                    intensity: intensity(hit.kind, world),
                    ring,
                    t_s: (tc - self.rev_start_s + id as f64 * self.laser_dt_s) as f32,
                });
            }
            self.next_col += 1;
            if self.next_col == self.az.len() {
                done = Some(sensing::Scan {
                    stamp_s: self.rev_start_s,
                    points: std::mem::take(&mut self.points),
                });
                self.points.reserve(self.az.len() * self.el.len());
                self.next_col = 0;
                self.rev_start_s += 1.0 / self.cfg.rate_hz;
            }
        }
        done
    }
}

/// Renders one depth-camera frame at a camera pose (`map <- camera`), in the camera frame.
pub(crate) fn depth_frame(
    cfg: &DepthConfig,
    world: &World,
    walkers: &[Solid],
    cam: &Isometry3<f64>,
    t_s: f64,
    rng: &mut SmallRng,
) -> sensing::Scan {
    let o = Point3::from(cam.translation.vector);
    let rot = cam.rotation.to_rotation_matrix();
    let near = |s: &Solid| {
        let (cx, cy, r) = s.bounds();
        (cx - o.x).hypot(cy - o.y) <= r + cfg.max_range_m
    };
    let ids: Vec<u32> = (0..world.solids().len() as u32)
        .filter(|&i| near(&world.solids()[i as usize]))
        .collect();
    let wids: Vec<u32> = (0..walkers.len() as u32)
        .filter(|&i| near(&walkers[i as usize]))
        .collect();
    let fx = 0.5 * cfg.width_px as f64 / (0.5 * cfg.hfov_deg.to_radians()).tan();
    let fy = 0.5 * cfg.height_px as f64 / (0.5 * cfg.vfov_deg.to_radians()).tan();
    let (cu, cv) = (0.5 * cfg.width_px as f64, 0.5 * cfg.height_px as f64);
    let mut points = Vec::with_capacity(cfg.width_px * cfg.height_px);
    for v in 0..cfg.height_px {
        for u in 0..cfg.width_px {
            let ds = Vector3::new(
                1.0,
                -(u as f64 + 0.5 - cu) / fx,
                -(v as f64 + 0.5 - cv) / fy,
            )
            .normalize();
            let dm = rot * ds;
            let Some(hit) =
                world.raycast_candidates(&o, &dm, cfg.max_range_m, &ids, walkers, &wids)
            else {
                continue;
            };
            let n: f64 = rng.sample(StandardNormal);
            let r = hit.range_m + n * cfg.range_noise_sigma_m;
            if r <= 0.0 || r > cfg.max_range_m {
                continue;
            }
            let p = ds * r;
            points.push(Point {
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                intensity: intensity(hit.kind, world),
                ring: v as u16,
                t_s: 0.0,
            });
        }
    }
    sensing::Scan {
        stamp_s: t_s,
        points,
    }
}
