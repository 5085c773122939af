//! The point map: points with normals and a P(dynamic) each, a spatial index rebuilt after each
//! update, insertion of new points beyond `min_dist_new_point_m`, a distance limit around the
//! sensor, and the ray-model dynamic-point update (methods.md §3).

use crate::config::{DynamicConfig, MapConfig, MapIndexKind};
use crate::filters::OrientedCloud;
use crate::index::{KdIndex, Neighbours, VoxelIndex};
use nalgebra::{Isometry3, Point3, Vector3};
use sensing::Point;

#[derive(Debug)]
enum Index {
    Kd(KdIndex),
    Voxel(VoxelIndex),
}

/// What one map update did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MapUpdateStats {
    /// Reading points added.
    pub added: usize,
    /// Points removed as dynamic.
    pub removed_dynamic: usize,
    /// Points removed by the distance limit.
    pub removed_far: usize,
    /// Map points whose P(dynamic) was updated.
    pub observed: usize,
}

/// The SLAM map in the `map` frame.
#[derive(Debug)]
pub struct Map {
    cloud: OrientedCloud,
    p_dynamic: Vec<f32>,
    index: Index,
    kind: MapIndexKind,
    voxel_size_m: f32,
}

impl Map {
    /// An empty map using the given index kind; `voxel_size_m` is the cube size of a voxel index.
    pub fn new(kind: MapIndexKind, voxel_size_m: f32) -> Self {
        let index = match kind {
            MapIndexKind::KdTree => Index::Kd(KdIndex::default()),
            MapIndexKind::Voxel => Index::Voxel(VoxelIndex::default()),
        };
        Self {
            cloud: OrientedCloud::default(),
            p_dynamic: Vec::new(),
            index,
            kind,
            voxel_size_m,
        }
    }

    /// Number of map points.
    pub fn len(&self) -> usize {
        self.cloud.len()
    }

    /// True when the map has no points.
    pub fn is_empty(&self) -> bool {
        self.cloud.is_empty()
    }

    /// Points and normals, map frame.
    pub fn cloud(&self) -> &OrientedCloud {
        &self.cloud
    }

    /// P(dynamic) per point, same order as [`Map::cloud`].
    pub fn p_dynamic(&self) -> &[f32] {
        &self.p_dynamic
    }

    fn rebuild(&mut self) {
        self.index = match self.kind {
            MapIndexKind::KdTree => Index::Kd(KdIndex::build(&self.cloud.points)),
            MapIndexKind::Voxel => {
                Index::Voxel(VoxelIndex::build(&self.cloud.points, self.voxel_size_m))
            }
        };
    }

    /// One update after a scan is localised: P(dynamic) from the unfiltered scan (`raw_sensor`,
    /// sensor frame), removal of dynamic and far points, insertion of new reading points
    /// (`reading_map`, map frame) farther than `min_dist_new_point_m` from the map.
    pub fn update(
        &mut self,
        reading_map: &OrientedCloud,
        raw_sensor: &[Point],
        map_from_sensor: &Isometry3<f64>,
        cfg: &MapConfig,
        dyn_cfg: &DynamicConfig,
    ) -> MapUpdateStats {
        let mut stats = MapUpdateStats::default();
        if dyn_cfg.enabled && !self.is_empty() {
            stats.observed = update_dynamic(
                &self.cloud,
                &mut self.p_dynamic,
                raw_sensor,
                map_from_sensor,
                dyn_cfg,
            );
        }
        let sensor = map_from_sensor.translation.vector.cast::<f32>();
        let max_new = cfg.sensor_max_range_m as f32;
        let min_d2 = (cfg.min_dist_new_point_m * cfg.min_dist_new_point_m) as f32;
        let mut nb = Vec::with_capacity(1);
        let mut new_idx = Vec::new();
        for (i, p) in reading_map.points.iter().enumerate() {
            if (Vector3::from(*p) - sensor).norm() > max_new {
                continue;
            }
            self.knn(p, 1, f32::MAX.sqrt() / 2.0, &mut nb);
            if nb.first().is_none_or(|(_, d2)| *d2 > min_d2) {
                new_idx.push(i);
            }
        }
        let limit2 = (cfg.distance_limit_m * cfg.distance_limit_m) as f32;
        let thr = dyn_cfg.threshold as f32;
        let mut kept = OrientedCloud {
            points: Vec::with_capacity(self.len() + new_idx.len()),
            normals: Vec::with_capacity(self.len() + new_idx.len()),
        };
        let mut kept_p = Vec::with_capacity(self.len() + new_idx.len());
        for ((p, n), pd) in self
            .cloud
            .points
            .iter()
            .zip(&self.cloud.normals)
            .zip(&self.p_dynamic)
        {
            if *pd > thr {
                stats.removed_dynamic += 1;
            } else if (Vector3::from(*p) - sensor).norm_squared() > limit2 {
                stats.removed_far += 1;
            } else {
                kept.points.push(*p);
                kept.normals.push(*n);
                kept_p.push(*pd);
            }
        }
        for i in new_idx {
            kept.points.push(reading_map.points[i]);
            kept.normals.push(reading_map.normals[i]);
            kept_p.push(dyn_cfg.prior as f32);
            stats.added += 1;
        }
        self.cloud = kept;
        self.p_dynamic = kept_p;
        self.rebuild();
        stats
    }

    /// Map points within `radius_m` of `center_m` as plain points (map frame).
    pub fn cloud_around(&self, center_m: &Vector3<f64>, radius_m: f64) -> Vec<Point> {
        let c = center_m.cast::<f32>();
        let r2 = (radius_m * radius_m) as f32;
        self.cloud
            .points
            .iter()
            .filter(|p| (Vector3::from(**p) - c).norm_squared() <= r2)
            .map(|p| Point::xyz(p[0], p[1], p[2]))
            .collect()
    }
}

impl Neighbours for Map {
    fn knn_within(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>) {
        self.knn(q, k, max_dist_m, out)
    }
}

impl Map {
    fn knn(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>) {
        match &self.index {
            Index::Kd(t) => t.knn_within(q, k, max_dist_m, out),
            Index::Voxel(v) => {
                // A voxel query only sees one cube around; unbounded queries (insertion) are
                // therefore capped at the cube size, which is far beyond `min_dist_new_point_m`.
                v.knn_within(q, k, max_dist_m.min(self.voxel_size_m), out)
            }
        }
    }
}

/// atan2 to ~1e-5 rad (a bin index only needs to be consistent; the beam angle itself is
/// computed exactly), several times cheaper than libm's on 100k points a scan.
fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (mn, mx) = if ax < ay { (ax, ay) } else { (ay, ax) };
    if mx == 0.0 {
        return 0.0;
    }
    let a = mn / mx;
    let s = a * a;
    // Minimax polynomial for atan on [0, 1].
    let mut r = a
        * (0.999_977_26
            + s * (-0.332_623_47
                + s * (0.193_543_46
                    + s * (-0.116_432_87 + s * (0.052_653_32 + s * -0.011_721_2)))));
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

/// Direction bins of a scan (a sparse range image) for beam look-ups, built by counting sort
/// over the elevation band the scan covers: O(points), no comparison sort.
struct BeamBins {
    /// Cell `c` holds `order[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    order: Vec<u32>,
    n_az: u32,
    row0: u32,
    n_rows: u32,
    inv_bin: f32,
}

impl BeamBins {
    fn bin(inv_bin: f32, n_az: u32, p: &Vector3<f32>) -> (u32, u32) {
        let az = fast_atan2(p.y, p.x) + std::f32::consts::PI;
        let el = fast_atan2(p.z, (p.x * p.x + p.y * p.y).sqrt()) + std::f32::consts::FRAC_PI_2;
        let a = ((az * inv_bin) as u32).min(n_az - 1);
        let e = (el * inv_bin) as u32;
        (a, e)
    }

    fn new(points: &[Vector3<f32>], bin_rad: f32) -> Self {
        let inv_bin = 1.0 / bin_rad;
        let n_az = (std::f32::consts::TAU * inv_bin).ceil() as u32;
        let bins: Vec<(u32, u32)> = points.iter().map(|p| Self::bin(inv_bin, n_az, p)).collect();
        let row0 = bins.iter().map(|b| b.1).min().unwrap_or(0);
        let row1 = bins.iter().map(|b| b.1).max().unwrap_or(0);
        let n_rows = row1 - row0 + 1;
        let cells = (n_rows * n_az) as usize;
        let mut start = vec![0u32; cells + 1];
        for (a, e) in &bins {
            start[((e - row0) * n_az + a) as usize + 1] += 1;
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; points.len()];
        for (i, (a, e)) in bins.iter().enumerate() {
            let c = ((e - row0) * n_az + a) as usize;
            order[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        BeamBins {
            start,
            order,
            n_az,
            row0,
            n_rows,
            inv_bin,
        }
    }

    /// Calls `f` with the indices of points in the 3x3 bins around `q`'s direction.
    fn for_each_near(&self, q: &Vector3<f32>, mut f: impl FnMut(usize)) {
        let (a, e) = Self::bin(self.inv_bin, self.n_az, q);
        for de in [-1i64, 0, 1] {
            let row = i64::from(e) + de - i64::from(self.row0);
            if row < 0 || row >= i64::from(self.n_rows) {
                continue;
            }
            for da in [self.n_az - 1, 0, 1] {
                let col = (a + da) % self.n_az;
                let c = row as usize * self.n_az as usize + col as usize;
                for &i in &self.order[self.start[c] as usize..self.start[c + 1] as usize] {
                    f(i as usize);
                }
            }
        }
    }
}

/// Bayes update of P(dynamic) for map points seen along a beam of the new scan. Returns how many
/// points were updated.
///
/// Two deliberate readings of methods.md's formulas: the beam weight is `1 - theta/theta_max`
/// (evidence is strongest on the beam axis; `theta/theta_max` taken literally would ignore points
/// exactly on a beam), and the static likelihood falls with how far the beam went *past* q beyond
/// the noise band `eps_d + |p| eps_a`: `P(delta|dynamic) = clamp(delta - band, 0, 1)` (taken
/// literally, `P(delta|static)` could never exceed the band, ~0.1, and every seen point would
/// turn dynamic).
fn update_dynamic(
    map: &OrientedCloud,
    p_dynamic: &mut [f32],
    raw_sensor: &[Point],
    map_from_sensor: &Isometry3<f64>,
    cfg: &DynamicConfig,
) -> usize {
    let scan: Vec<Vector3<f32>> = raw_sensor
        .iter()
        .filter(|p| p.is_finite() && p.range_m() > 0.0)
        .map(|p| Vector3::new(p.x, p.y, p.z))
        .collect();
    if scan.is_empty() {
        return 0;
    }
    let ranges: Vec<f32> = scan.iter().map(|p| p.norm()).collect();
    let theta_max = cfg.beam_half_angle_rad as f32;
    let bins = BeamBins::new(&scan, theta_max);
    let sensor_from_map = map_from_sensor.inverse().cast::<f32>();
    let sensor_m = map_from_sensor.translation.vector.cast::<f32>();
    let max_r2 = (cfg.max_range_m * cfg.max_range_m) as f32;
    let (alpha, beta) = (cfg.alpha as f32, cfg.beta as f32);
    let mut updated = 0;
    for ((q_map, n_map), pd) in map
        .points
        .iter()
        .zip(&map.normals)
        .zip(p_dynamic.iter_mut())
    {
        if (Vector3::from(*q_map) - sensor_m).norm_squared() > max_r2 {
            continue;
        }
        let q = (sensor_from_map * Point3::from(*q_map)).coords;
        let q_r = q.norm();
        if q_r < 1e-3 {
            continue;
        }
        // The reading point whose beam passes closest to q (largest cosine; theta is small, so
        // sin(theta) = |p x q| / (|p| |q|) stands in for it).
        let q_unit = q / q_r;
        let mut best: Option<(f32, usize)> = None;
        bins.for_each_near(&q, |i| {
            let cos = scan[i].dot(&q_unit) / ranges[i];
            if best.is_none_or(|(c, _)| cos > c) {
                best = Some((cos, i));
            }
        });
        let Some((_, i)) = best else { continue };
        let theta = (scan[i].cross(&q_unit).norm() / ranges[i]).min(1.0).asin();
        if theta >= theta_max {
            continue;
        }
        let p_r = ranges[i];
        if p_r < q_r {
            // Something in front of q: the beam never reached it, no evidence either way.
            continue;
        }
        let n = sensor_from_map.rotation * Vector3::from(*n_map);
        let incidence = (n.dot(&q) / q_r).abs().min(1.0).acos();
        let usable = (1.0 - theta / theta_max) * (1.0 - 2.0 * incidence / std::f32::consts::PI);
        let band = cfg.eps_d_m as f32 + p_r * cfg.eps_a as f32;
        let l_dyn = (p_r - q_r - band).clamp(0.0, 1.0);
        let l_dyn = usable * l_dyn + (1.0 - usable) * 0.5;
        let l_sta = 1.0 - l_dyn;
        let ps = 1.0 - *pd;
        let pd_pred = (1.0 - alpha) * ps + beta * *pd;
        let ps_pred = alpha * ps + (1.0 - beta) * *pd;
        let num = pd_pred * l_dyn;
        let den = num + ps_pred * l_sta;
        if den > 0.0 {
            *pd = num / den;
            updated += 1;
        }
    }
    updated
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense "scan" (sensor frame) of a wall at x = `wall_x`, plus an optional box at x = 3.
    fn scan(wall_x: f32, with_box: bool) -> Vec<Point> {
        let mut v = Vec::new();
        for ia in -300..=300 {
            for ie in -30..=30 {
                let az = ia as f32 * 0.002;
                let el = ie as f32 * 0.002;
                let dir = Vector3::new(az.cos() * el.cos(), az.sin() * el.cos(), el.sin());
                let in_box = with_box && az.abs() < 0.1 && el.abs() < 0.05;
                let r = if in_box { 3.0 / dir.x } else { wall_x / dir.x };
                let p = dir * r;
                v.push(Point::xyz(p.x, p.y, p.z));
            }
        }
        v
    }

    fn as_cloud(points: &[Point]) -> OrientedCloud {
        OrientedCloud {
            points: points.iter().map(|p| [p.x, p.y, p.z]).collect(),
            normals: points.iter().map(|_| [-1.0, 0.0, 0.0]).collect(),
        }
    }

    fn box_points(map: &Map) -> usize {
        map.cloud()
            .points
            .iter()
            .filter(|p| (p[0] - 3.0).abs() < 0.05)
            .count()
    }

    #[test]
    fn fast_atan2_is_close_to_libm() {
        for i in 0..3600 {
            let a = (i as f32).to_radians() * 0.1 - 3.1;
            for r in [0.5f32, 10.0] {
                let (y, x) = (r * a.sin(), r * a.cos());
                assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{y} {x}");
            }
        }
    }

    #[test]
    fn box_that_moves_away_is_removed_and_the_wall_stays() {
        let cfg = MapConfig::default();
        let dyn_cfg = DynamicConfig::default();
        let mut map = Map::new(MapIndexKind::KdTree, 1.1);
        let first = scan(8.0, true);
        map.update(
            &as_cloud(&first),
            &first,
            &Isometry3::identity(),
            &cfg,
            &dyn_cfg,
        );
        let boxed = box_points(&map);
        assert!(boxed > 100, "box not in the map: {boxed}");
        let wall_before = map.len() - boxed;
        // The box left: the beams now go through where it was and hit the wall.
        let empty = scan(8.0, false);
        for _ in 0..3 {
            map.update(
                &OrientedCloud::default(),
                &empty,
                &Isometry3::identity(),
                &cfg,
                &dyn_cfg,
            );
        }
        assert_eq!(box_points(&map), 0);
        let wall_after = map.len();
        assert!(
            wall_after as f64 > 0.99 * wall_before as f64,
            "wall lost: {wall_before} -> {wall_after}"
        );
        assert!(map.p_dynamic().iter().all(|p| *p < 0.5));
    }

    #[test]
    fn static_scene_seen_again_stays() {
        let mut map = Map::new(MapIndexKind::KdTree, 1.1);
        let s = scan(8.0, true);
        for _ in 0..5 {
            map.update(
                &as_cloud(&s),
                &s,
                &Isometry3::identity(),
                &MapConfig::default(),
                &DynamicConfig::default(),
            );
        }
        assert!(box_points(&map) > 100);
        // Re-observing adds nothing new (all within min_dist_new_point of existing points).
        assert_eq!(map.len(), s.len());
    }

    #[test]
    fn insertion_respects_min_distance_and_distance_limit() {
        let mut map = Map::new(MapIndexKind::KdTree, 1.1);
        let cfg = MapConfig {
            distance_limit_m: 10.0,
            ..MapConfig::default()
        };
        let dyn_cfg = DynamicConfig {
            enabled: false,
            ..DynamicConfig::default()
        };
        let c = OrientedCloud {
            points: vec![[1.0, 0.0, 0.0], [1.05, 0.0, 0.0], [1.2, 0.0, 0.0]],
            normals: vec![[1.0, 0.0, 0.0]; 3],
        };
        let s = map.update(&c, &[], &Isometry3::identity(), &cfg, &dyn_cfg);
        assert_eq!(s.added, 3, "an empty map takes everything");
        let c2 = OrientedCloud {
            points: vec![[1.03, 0.0, 0.0], [1.5, 0.0, 0.0]],
            normals: vec![[1.0, 0.0, 0.0]; 2],
        };
        let s = map.update(&c2, &[], &Isometry3::identity(), &cfg, &dyn_cfg);
        assert_eq!(s.added, 1);
        let far = Isometry3::translation(20.0, 0.0, 0.0);
        let s = map.update(&OrientedCloud::default(), &[], &far, &cfg, &dyn_cfg);
        assert_eq!((s.removed_far, map.len()), (4, 0));
    }
}
