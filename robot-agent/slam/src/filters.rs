//! Reading filters (docs/algorithms.md §3.2): every n-th point, robot-box removal, range limits,
//! random sampling, voxel grid, surface normals by PCA, max density, normals oriented toward the
//! sensor.

use crate::config::FilterConfig;
use crate::index::KdIndex;
use nalgebra::{Isometry3, Matrix3, Point3, SymmetricEigen, Vector3};
use rand::rngs::StdRng;
use rand::Rng;
use sensing::Point;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Points with unit surface normals, both in the same frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OrientedCloud {
    /// Positions, metres.
    pub points: Vec<[f32; 3]>,
    /// Unit normals, one per point.
    pub normals: Vec<[f32; 3]>,
}

impl OrientedCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The cloud moved by `t` (points and normals).
    pub fn transformed(&self, t: &Isometry3<f64>) -> OrientedCloud {
        let tf = t.cast::<f32>();
        let points = self
            .points
            .iter()
            .map(|p| (tf * Point3::from(*p)).coords.into())
            .collect();
        let normals = self
            .normals
            .iter()
            .map(|n| (tf.rotation * Vector3::from(*n)).into())
            .collect();
        OrientedCloud { points, normals }
    }
}

/// FxHash-style multiplicative hasher: voxel keys are small integers, SipHash would dominate.
#[derive(Default)]
pub(crate) struct FastHasher(u64);

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(u64::from(*b));
        }
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i32(&mut self, i: i32) {
        self.write_u64(i as u32 as u64);
    }
}

/// Hash map with [`FastHasher`].
pub(crate) type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FastHasher>>;

/// Integer voxel of a point.
pub(crate) fn voxel_of(p: &[f32; 3], inv_size: f32) -> [i32; 3] {
    [
        (p[0] * inv_size).floor() as i32,
        (p[1] * inv_size).floor() as i32,
        (p[2] * inv_size).floor() as i32,
    ]
}

/// Sub-samples a raw scan (sensor frame) down to the points ICP uses, before normals.
pub fn sample(
    points: &[Point],
    base_from_lidar: &Isometry3<f64>,
    cfg: &FilterConfig,
    rng: &mut StdRng,
) -> Vec<[f32; 3]> {
    let n = cfg.keep_every_n.max(1);
    let lo = cfg.robot_box_min_m;
    let hi = cfg.robot_box_max_m;
    let (min_r, max_r) = (cfg.min_range_m as f32, cfg.max_range_m as f32);
    let mut out = Vec::with_capacity(points.len() / n + 1);
    for p in points.iter().step_by(n) {
        if !p.is_finite() {
            continue;
        }
        let r = p.range_m();
        if r < min_r || r > max_r || r == 0.0 {
            continue;
        }
        let pb = base_from_lidar * Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
        let inside = (0..3).all(|i| pb[i] >= lo[i] && pb[i] <= hi[i]);
        if inside {
            continue;
        }
        if cfg.keep_probability < 1.0 && rng.random::<f64>() >= cfg.keep_probability {
            continue;
        }
        out.push([p.x, p.y, p.z]);
    }
    // An unresolved "auto" (no adaptive state) means no voxel grid.
    if let Some(v) = cfg.voxel_size_m.fixed().filter(|v| *v > 0.0) {
        out = voxel_downsample(&out, v as f32);
    }
    out
}

/// Keeps the first point of each voxel (input order, so the result is deterministic).
pub fn voxel_downsample(points: &[[f32; 3]], size_m: f32) -> Vec<[f32; 3]> {
    let inv = 1.0 / size_m;
    let mut seen: FastMap<[i32; 3], ()> = FastMap::default();
    seen.reserve(points.len());
    points
        .iter()
        .filter(|p| seen.insert(voxel_of(p, inv), ()).is_none())
        .copied()
        .collect()
}

/// A PCA surface fit of one neighbourhood: the unit normal (smallest-variance direction) and the
/// variances along the three principal axes, ascending.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneFit {
    /// Unit normal (sign arbitrary).
    pub normal: Vector3<f32>,
    /// Centroid of the neighbourhood.
    pub centroid: Vector3<f32>,
    /// Variances `l0 <= l1 <= l2`, square metres.
    pub variances: [f32; 3],
}

impl PlaneFit {
    /// True when the neighbourhood is a surface: spread in two directions (`l1 >= min_spread *
    /// l2`) and thin in the third (`l0 <= max_thickness * l1`). A lidar ring seen alone is a line
    /// (`l1` is range noise), and the "normal" PCA picks for it is any direction across the
    /// ring, typically tens of degrees off the real surface: such fits must not act as planes.
    pub fn is_planar(&self, min_spread: f32, max_thickness: f32) -> bool {
        let [l0, l1, l2] = self.variances;
        l2 > 0.0 && l1 >= min_spread * l2 && l0 <= max_thickness * l1
    }

    /// True when `p` lies on the fitted plane as well as its neighbours do (within three standard
    /// deviations of their spread across it, or `min_m`). A person standing on a lawn has the
    /// lawn's plane as its neighbourhood fit; that plane says nothing about the person's points.
    pub fn fits(&self, p: &Vector3<f32>, min_m: f32) -> bool {
        (p - self.centroid).dot(&self.normal).abs() <= (3.0 * self.variances[0].sqrt()).max(min_m)
    }
}

/// PCA over the neighbours `neighbours` (indices into `pts`); `None` when there are fewer than 3
/// or the fit is degenerate.
pub fn pca_fit(pts: &[[f32; 3]], neighbours: &[(u32, f32)]) -> Option<PlaneFit> {
    if neighbours.len() < 3 {
        return None;
    }
    let mut mean = Vector3::<f32>::zeros();
    for (j, _) in neighbours {
        mean += Vector3::from(pts[*j as usize]);
    }
    mean /= neighbours.len() as f32;
    let mut cov = Matrix3::<f32>::zeros();
    for (j, _) in neighbours {
        let d = Vector3::from(pts[*j as usize]) - mean;
        cov += d * d.transpose();
    }
    cov /= neighbours.len() as f32;
    let (variances, n) = smallest_eigen(&cov)?;
    let norm = n.norm();
    if !norm.is_finite() || norm < 1e-6 {
        return None;
    }
    Some(PlaneFit {
        normal: n / norm,
        centroid: mean,
        variances,
    })
}

/// Eigenvalues (ascending, clamped at 0) of a symmetric 3x3 matrix and an eigenvector of the
/// smallest, in closed form (trigonometric solution of the characteristic cubic): several times
/// cheaper than the iterative solver, and normals are computed for every reading point of every
/// scan. Falls back to the iterative solver when the smallest eigenvalue is repeated.
fn smallest_eigen(a: &Matrix3<f32>) -> Option<([f32; 3], Vector3<f32>)> {
    let m = a.cast::<f64>();
    let p1 = m[(0, 1)].powi(2) + m[(0, 2)].powi(2) + m[(1, 2)].powi(2);
    let q = m.trace() / 3.0;
    let p2 = (m[(0, 0)] - q).powi(2) + (m[(1, 1)] - q).powi(2) + (m[(2, 2)] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if !p.is_finite() || p <= 1e-300 {
        return None;
    }
    let b = (m - Matrix3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let l_max = q + 2.0 * p * phi.cos();
    let l_min = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let l_mid = 3.0 * q - l_max - l_min;
    let variances = [l_min, l_mid, l_max].map(|l| l.max(0.0) as f32);
    // The eigenvector of l_min is orthogonal to the rows of (A - l_min I): the largest cross
    // product of two of them.
    let s = m - Matrix3::identity() * l_min;
    let rows = [
        s.row(0).transpose(),
        s.row(1).transpose(),
        s.row(2).transpose(),
    ];
    let best = [
        rows[0].cross(&rows[1]),
        rows[0].cross(&rows[2]),
        rows[1].cross(&rows[2]),
    ]
    .into_iter()
    .max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared()))?;
    if best.norm_squared() > 1e-12 * p * p * p * p {
        return Some((variances, best.cast::<f32>()));
    }
    let eig = SymmetricEigen::new(*a);
    let i = (0..3).min_by(|&x, &y| eig.eigenvalues[x].total_cmp(&eig.eigenvalues[y]))?;
    Some((variances, eig.eigenvectors.column(i).into_owned()))
}

/// Surface normals (PCA over `knn` neighbours), max-density thinning and orientation toward the
/// sensor at `sensor_m` (same frame as `points`).
pub fn normals_and_density(
    points: Vec<[f32; 3]>,
    sensor_m: [f32; 3],
    cfg: &FilterConfig,
    rng: &mut StdRng,
) -> OrientedCloud {
    let index = KdIndex::build(&points);
    let k = cfg.normal_knn.max(3);
    let max_density = cfg.max_density_per_m3 as f32;
    let max_dist_m = if cfg.normal_max_dist_m > 0.0 {
        cfg.normal_max_dist_m as f32
    } else {
        1e15
    };
    let mut out = OrientedCloud {
        points: Vec::with_capacity(points.len()),
        normals: Vec::with_capacity(points.len()),
    };
    let mut nb = Vec::with_capacity(k);
    for p in &points {
        index.knn_within(p, k, max_dist_m, &mut nb);
        let Some(fit) = pca_fit(&points, &nb) else {
            continue;
        };
        // An unreliable normal is kept as zero: the point still registers against the map, it
        // just cannot vote in the normal-angle test (or act as a plane when it is the target).
        let mut n = if fit.is_planar(cfg.normal_min_spread, cfg.normal_max_thickness) {
            fit.normal
        } else {
            Vector3::zeros()
        };
        if max_density > 0.0 {
            // Density = neighbours inside the sphere reaching the farthest of them.
            let r_m = nb.last().map_or(0.0, |(_, d2)| d2.sqrt()).max(1e-3);
            let density = nb.len() as f32 / (4.0 / 3.0 * std::f32::consts::PI * r_m * r_m * r_m);
            if density > max_density && rng.random::<f32>() >= max_density / density {
                continue;
            }
        }
        let to_sensor = Vector3::from(sensor_m) - Vector3::from(*p);
        if n.dot(&to_sensor) < 0.0 {
            n = -n;
        }
        out.points.push(*p);
        out.normals.push(n.into());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn plane(n: usize, spacing: f32, z: f32) -> Vec<[f32; 3]> {
        let mut v = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let x = i as f32 * spacing - 2.0;
                let y = j as f32 * spacing - 2.0;
                v.push([x, y, z + 0.1 * x + 0.2 * y]);
            }
        }
        v
    }

    #[test]
    fn closed_form_eigen_matches_the_iterative_solver() {
        let mut rng = StdRng::seed_from_u64(5);
        for _ in 0..2000 {
            let v = Matrix3::<f32>::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let scale = Vector3::new(
                rng.random_range(0.001..1.0),
                rng.random_range(0.01..1.0),
                1.0,
            );
            let a = v * Matrix3::from_diagonal(&scale) * v.transpose();
            let (vals, n) = smallest_eigen(&a).expect("eigen");
            let eig = SymmetricEigen::new(a);
            let mut want: Vec<f32> = eig.eigenvalues.iter().copied().collect();
            want.sort_by(f32::total_cmp);
            for (g, w) in vals.iter().zip(&want) {
                assert!(
                    (g - w.max(0.0)).abs() < 1e-4 * want[2].max(1e-6),
                    "{vals:?} {want:?}"
                );
            }
            let n = n.normalize();
            let residual = (a * n - n * vals[0]).norm();
            assert!(residual < 1e-3 * want[2], "{residual} for {a}");
        }
    }

    #[test]
    fn normals_on_a_plane_are_perpendicular_and_face_the_sensor() {
        let cfg = FilterConfig {
            max_density_per_m3: 0.0,
            ..FilterConfig::default()
        };
        let mut rng = StdRng::seed_from_u64(1);
        let cloud = normals_and_density(plane(20, 0.2, -1.0), [0.0, 0.0, 0.0], &cfg, &mut rng);
        assert_eq!(cloud.len(), 400);
        let truth = Vector3::new(-0.1f32, -0.2, 1.0).normalize();
        for (p, n) in cloud.points.iter().zip(&cloud.normals) {
            let n = Vector3::from(*n);
            assert!((n.dot(&truth) - 1.0).abs() < 1e-4, "normal {n:?} at {p:?}");
        }
    }

    #[test]
    fn max_density_thins_dense_surfaces_only() {
        let mut rng = StdRng::seed_from_u64(1);
        let cfg = FilterConfig::default();
        // 2 cm spacing is far above 10 points/m^3; 1 m spacing is below it.
        let dense = normals_and_density(plane(30, 0.02, -1.0), [0.0; 3], &cfg, &mut rng);
        let sparse = normals_and_density(plane(10, 1.0, -1.0), [0.0; 3], &cfg, &mut rng);
        assert!(dense.len() < 900 / 10, "dense kept {}", dense.len());
        assert_eq!(sparse.len(), 100);
    }

    #[test]
    fn sampling_drops_robot_box_and_every_nth() {
        let pts: Vec<Point> = (0..300)
            .map(|i| Point::xyz(0.1 + i as f32 * 0.01, 0.0, 0.0))
            .collect();
        let cfg = FilterConfig {
            keep_every_n: 1,
            keep_probability: 1.0,
            ..FilterConfig::default()
        };
        let mut rng = StdRng::seed_from_u64(1);
        let kept = sample(&pts, &Isometry3::identity(), &cfg, &mut rng);
        assert!(kept.iter().all(|p| p[0] > 0.5), "robot box not removed");
        assert_eq!(kept.len(), pts.iter().filter(|p| p.x > 0.5).count());
        let cfg3 = FilterConfig {
            keep_every_n: 3,
            ..cfg
        };
        let expect = pts.iter().step_by(3).filter(|p| p.x > 0.5).count();
        assert_eq!(
            sample(&pts, &Isometry3::identity(), &cfg3, &mut rng).len(),
            expect
        );
    }

    #[test]
    fn voxel_keeps_one_point_per_cube() {
        let pts = vec![
            [0.1, 0.1, 0.1],
            [0.2, 0.2, 0.2],
            [1.1, 0.1, 0.1],
            [-0.1, 0.1, 0.1],
        ];
        assert_eq!(
            voxel_downsample(&pts, 1.0),
            vec![[0.1, 0.1, 0.1], [1.1, 0.1, 0.1], [-0.1, 0.1, 0.1]]
        );
    }
}
