//! Point filters of docs/algorithms.md §4.1 (the source's steps 1-2): the height filter relative to
//! the robot and the isolated-point filter for dynamic leftovers.

use crate::config::IsolatedPair;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// Step 1: keeps a point unless `z_p > z_r + h_r + tan(phi_max) * dist_xy(p, r)`, and drops
/// points farther than `max_range_m` horizontally. `robot` is the map-frame position of the
/// ground under the robot. Returns how many points were dropped.
pub fn height_filter(
    points: &mut Vec<[f32; 3]>,
    robot: [f64; 3],
    h_r_m: f64,
    phi_max_rad: f64,
    max_range_m: f64,
) -> usize {
    let before = points.len();
    let tan_phi = phi_max_rad.tan();
    let r2 = max_range_m * max_range_m;
    points.retain(|p| {
        let (dx, dy) = (f64::from(p[0]) - robot[0], f64::from(p[1]) - robot[1]);
        let d2 = dx * dx + dy * dy;
        d2 <= r2 && f64::from(p[2]) <= robot[2] + h_r_m + tan_phi * d2.sqrt()
    });
    before - points.len()
}

/// Step 2: drops a point when, for any pair, the mean distance to its `knn_k` nearest neighbours
/// exceeds `dist_k_m`. Returns how many points were dropped.
pub fn isolated_point_filter(points: &mut Vec<[f32; 3]>, pairs: &[IsolatedPair]) -> usize {
    let test = vec![true; points.len()];
    isolated_point_filter_where(points, pairs, &test)
}

/// [`isolated_point_filter`] testing only the points with `test[i]` (all points still count as
/// neighbours). The mapper tests only points above their cell's lowest return: a stray point at
/// ground level cannot raise an obstacle, and ground returns are ~85 % of a sweep.
pub fn isolated_point_filter_where(
    points: &mut Vec<[f32; 3]>,
    pairs: &[IsolatedPair],
    test: &[bool],
) -> usize {
    debug_assert_eq!(points.len(), test.len());
    let before = points.len();
    let k_max = pairs.iter().map(|p| p.knn_k).max().unwrap_or(0);
    if points.is_empty() || k_max == 0 {
        return 0;
    }
    let Ok(tree) = ImmutableKdTree::<f32, 3>::new_from_slice(points) else {
        // Construction only fails on degenerate input (a huge pile of identical points); keeping
        // everything is the safe side for a filter meant to remove isolated points.
        return 0;
    };
    // A point passes a pair for sure if its k-th neighbour is within dist_k; the search radius
    // below is the largest k-th distance that can still give a mean within dist_k.
    let r_max = pairs
        .iter()
        .map(|p| p.knn_k as f64 * p.dist_k_m)
        .fold(0.0, f64::max) as f32;
    let Some(k_query) = NonZeroUsize::new(k_max + 1) else {
        return 0;
    };
    // One buffer for every query's distances (this runs for thousands of points a sweep).
    let mut dists: Vec<f32> = Vec::with_capacity(k_max);
    let keep: Vec<bool> = points
        .iter()
        .zip(test)
        .map(|(q, &t)| {
            if !t {
                return true;
            }
            let nn = tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f32>>(k_query)
                .within(r_max * r_max)
                .execute();
            // The point itself comes back at distance 0; skip one zero-distance entry.
            dists.clear();
            dists.extend(nn.iter().skip(1).map(|n| n.distance.sqrt()));
            pairs.iter().all(|pair| {
                if dists.len() < pair.knn_k {
                    return false;
                }
                let mean = dists[..pair.knn_k].iter().sum::<f32>() / pair.knn_k as f32;
                f64::from(mean) <= pair.dist_k_m
            })
        })
        .collect();
    let mut i = 0;
    points.retain(|_| {
        i += 1;
        keep[i - 1]
    });
    before - points.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Config;

    #[test]
    fn height_filter_drops_points_above_the_climb_cone() {
        let mut pts = vec![
            [0.0, 0.0, 0.9],
            [0.0, 0.0, 1.1],
            [5.0, 0.0, 3.0],
            [5.0, 0.0, 3.2],
            [40.0, 0.0, 0.0],
        ];
        // Cone at 5 m: 1.0 + 5 tan(23 deg) = 3.12 m.
        let dropped = height_filter(&mut pts, [0.0, 0.0, 0.0], 1.0, 23f64.to_radians(), 30.0);
        assert_eq!(dropped, 3);
        assert_eq!(pts, vec![[0.0, 0.0, 0.9], [5.0, 0.0, 3.0]]);
    }

    #[test]
    fn isolated_points_go_dense_points_stay() {
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                pts.push([i as f32 * 0.05, j as f32 * 0.05, 0.0]);
            }
        }
        let n = pts.len();
        pts.push([0.5, 0.5, 0.6]); // a lone point above the patch
        pts.push([3.0, 3.0, 0.0]);
        pts.push([3.05, 3.0, 0.0]); // a pair: passes k=2? mean of 2 nn > 0.08 since only one neighbour is near
        let dropped = isolated_point_filter(&mut pts, &Config::default().isolated_pairs);
        assert_eq!(dropped, 3, "kept {:?}", &pts[n..]);
        assert_eq!(pts.len(), n);
    }
}
