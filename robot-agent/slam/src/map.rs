//! The point map: points with normals and a P(dynamic) each, a spatial index rebuilt after each
//! update, insertion of new points beyond `min_dist_new_point_m`, a distance limit around the
//! sensor, and the ray-model dynamic-point update (docs/algorithms.md §3.4-3.5).

use crate::config::{DynamicConfig, MapConfig, MapIndexKind};
use crate::filters::{pca_fit, OrientedCloud};
use crate::index::{KdIndex, Neighbours, VoxelIndex};
use nalgebra::{Isometry3, Vector3};
use sensing::Point;

mod dynamic;

#[cfg(test)]
use dynamic::{angles, fast_atan2, RangeImage};
use dynamic::{update_dynamic, BeamBins};

#[derive(Debug)]
enum Index {
    Kd(KdIndex),
    Voxel(VoxelIndex),
}

/// A map point closer than this to its neighbourhood's plane is on it, whatever the spread.
const PLANE_FIT_MIN_M: f32 = 0.03;

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
    /// Stamp of the scan that inserted each point.
    stamps: Vec<f64>,
    index: Index,
    /// Index item -> current point, after removals since the index was built (`u32::MAX`:
    /// removed); `None` while the index matches the points one to one. Removing a handful of
    /// dynamic points must not cost a rebuild on every scan.
    index_map: Option<Vec<u32>>,
    kind: MapIndexKind,
    voxel_size_m: f32,
    /// The dynamic-point update's direction bins, reused between scans.
    beam_bins: BeamBins,
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
            stamps: Vec::new(),
            index,
            index_map: None,
            kind,
            voxel_size_m,
            beam_bins: BeamBins::default(),
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

    /// Stamp of the scan that inserted each point, same order as [`Map::cloud`] (where a point
    /// came from: evaluation tools trace map points back to the scan, and so to the world).
    pub fn stamps(&self) -> &[f64] {
        &self.stamps
    }

    fn rebuild(&mut self) {
        self.index_map = None;
        self.index = match self.kind {
            MapIndexKind::KdTree => Index::Kd(KdIndex::build(&self.cloud.points)),
            MapIndexKind::Voxel => {
                Index::Voxel(VoxelIndex::build(&self.cloud.points, self.voxel_size_m))
            }
        };
    }

    /// One update after the scan stamped `stamp_s` is localised: P(dynamic) from the unfiltered
    /// scan (`raw_sensor`, sensor frame), removal of dynamic and far points, insertion of new
    /// reading points (`reading_map`, map frame) farther than `min_dist_new_point_m` from the map.
    pub fn update(
        &mut self,
        reading_map: &OrientedCloud,
        raw_sensor: &[Point],
        map_from_sensor: &Isometry3<f64>,
        stamp_s: f64,
        cfg: &MapConfig,
        dyn_cfg: &DynamicConfig,
    ) -> MapUpdateStats {
        let mut stats = MapUpdateStats::default();
        if dyn_cfg.enabled && !self.is_empty() {
            stats.observed = update_dynamic(
                &mut self.beam_bins,
                &self.cloud,
                &mut self.p_dynamic,
                raw_sensor,
                map_from_sensor,
                dyn_cfg,
            );
        }
        self.insert_and_limit(
            reading_map,
            map_from_sensor,
            stamp_s,
            cfg,
            dyn_cfg,
            &mut stats,
        );
        stats
    }

    /// The dynamic-point update alone, for scans that localise but do not update the map: every
    /// scan is a look through the places people may have left. Points that turn dynamic are
    /// removed at once.
    pub fn observe(
        &mut self,
        raw_sensor: &[Point],
        map_from_sensor: &Isometry3<f64>,
        dyn_cfg: &DynamicConfig,
    ) -> MapUpdateStats {
        let mut stats = MapUpdateStats::default();
        if !dyn_cfg.enabled || self.is_empty() {
            return stats;
        }
        stats.observed = update_dynamic(
            &mut self.beam_bins,
            &self.cloud,
            &mut self.p_dynamic,
            raw_sensor,
            map_from_sensor,
            dyn_cfg,
        );
        let thr = dyn_cfg.threshold as f32;
        if self.p_dynamic.iter().any(|pd| *pd > thr) {
            let keep: Vec<bool> = self.p_dynamic.iter().map(|pd| *pd <= thr).collect();
            stats.removed_dynamic = self.retain(&keep);
        }
        stats
    }

    /// Keeps the points whose `keep` is true (order preserved) and remaps the index onto them;
    /// returns how many went.
    fn retain(&mut self, keep: &[bool]) -> usize {
        let before = self.len();
        let mut new_pos = vec![u32::MAX; before];
        let mut j = 0;
        for i in 0..before {
            if keep[i] {
                self.cloud.points[j] = self.cloud.points[i];
                self.cloud.normals[j] = self.cloud.normals[i];
                self.p_dynamic[j] = self.p_dynamic[i];
                self.stamps[j] = self.stamps[i];
                new_pos[i] = j as u32;
                j += 1;
            }
        }
        self.cloud.points.truncate(j);
        self.cloud.normals.truncate(j);
        self.p_dynamic.truncate(j);
        self.stamps.truncate(j);
        self.index_map = Some(match self.index_map.take() {
            None => new_pos,
            Some(m) => m
                .into_iter()
                .map(|p| new_pos.get(p as usize).copied().unwrap_or(u32::MAX))
                .collect(),
        });
        before - j
    }

    /// Insertion of new reading points, removal of dynamic and far points, index and normals.
    fn insert_and_limit(
        &mut self,
        reading_map: &OrientedCloud,
        map_from_sensor: &Isometry3<f64>,
        stamp_s: f64,
        cfg: &MapConfig,
        dyn_cfg: &DynamicConfig,
        stats: &mut MapUpdateStats,
    ) {
        let sensor = map_from_sensor.translation.vector.cast::<f32>();
        let max_new = cfg.sensor_max_range_m as f32;
        // An unresolved "auto" (no adaptive state) is the adaptive floor.
        let min_d = cfg
            .min_dist_new_point_m
            .fixed()
            .unwrap_or_else(|| crate::adaptive::AdaptiveConfig::default().min_new_point_m);
        let min_d2 = (min_d * min_d) as f32;
        let thr = dyn_cfg.threshold as f32;
        let mut nb = Vec::with_capacity(1);
        let mut new_idx = Vec::new();
        for (i, p) in reading_map.points.iter().enumerate() {
            if (Vector3::from(*p) - sensor).norm() > max_new {
                continue;
            }
            self.knn(p, 1, f32::MAX.sqrt() / 2.0, &mut nb);
            // A neighbour about to be removed as dynamic does not count: the surface behind a
            // person who walked away must be able to fill in.
            if nb
                .first()
                .is_none_or(|(j, d2)| *d2 > min_d2 || self.p_dynamic[*j as usize] > thr)
            {
                new_idx.push(i);
            }
        }
        let limit2 = (cfg.distance_limit_m * cfg.distance_limit_m) as f32;
        let mut kept = OrientedCloud {
            points: Vec::with_capacity(self.len() + new_idx.len()),
            normals: Vec::with_capacity(self.len() + new_idx.len()),
        };
        let mut kept_p = Vec::with_capacity(self.len() + new_idx.len());
        let mut kept_t = Vec::with_capacity(self.len() + new_idx.len());
        for (((p, n), pd), t) in self
            .cloud
            .points
            .iter()
            .zip(&self.cloud.normals)
            .zip(&self.p_dynamic)
            .zip(&self.stamps)
        {
            if *pd > thr {
                stats.removed_dynamic += 1;
            } else if (Vector3::from(*p) - sensor).norm_squared() > limit2 {
                stats.removed_far += 1;
            } else {
                kept.points.push(*p);
                kept.normals.push(*n);
                kept_p.push(*pd);
                kept_t.push(*t);
            }
        }
        let first_new = kept.len();
        for i in new_idx {
            kept.points.push(reading_map.points[i]);
            kept.normals.push([0.0; 3]);
            kept_p.push(dyn_cfg.prior as f32);
            kept_t.push(stamp_s);
            stats.added += 1;
        }
        self.cloud = kept;
        self.p_dynamic = kept_p;
        self.stamps = kept_t;
        self.rebuild();
        self.refresh_normals(first_new, &sensor, cfg);
    }

    /// PCA normals of the points from `first_new` on and of the untrusted (zero) normals among
    /// their neighbours. Non-planar neighbourhoods, and points off their neighbourhood's plane,
    /// get a zero normal. New normals face the sensor; refreshed ones keep the side they had.
    fn refresh_normals(&mut self, first_new: usize, sensor: &Vector3<f32>, cfg: &MapConfig) {
        let n = self.len();
        if first_new >= n {
            return;
        }
        let k = cfg.normal_knn.max(3);
        let r = cfg.normal_max_dist_m as f32;
        let mut nb = Vec::with_capacity(k);
        let mut dirty = vec![false; n];
        let mut list: Vec<u32> = Vec::new();
        // The new points' neighbourhoods, kept for their own fits below (the same query on the
        // same index: asking again cost half of this pass's searches).
        let mut new_nb: Vec<(u32, f32)> = Vec::with_capacity((n - first_new) * k);
        let mut new_at: Vec<u32> = Vec::with_capacity(n - first_new + 1);
        new_at.push(0);
        for i in first_new..n {
            self.knn(&self.cloud.points[i], k, r, &mut nb);
            new_nb.extend_from_slice(&nb);
            new_at.push(new_nb.len() as u32);
            // A trusted normal stays (its neighbourhood was already a good plane); untrusted
            // ones get another chance as the map fills in around them.
            for (j, _) in &nb {
                let ju = *j as usize;
                let stale = ju >= first_new || self.cloud.normals[ju] == [0.0; 3];
                if stale && !std::mem::replace(&mut dirty[ju], true) {
                    list.push(*j);
                }
            }
            if !std::mem::replace(&mut dirty[i], true) {
                list.push(i as u32);
            }
        }
        let fresh: Vec<[f32; 3]> = list
            .iter()
            .map(|&i| {
                let p = self.cloud.points[i as usize];
                let nb: &[(u32, f32)] = match (i as usize).checked_sub(first_new) {
                    Some(j) => &new_nb[new_at[j] as usize..new_at[j + 1] as usize],
                    None => {
                        self.knn(&p, k, r, &mut nb);
                        &nb
                    }
                };
                let Some(fit) = pca_fit(&self.cloud.points, nb).filter(|f| {
                    f.is_planar(cfg.normal_min_spread, cfg.normal_max_thickness)
                        && f.fits(&Vector3::from(p), PLANE_FIT_MIN_M)
                }) else {
                    return [0.0; 3];
                };
                let old = Vector3::from(self.cloud.normals[i as usize]);
                let side = if old != Vector3::zeros() {
                    old
                } else {
                    sensor - Vector3::from(p)
                };
                let nrm = if fit.normal.dot(&side) < 0.0 {
                    -fit.normal
                } else {
                    fit.normal
                };
                nrm.into()
            })
            .collect();
        for (i, nrm) in list.into_iter().zip(fresh) {
            self.cloud.normals[i as usize] = nrm;
        }
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
        if let Some(m) = &self.index_map {
            out.retain_mut(|(i, _)| {
                *i = m[*i as usize];
                *i != u32::MAX
            });
        }
    }
}

#[cfg(test)]
mod tests;
