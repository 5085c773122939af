//! Place recognition: a Scan Context descriptor (Kim & Kim, IROS 2018) with ring-key retrieval.
//!
//! A scan (sensor frame, z up) is binned in a polar grid of [`RINGS`] range rings by
//! [`SECTORS`] azimuth sectors; a cell holds the highest point in it (above `z_offset_m` below
//! the sensor, so empty cells are zero). The ring key (share of occupied cells per ring) does
//! not change when the robot turns in place: it retrieves candidates from a KD-tree (kiddo).
//! Candidates are then compared column by column at every sector shift; the best shift is the
//! yaw between the two scans, which seeds the ICP that verifies the loop.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// Range rings of the descriptor (the paper's value).
pub const RINGS: usize = 20;
/// Azimuth sectors of the descriptor (6 degrees each, the paper's value).
pub const SECTORS: usize = 60;

/// One scan's descriptor.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanContext {
    /// Cell heights above the floor offset, metres, ring-major (`ring * SECTORS + sector`).
    cells: Vec<f32>,
    /// Share of occupied cells per ring (rotation invariant).
    ring_key: [f32; RINGS],
}

impl ScanContext {
    /// Builds the descriptor of `points` (sensor frame, metres) out to `max_range_m`; points
    /// lower than `z_offset_m` below the sensor are ignored.
    pub fn new(points: &[[f32; 3]], max_range_m: f64, z_offset_m: f64) -> Self {
        let mut cells = vec![0.0f32; RINGS * SECTORS];
        let max_r = max_range_m as f32;
        let off = z_offset_m as f32;
        for p in points {
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            let h = p[2] + off;
            if !(r < max_r && r > 0.0 && h > 0.0) {
                continue;
            }
            let ring = ((r / max_r) * RINGS as f32) as usize;
            let a = p[1].atan2(p[0]) + std::f32::consts::PI;
            let sector = ((a / std::f32::consts::TAU) * SECTORS as f32) as usize % SECTORS;
            let c = &mut cells[ring.min(RINGS - 1) * SECTORS + sector];
            *c = c.max(h);
        }
        let mut ring_key = [0.0f32; RINGS];
        for (r, k) in ring_key.iter_mut().enumerate() {
            let row = &cells[r * SECTORS..(r + 1) * SECTORS];
            *k = row.iter().filter(|v| **v > 0.0).count() as f32 / SECTORS as f32;
        }
        Self { cells, ring_key }
    }

    /// The rotation-invariant ring key.
    pub fn ring_key(&self) -> &[f32; RINGS] {
        &self.ring_key
    }

    /// Share of occupied cells: a descriptor of an empty field says nothing about the place.
    pub fn occupancy(&self) -> f64 {
        self.ring_key.iter().map(|v| f64::from(*v)).sum::<f64>() / RINGS as f64
    }

    /// Column-wise cosine distance to `other` with `other`'s sectors shifted by `shift`
    /// (`other[k + shift]` against `self[k]`), 0 (same) to 1; columns empty in either are skipped.
    fn distance_at(&self, other: &ScanContext, shift: usize) -> f64 {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for k in 0..SECTORS {
            let ko = (k + shift) % SECTORS;
            let (mut dot, mut na, mut nb) = (0.0f32, 0.0f32, 0.0f32);
            for r in 0..RINGS {
                let a = self.cells[r * SECTORS + k];
                let b = other.cells[r * SECTORS + ko];
                dot += a * b;
                na += a * a;
                nb += b * b;
            }
            if na > 0.0 && nb > 0.0 {
                sum += 1.0 - f64::from(dot / (na.sqrt() * nb.sqrt()));
                n += 1;
            }
        }
        if n == 0 {
            1.0
        } else {
            sum / n as f64
        }
    }

    /// Best distance over all sector shifts and the yaw it implies: `Rz(yaw)` maps this scan's
    /// frame into `other`'s (`other<-self`), radians in (-pi, pi].
    pub fn distance(&self, other: &ScanContext) -> (f64, f64) {
        let (mut best, mut best_shift) = (f64::INFINITY, 0usize);
        for s in 0..SECTORS {
            let d = self.distance_at(other, s);
            if d < best {
                best = d;
                best_shift = s;
            }
        }
        let step = std::f64::consts::TAU / SECTORS as f64;
        let mut yaw = best_shift as f64 * step;
        if yaw > std::f64::consts::PI {
            yaw -= std::f64::consts::TAU;
        }
        (best, yaw)
    }
}

/// A place match: the stored entry, its descriptor distance and the yaw `candidate<-query`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaceMatch {
    /// Id the entry was stored with (a keyframe index).
    pub id: usize,
    /// Scan Context distance, 0..1.
    pub distance: f64,
    /// Yaw from the query's frame to the candidate's, radians.
    pub yaw_rad: f64,
}

/// Stored descriptors with their time stamps, searchable by ring key.
#[derive(Default)]
pub struct PlaceDb {
    entries: Vec<(usize, f64, ScanContext)>,
    tree: Option<ImmutableKdTree<f32, RINGS>>,
    /// Entries the tree was built over (a prefix of `entries`, which arrive in time order).
    tree_len: usize,
}

impl std::fmt::Debug for PlaceDb {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlaceDb")
            .field("entries", &self.entries.len())
            .finish()
    }
}

impl PlaceDb {
    /// Stores a descriptor; stamps must not decrease.
    pub fn insert(&mut self, id: usize, stamp_s: f64, sc: ScanContext) {
        self.entries.push((id, stamp_s, sc));
    }

    /// Number of stored descriptors.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The best match of `query` among entries older than `before_s` (recent ones are the
    /// place the robot is in, not a revisit): the `candidates` nearest ring keys are compared
    /// in full and the closest below `max_distance` wins.
    pub fn query(
        &mut self,
        query: &ScanContext,
        before_s: f64,
        candidates: usize,
        max_distance: f64,
    ) -> Option<PlaceMatch> {
        let eligible = self.entries.partition_point(|e| e.1 < before_s);
        if eligible == 0 {
            return None;
        }
        if self.tree.is_none() || self.tree_len != eligible {
            let keys: Vec<[f32; RINGS]> = self.entries[..eligible]
                .iter()
                .map(|e| e.2.ring_key)
                .collect();
            self.tree = ImmutableKdTree::new_from_slice(&keys).ok();
            self.tree_len = eligible;
        }
        let tree = self.tree.as_ref()?;
        let k = NonZeroUsize::new(candidates.max(1))?;
        let nn = tree
            .query(&query.ring_key)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute();
        nn.into_iter()
            .filter_map(|n| {
                let (id, _, sc) = &self.entries[n.item as usize];
                let (distance, yaw_rad) = query.distance(sc);
                (distance <= max_distance).then_some(PlaceMatch {
                    id: *id,
                    distance,
                    yaw_rad,
                })
            })
            .min_by(|a, b| a.distance.total_cmp(&b.distance))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
    use rand::{rngs::StdRng, Rng, SeedableRng};

    /// A synthetic world: a ground plane and randomly placed upright boxes (trees, posts,
    /// buildings) of random heights over a square of `size_m`, as world points.
    pub(crate) fn world(seed: u64, size_m: f32, objects: usize) -> Vec<[f32; 3]> {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut v = Vec::new();
        for _ in 0..objects {
            let cx: f32 = rng.random_range(-size_m / 2.0..size_m / 2.0);
            let cy: f32 = rng.random_range(-size_m / 2.0..size_m / 2.0);
            let w: f32 = rng.random_range(0.5..4.0);
            let h: f32 = rng.random_range(1.0..8.0);
            // Four faces of a box, sampled at ~0.3 m.
            let n = ((w / 0.3) as usize).max(2);
            let m = ((h / 0.3) as usize).max(2);
            for i in 0..=n {
                let s = -w / 2.0 + w * i as f32 / n as f32;
                for j in 0..=m {
                    let z = h * j as f32 / m as f32;
                    v.push([cx + s, cy - w / 2.0, z]);
                    v.push([cx + s, cy + w / 2.0, z]);
                    v.push([cx - w / 2.0, cy + s, z]);
                    v.push([cx + w / 2.0, cy + s, z]);
                }
            }
        }
        v
    }

    /// What a 360-degree sensor at `pose` (world<-sensor, sensor 1.5 m above ground) sees of
    /// `world` within `range_m`: sensor-frame points plus ground rings, with a little noise.
    pub(crate) fn scan(
        world: &[[f32; 3]],
        pose: &Isometry3<f64>,
        range_m: f32,
        seed: u64,
    ) -> Vec<[f32; 3]> {
        let mut rng = StdRng::seed_from_u64(seed);
        let inv = pose.inverse().cast::<f32>();
        let mut out = Vec::new();
        for p in world {
            let q = inv * Point3::from(*p);
            if q.coords.xy().norm() < range_m && rng.random_bool(0.8) {
                out.push([
                    q.x + rng.random_range(-0.02..0.02),
                    q.y + rng.random_range(-0.02..0.02),
                    q.z + rng.random_range(-0.02..0.02),
                ]);
            }
        }
        // Ground: world z = 0, sampled in the sensor frame.
        for _ in 0..3000 {
            let r: f32 = rng.random_range(2.0..range_m.min(30.0));
            let a: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let w = pose.cast::<f32>() * Point3::new(r * a.cos(), r * a.sin(), 0.0);
            let g = inv * Point3::new(w.x, w.y, 0.0);
            out.push([g.x, g.y, g.z]);
        }
        out
    }

    pub(crate) fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, 1.5),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    #[test]
    fn descriptor_is_rotation_invariant_and_recovers_yaw() {
        let w = world(1, 200.0, 150);
        let a = ScanContext::new(&scan(&w, &pose(10.0, 5.0, 0.3), 60.0, 1), 60.0, 2.0);
        let other = ScanContext::new(&scan(&w, &pose(-40.0, 30.0, 0.3), 60.0, 3), 60.0, 2.0);
        for yaw in [1.0f64, -2.5, 3.0] {
            let b = ScanContext::new(&scan(&w, &pose(10.0, 5.0, 0.3 + yaw), 60.0, 2), 60.0, 2.0);
            assert!(
                a.ring_key()
                    .iter()
                    .zip(b.ring_key())
                    .all(|(x, y)| (x - y).abs() < 0.08),
                "ring keys differ: {:?} {:?}",
                a.ring_key(),
                b.ring_key()
            );
            let (d, est) = b.distance(&a);
            assert!(d < 0.25, "distance {d} at yaw {yaw}");
            // Another place is farther than the same place turned.
            let (d_other, _) = b.distance(&other);
            assert!(d_other > d + 0.1, "{d_other} vs {d}");
            let err = (est - yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(err.abs() < 0.11, "yaw {yaw} estimated {est}");
        }
    }

    #[test]
    fn revisited_place_is_retrieved_among_a_path() {
        let w = world(2, 300.0, 300);
        let mut db = PlaceDb::default();
        // A path east along y = 0, one keyframe every 5 m, stamps 1 s apart.
        for i in 0..40 {
            let x = -100.0 + 5.0 * i as f64;
            let sc = ScanContext::new(&scan(&w, &pose(x, 0.0, 0.0), 60.0, i), 60.0, 2.0);
            db.insert(i as usize, i as f64, sc);
        }
        // Back at x = -40 (keyframe 12), 1 m to the side, driving west.
        let q = ScanContext::new(
            &scan(&w, &pose(-40.0, 1.0, std::f64::consts::PI), 60.0, 99),
            60.0,
            2.0,
        );
        let m = db.query(&q, 100.0, 10, 0.4).expect("a match");
        assert!((11..=13).contains(&m.id), "matched keyframe {}", m.id);
        assert!(
            (m.yaw_rad.abs() - std::f64::consts::PI).abs() < 0.15,
            "{m:?}"
        );
        // Entries at or after the exclusion stamp are not searched.
        assert!(db
            .query(&q, 5.0, 10, 0.4)
            .is_none_or(|m| m.id < 5 && m.distance > 0.2));
        // A place never visited does not match under a tight threshold.
        let far = ScanContext::new(&scan(&w, &pose(60.0, 90.0, 0.0), 60.0, 5), 60.0, 2.0);
        let best = db.query(&far, 100.0, 10, 1.0).expect("some candidate");
        let right = db.query(&q, 100.0, 10, 1.0).expect("a match");
        assert!(
            best.distance > right.distance + 0.1,
            "{best:?} vs {right:?}"
        );
    }
}
