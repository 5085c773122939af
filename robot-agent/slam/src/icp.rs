//! Point-to-plane ICP: KD-tree matching, Cauchy weights on scaled residuals, normal-angle outlier
//! rejection, Gauss-Newton on SE(3) and the differential / counter / bound checkers.

use crate::config::IcpConfig;
use crate::filters::OrientedCloud;
use crate::index::Neighbours;
use crate::se3;
use nalgebra::{Isometry3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};

/// How an ICP run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum IcpStatus {
    /// The differential checker stopped it: the last step was below both thresholds.
    Converged,
    /// The counter checker stopped it (result still used).
    MaxIterations,
    /// The bound checker fired: the correction from the prior was implausibly large.
    OutOfBounds,
    /// Too few reading points found a partner, or too few of them were inliers.
    TooFewInliers,
}

impl IcpStatus {
    /// True when the registration result can be used.
    pub fn is_ok(self) -> bool {
        matches!(self, IcpStatus::Converged | IcpStatus::MaxIterations)
    }
}

/// The result and diagnostics of one registration.
#[derive(Clone, Debug, PartialEq)]
pub struct IcpResult {
    /// Estimated `target<-reading` (the prior when `status` is a failure).
    pub pose: Isometry3<f64>,
    /// How it ended.
    pub status: IcpStatus,
    /// Gauss-Newton iterations run.
    pub iterations: usize,
    /// Weighted RMS point-to-plane residual of the last iteration, metres.
    pub residual_rms_m: f64,
    /// Mean best weight per reading point (0..1): the share of the reading that is explained.
    pub inlier_ratio: f64,
    /// Reading points with at least one partner in the last iteration.
    pub matched_points: usize,
    /// Smallest / largest eigenvalue of the 6x6 Hessian in the last iteration.
    pub eig_ratio: f64,
    /// True when the geometry left some direction unconstrained (see `degenerate_eig_ratio`).
    pub degenerate: bool,
}

/// Cauchy robust weight `1/(1 + e^2/k^2)` of a residual already divided by its robust scale.
pub fn cauchy_weight(scaled_residual: f64, k: f64) -> f64 {
    1.0 / (1.0 + scaled_residual * scaled_residual / (k * k))
}

/// Registers `reading` (its own frame) against `target` (points + normals + index), starting at
/// `init` = `target<-reading`.
pub fn register(
    reading: &OrientedCloud,
    target: &OrientedCloud,
    index: &impl Neighbours,
    init: &Isometry3<f64>,
    cfg: &IcpConfig,
) -> IcpResult {
    let mut pose = *init;
    let mut res = IcpResult {
        pose,
        status: IcpStatus::TooFewInliers,
        iterations: 0,
        residual_rms_m: f64::NAN,
        inlier_ratio: 0.0,
        matched_points: 0,
        eig_ratio: 0.0,
        degenerate: false,
    };
    if reading.is_empty() || target.is_empty() {
        return res;
    }
    let cos_max = cfg.max_normal_angle_rad.cos() as f32;
    let k = cfg.knn.max(1);
    let max_d = cfg.match_dist_m() as f32;
    let mut nb = Vec::with_capacity(k);
    // Pairs of the current iteration: (reading index, point in target frame, target normal, residual).
    let mut pairs: Vec<(u32, Vector3<f32>, Vector3<f32>, f32)> =
        Vec::with_capacity(reading.len() * k);
    let mut abs_res: Vec<f32> = Vec::with_capacity(reading.len() * k);
    let mut best_w = vec![0.0f32; reading.len()];
    let mut status = IcpStatus::MaxIterations;
    for iter in 0..cfg.max_iterations.max(1) {
        res.iterations = iter + 1;
        let tf = pose.cast::<f32>();
        pairs.clear();
        for (i, (p, n)) in reading.points.iter().zip(&reading.normals).enumerate() {
            let pt = (tf * Point3::from(*p)).coords;
            let nr = tf.rotation * Vector3::from(*n);
            index.knn_within(&pt.into(), k, max_d, &mut nb);
            // A zero normal is an untrusted one (not a surface): such a target is skipped, such a
            // reading point is matched without the normal-angle test.
            let test_angle = nr != Vector3::zeros();
            for (j, _) in &nb {
                let j = *j as usize;
                let nq = Vector3::from(target.normals[j]);
                if nq == Vector3::zeros() || (test_angle && nr.dot(&nq) < cos_max) {
                    continue;
                }
                let e = (pt - Vector3::from(target.points[j])).dot(&nq);
                pairs.push((i as u32, pt, nq, e));
            }
        }
        best_w.iter_mut().for_each(|w| *w = 0.0);
        let mut matched = 0usize;
        let mut last = u32::MAX;
        for (i, ..) in &pairs {
            if *i != last {
                matched += 1;
                last = *i;
            }
        }
        res.matched_points = matched;
        if matched < cfg.min_matched_points.max(6) {
            status = IcpStatus::TooFewInliers;
            break;
        }
        // Robust scale: median absolute residual (MAD around zero, normal-consistent).
        abs_res.clear();
        abs_res.extend(pairs.iter().map(|p| p.3.abs()));
        let mid = abs_res.len() / 2;
        let (_, med, _) = abs_res.select_nth_unstable_by(mid, f32::total_cmp);
        let scale = (1.4826 * f64::from(*med)).max(cfg.min_residual_scale_m);
        // Linearise about the sensor position, not the map origin: far from the origin rotations
        // would otherwise look like translations and the Hessian's spectrum would mean nothing.
        let c = pose.translation.vector;
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        let (mut sw, mut swe2, mut sr2) = (0.0f64, 0.0f64, 0.0f64);
        for (i, pt, nq, e) in &pairs {
            let e = f64::from(*e);
            let w = cauchy_weight(e / scale, cfg.cauchy_k);
            let bw = &mut best_w[*i as usize];
            *bw = bw.max(w as f32);
            let pr = pt.cast::<f64>() - c;
            let nq = nq.cast::<f64>();
            let cr = pr.cross(&nq);
            let j = Vector6::new(cr.x, cr.y, cr.z, nq.x, nq.y, nq.z);
            h.syger(w, &j, &j, 1.0);
            g.axpy(w * e, &j, 1.0);
            sw += w;
            swe2 += w * e * e;
            sr2 += w * pr.norm_squared();
        }
        // syger fills the lower triangle only.
        h.fill_upper_triangle_with_lower_triangle();
        res.residual_rms_m = (swe2 / sw.max(1e-12)).sqrt();
        res.inlier_ratio = best_w.iter().map(|w| f64::from(*w)).sum::<f64>() / reading.len() as f64;
        if res.inlier_ratio < cfg.min_inlier_ratio {
            status = IcpStatus::TooFewInliers;
            break;
        }
        // Rotations are measured as arc length at the typical range so that the eigenvalues of
        // rotation and translation directions compare (both in m^2 per unit weight).
        let len_m = (sr2 / sw.max(1e-12)).sqrt().max(1.0);
        let d = Vector6::new(1.0 / len_m, 1.0 / len_m, 1.0 / len_m, 1.0, 1.0, 1.0);
        let hs = Matrix6::from_fn(|r, k| h[(r, k)] * d[r] * d[k]);
        let gs = g.component_mul(&d);
        let eig = SymmetricEigen::new(hs);
        let lmax = eig.eigenvalues.max();
        let lmin = eig.eigenvalues.min();
        res.eig_ratio = if lmax > 0.0 { lmin / lmax } else { 0.0 };
        res.degenerate = res.eig_ratio < cfg.degenerate_eig_ratio;
        // Solve H xi = -g in the eigenbasis, dropping degenerate directions: along them the
        // prior wins instead of noise (solution remapping). Along weak ones the data is
        // followed only within a few of its standard deviations of the prior: there a handful
        // of far points, or a surface the correspondences slide along, can walk the pose a
        // metre from a prior that was right (docs/algorithms.md §3.3).
        let about_sensor = Isometry3::translation(c.x, c.y, c.z);
        // Only sweeps with a weak direction need it (most have none).
        let mut from_init = None;
        let mut xs = Vector6::<f64>::zeros();
        for k in 0..6 {
            let l = eig.eigenvalues[k];
            if l <= cfg.degenerate_eig_ratio * lmax || l <= 0.0 {
                continue;
            }
            let v = eig.eigenvectors.column(k);
            let mut step = -v.dot(&gs) / l;
            if l < cfg.weak_eig_ratio * lmax {
                let reach = cfg.weak_max_sigmas * scale / l.sqrt();
                let from_init = from_init.get_or_insert_with(|| {
                    se3::log(&(about_sensor.inverse() * pose * init.inverse() * about_sensor))
                        .component_div(&d)
                });
                let at = v.dot(from_init);
                step = (at + step).clamp(-reach, reach) - at;
            }
            xs += v * step;
        }
        let xi = xs.component_mul(&d);
        pose = about_sensor * se3::exp(&xi) * about_sensor.inverse() * pose;
        let corr = pose * init.inverse();
        if se3::rotation_angle(&corr) > cfg.max_correction_rot_rad
            || (pose.translation.vector - init.translation.vector).norm()
                > cfg.max_correction_trans_m
        {
            status = IcpStatus::OutOfBounds;
            break;
        }
        let step_rot = Vector3::new(xi[0], xi[1], xi[2]).norm();
        let step_trans = Vector3::new(xi[3], xi[4], xi[5]).norm();
        if step_rot < cfg.min_step_rot_rad && step_trans < cfg.min_step_trans_m {
            status = IcpStatus::Converged;
            break;
        }
    }
    res.status = status;
    res.pose = if status.is_ok() { pose } else { *init };
    res
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::FilterConfig;
    use crate::filters::normals_and_density;
    use crate::index::KdIndex;
    use rand::{rngs::StdRng, Rng, SeedableRng};

    /// A room-like scene: floor, three walls and a box, so all six DoF are constrained.
    pub(crate) fn scene(rng: &mut StdRng, n: usize) -> Vec<[f32; 3]> {
        let mut v = Vec::new();
        for _ in 0..n {
            let a: f32 = rng.random_range(-5.0..5.0);
            let b: f32 = rng.random_range(-5.0..5.0);
            let c: f32 = rng.random_range(0.0..3.0);
            match rng.random_range(0..5) {
                0 => v.push([a, b, -1.0]),
                1 => v.push([6.0, a, c - 1.0]),
                2 => v.push([a, 6.0, c - 1.0]),
                3 => v.push([-6.0, a, c - 1.0]),
                _ => {
                    let s: f32 = rng.random_range(0.0..1.0);
                    v.push([2.0 + s, 1.0, c * 0.5 - 1.0]);
                }
            }
        }
        v
    }

    fn cloud(points: Vec<[f32; 3]>) -> OrientedCloud {
        let cfg = FilterConfig {
            max_density_per_m3: 0.0,
            ..FilterConfig::default()
        };
        normals_and_density(points, [0.0; 3], &cfg, &mut StdRng::seed_from_u64(3))
    }

    #[test]
    fn synthetic_pair_recovers_known_offset() {
        let mut rng = StdRng::seed_from_u64(7);
        let target = cloud(scene(&mut rng, 20_000));
        let truth = se3::from_xyz_rpy([0.3, -0.2, 0.05], [0.01, -0.02, 0.08]);
        // The reading is a fresh sample of the same scene seen from `truth`.
        let inv = truth.inverse().cast::<f32>();
        let reading_pts: Vec<[f32; 3]> = scene(&mut rng, 8_000)
            .into_iter()
            .map(|p| (inv * Point3::from(p)).coords.into())
            .collect();
        let reading = normals_and_density(
            reading_pts,
            [0.0; 3],
            &FilterConfig {
                max_density_per_m3: 0.0,
                ..FilterConfig::default()
            },
            &mut rng,
        );
        let index = KdIndex::build(&target.points);
        let r = register(
            &reading,
            &target,
            &index,
            &Isometry3::identity(),
            &IcpConfig::default(),
        );
        assert!(r.status.is_ok(), "{r:?}");
        let err = truth.inverse() * r.pose;
        assert!(
            se3::translation_norm(&err) < 0.01,
            "translation error {err:?}"
        );
        assert!(se3::rotation_angle(&err) < 0.002, "rotation error {err:?}");
        assert!(!r.degenerate);
        assert!(r.inlier_ratio > 0.8, "{r:?}");
    }

    #[test]
    fn a_single_plane_is_degenerate_and_keeps_the_prior_in_plane() {
        let mut rng = StdRng::seed_from_u64(9);
        let floor: Vec<[f32; 3]> = (0..5000)
            .map(|_| {
                [
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    -1.0,
                ]
            })
            .collect();
        let target = cloud(floor.clone());
        let reading = cloud(floor.iter().map(|p| [p[0], p[1], p[2] + 0.1]).collect());
        let init = se3::from_xyz_rpy([0.5, 0.0, 0.0], [0.0; 3]);
        let r = register(
            &reading,
            &target,
            &KdIndex::build(&target.points),
            &init,
            &IcpConfig::default(),
        );
        assert!(r.degenerate, "{r:?}");
        // z is corrected, x (unobservable on a plane) stays at the prior.
        assert!((r.pose.translation.z + 0.1).abs() < 0.01, "{r:?}");
        assert!((r.pose.translation.x - 0.5).abs() < 1e-6, "{r:?}");
    }

    #[test]
    fn a_weak_direction_moves_only_within_its_spread() {
        // A floor and, 6 m away, a short wall of 40 points that moved 0.4 m sideways between
        // the two clouds (a parked car that left): the only hold on y is those points. As on a
        // flat platform top with one far edge in view, following them would slide the pose;
        // the odometry's prior is the better estimate along that direction.
        let mut rng = StdRng::seed_from_u64(5);
        let floor = |rng: &mut StdRng| -> Vec<[f32; 3]> {
            (0..5000)
                .map(|_| {
                    [
                        rng.random_range(-8.0..8.0),
                        rng.random_range(-8.0..8.0),
                        -1.0,
                    ]
                })
                .collect()
        };
        let wall = |rng: &mut StdRng, y: f32| -> Vec<[f32; 3]> {
            (0..40)
                .map(|_| [rng.random_range(-1.0..1.0), y, rng.random_range(-0.9..0.0)])
                .collect()
        };
        let mut t = floor(&mut rng);
        t.extend(wall(&mut rng, 6.0));
        let mut r = floor(&mut rng);
        r.extend(wall(&mut rng, 6.4));
        let target = cloud(t);
        let reading = cloud(r.iter().map(|p| [p[0], p[1], p[2] + 0.05]).collect());
        let init = Isometry3::identity();
        let index = KdIndex::build(&target.points);
        let held = register(&reading, &target, &index, &init, &IcpConfig::default());
        assert!(held.status.is_ok(), "{held:?}");
        assert!(held.pose.translation.y.abs() < 0.05, "{held:?}");
        assert!((held.pose.translation.z + 0.05).abs() < 0.01, "{held:?}");
        // Without the weak class the wall drags the pose along.
        let trusting = IcpConfig {
            weak_eig_ratio: 0.0,
            ..IcpConfig::default()
        };
        let dragged = register(&reading, &target, &index, &init, &trusting);
        assert!(dragged.pose.translation.y < -0.2, "{dragged:?}");
    }

    #[test]
    fn bound_checker_fails_and_returns_the_prior() {
        let mut rng = StdRng::seed_from_u64(11);
        let target = cloud(scene(&mut rng, 10_000));
        let reading = target.transformed(&se3::from_xyz_rpy([0.5, 0.0, 0.0], [0.0; 3]));
        let cfg = IcpConfig {
            max_correction_trans_m: 0.1,
            ..IcpConfig::default()
        };
        let init = Isometry3::identity();
        let r = register(
            &reading,
            &target,
            &KdIndex::build(&target.points),
            &init,
            &cfg,
        );
        assert_eq!(r.status, IcpStatus::OutOfBounds);
        assert_eq!(r.pose, init);
    }

    #[test]
    fn counter_and_differential_checkers() {
        let mut rng = StdRng::seed_from_u64(12);
        let target = cloud(scene(&mut rng, 10_000));
        let reading = target.transformed(&se3::from_xyz_rpy([0.3, 0.1, 0.0], [0.0, 0.0, 0.05]));
        let index = KdIndex::build(&target.points);
        let one = register(
            &reading,
            &target,
            &index,
            &Isometry3::identity(),
            &IcpConfig {
                max_iterations: 1,
                ..IcpConfig::default()
            },
        );
        assert_eq!((one.status, one.iterations), (IcpStatus::MaxIterations, 1));
        let full = register(
            &reading,
            &target,
            &index,
            &Isometry3::identity(),
            &IcpConfig::default(),
        );
        assert_eq!(full.status, IcpStatus::Converged);
        assert!(full.iterations > 1 && full.iterations < 40, "{full:?}");
    }

    #[test]
    fn no_partners_is_too_few_inliers() {
        let mut rng = StdRng::seed_from_u64(13);
        let target = cloud(scene(&mut rng, 2_000));
        let far = target.transformed(&se3::from_xyz_rpy([100.0, 0.0, 0.0], [0.0; 3]));
        let r = register(
            &far,
            &target,
            &KdIndex::build(&target.points),
            &Isometry3::identity(),
            &IcpConfig::default(),
        );
        assert_eq!(r.status, IcpStatus::TooFewInliers);
    }

    #[test]
    fn cauchy_weight_halves_at_k_scales() {
        assert_eq!(cauchy_weight(0.0, 3.0), 1.0);
        assert!((cauchy_weight(3.0, 3.0) - 0.5).abs() < 1e-12);
        assert!((cauchy_weight(-3.0, 3.0) - 0.5).abs() < 1e-12);
        assert!((cauchy_weight(30.0, 3.0) - 1.0 / 101.0).abs() < 1e-12);
    }
}
