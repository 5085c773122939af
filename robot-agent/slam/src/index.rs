//! Nearest-neighbour index over a point set: a thin wrapper so the rest of the crate never sees
//! kiddo's generic query builders.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// An immutable 3D KD-tree over `f32` points; items are indices into the slice it was built from.
#[derive(Default)]
pub struct KdIndex {
    tree: Option<ImmutableKdTree<f32, 3>>,
    len: usize,
}

impl std::fmt::Debug for KdIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdIndex").field("len", &self.len).finish()
    }
}

impl KdIndex {
    /// Builds the tree; an empty slice gives an empty index.
    pub fn build(points: &[[f32; 3]]) -> Self {
        if points.is_empty() {
            return Self::default();
        }
        // Construction only fails for pathological inputs (e.g. too many identical points for a
        // leaf); an empty index then degrades matching to "no neighbours" instead of panicking.
        let tree = ImmutableKdTree::new_from_slice(points).ok();
        let len = if tree.is_some() { points.len() } else { 0 };
        Self { tree, len }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when nothing is indexed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Up to `k` nearest points within `max_dist_m`, nearest first, as `(index, squared distance)`.
    pub fn knn_within(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>) {
        out.clear();
        let (Some(tree), Some(k)) = (&self.tree, NonZeroUsize::new(k)) else {
            return;
        };
        let r2 = max_dist_m * max_dist_m;
        if k.get() == 1 {
            let n = tree
                .query(q)
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute();
            if n.distance <= r2 {
                out.push((n.item, n.distance));
            }
            return;
        }
        if !r2.is_finite() || r2 >= 1e20 {
            // Unbounded: the plain k-NN query skips the distance-threshold collection.
            let res = tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .execute();
            out.extend(res.into_iter().map(|r| (r.item, r.distance)));
            return;
        }
        let res = tree
            .query(q)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .within(r2)
            .execute();
        out.extend(res.into_iter().map(|r| (r.item, r.distance)));
    }

    /// The nearest point as `(index, squared distance)`.
    pub fn nearest(&self, q: &[f32; 3]) -> Option<(u32, f32)> {
        let tree = self.tree.as_ref()?;
        let n = tree
            .query(q)
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        Some((n.item, n.distance))
    }
}

/// A spatial index the ICP matcher can query.
pub trait Neighbours {
    /// Up to `k` nearest points within `max_dist_m`, nearest first, as `(index, squared distance)`.
    fn knn_within(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>);
}

impl Neighbours for KdIndex {
    fn knn_within(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>) {
        KdIndex::knn_within(self, q, k, max_dist_m, out)
    }
}

/// Voxel-hash index (the KISS-ICP layout): points bucketed in cubes of the matching distance, a
/// query scans the 27 cubes around it. Kept as the measured alternative to the KD-tree.
#[derive(Debug, Default)]
pub struct VoxelIndex {
    cells: crate::filters::FastMap<[i32; 3], Vec<u32>>,
    points: Vec<[f32; 3]>,
    inv_size: f32,
}

impl VoxelIndex {
    /// Buckets `points` in cubes of `size_m`.
    pub fn build(points: &[[f32; 3]], size_m: f32) -> Self {
        let inv_size = 1.0 / size_m.max(1e-3);
        let mut cells: crate::filters::FastMap<[i32; 3], Vec<u32>> = Default::default();
        for (i, p) in points.iter().enumerate() {
            cells
                .entry(crate::filters::voxel_of(p, inv_size))
                .or_default()
                .push(i as u32);
        }
        Self {
            cells,
            points: points.to_vec(),
            inv_size,
        }
    }
}

impl Neighbours for VoxelIndex {
    fn knn_within(&self, q: &[f32; 3], k: usize, max_dist_m: f32, out: &mut Vec<(u32, f32)>) {
        out.clear();
        let c = crate::filters::voxel_of(q, self.inv_size);
        let r2 = max_dist_m * max_dist_m;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(v) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                        continue;
                    };
                    for &i in v {
                        let p = self.points[i as usize];
                        let d2 =
                            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                        if d2 <= r2 {
                            out.push((i, d2));
                        }
                    }
                }
            }
        }
        out.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        out.truncate(k);
    }
}
