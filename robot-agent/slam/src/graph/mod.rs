//! A pose graph behind the scan-to-map odometry (docs/algorithms.md §3.7).
//!
//! Keyframes carry the odometry's pose, the optimised pose, a local cloud and its place
//! descriptor. Factors: odometry between consecutive keyframes (information shrinking with the
//! distance driven), GNSS positions (only fixes the caller trusts), verified loop closures
//! (Cauchy kernel) and a prior on the first keyframe that fixes the gauge. [`PoseGraph::optimise`]
//! runs Levenberg-Marquardt with a sparse Cholesky solve; the correction `pose * odom_pose^-1`
//! it leaves on each keyframe is spread along the chain by the odometry factors instead of
//! jumping at the keyframe where the loop closed or the fix came back.
//!
//! Pure: no clock, no I/O; stamps are inputs. The graph's world frame is the frame the caller
//! gives odometry poses and GNSS positions in.

pub mod factors;
pub mod keyframes;
pub mod solve;

use crate::config::{FilterConfig, IcpConfig};
use crate::filters::{normals_and_density, voxel_downsample, OrientedCloud};
use crate::icp::{self, IcpStatus};
use crate::index::KdIndex;
use crate::place::{PlaceDb, ScanContext};
use factors::{information, BetweenKind, Factor};
pub use keyframes::{Keyframe, KeyframeSelector};
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use rand::{rngs::StdRng, SeedableRng};
use serde::Deserialize;
pub use solve::{SolveOptions, SolveReport};
use std::sync::Arc;

/// `[graph]` of config/slam.toml.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct GraphConfig {
    /// Run the pose graph (the agent feeds it and applies its corrections).
    pub enabled: bool,
    /// A keyframe after this much travel since the last, metres...
    pub keyframe_min_travel_m: f64,
    /// ...or this much turn, radians.
    pub keyframe_min_rotation_rad: f64,
    /// Odometry factor: translation sigma at zero distance, metres...
    pub odom_sigma_trans_min_m: f64,
    /// ...growing by this per metre driven between the two keyframes.
    pub odom_sigma_trans_per_m: f64,
    /// Odometry factor: rotation sigma at zero distance, radians...
    pub odom_sigma_rot_min_rad: f64,
    /// ...growing by this per metre driven.
    pub odom_sigma_rot_per_m_rad: f64,
    /// Gauge prior on the first keyframe: translation sigma, metres.
    pub anchor_sigma_m: f64,
    /// Gauge prior on the first keyframe: rotation sigma, radians.
    pub anchor_sigma_rad: f64,
    /// GNSS factors never trust a fix more than this, metres.
    pub gnss_min_sigma_m: f64,
    /// Gravity factor: tilt sigma of the accelerometer's up direction at a keyframe, radians
    /// (0: no gravity factors; the agent adds one only while its gravity estimate is fresh).
    pub gravity_sigma_rad: f64,
    /// Scan Context: range of the descriptor, metres.
    pub place_max_range_m: f64,
    /// Scan Context: points lower than this below the sensor are ignored, metres.
    pub place_z_offset_m: f64,
    /// Descriptors with fewer occupied cells than this share say nothing (open field), 0..1.
    pub place_min_occupancy: f64,
    /// Ring-key neighbours compared in full.
    pub place_candidates: usize,
    /// Largest Scan Context distance of a candidate, 0..1.
    pub place_max_distance: f64,
    /// Keyframes younger than this are not loop candidates, seconds.
    pub loop_exclude_recent_s: f64,
    /// Besides the descriptor's candidate, the nearest older keyframe by the graph's own poses
    /// within this distance is verified too, from their relative pose, metres (0: off).
    pub loop_search_radius_m: f64,
    /// Verification ICP: matching distance of the coarse pass, metres (the fine pass uses a
    /// third of it).
    pub loop_icp_max_match_dist_m: f64,
    /// Verification ICP: the two keyframes may be at most this far apart, metres.
    pub loop_max_offset_m: f64,
    /// The candidate's cloud is verified against together with this many keyframes on each
    /// side of it (their clouds carried into its frame by the graph's poses, thinned to
    /// `keyframe_voxel_m`): one sweep from another spot hits other ground rings and other
    /// faces of the same objects, a local submap holds them (0: the candidate's cloud alone).
    pub loop_submap_keyframes: usize,
    /// A loop is accepted when the ICP explains at least this share of the reading...
    pub loop_min_inlier_ratio: f64,
    /// ...with a weighted RMS point-to-plane residual at most this, metres...
    pub loop_max_rms_m: f64,
    /// ...and when the fit pins the reading in every direction: the smallest eigenvalue of the
    /// mean `n n^T` over the paired points' target normals is at least this (0..1/3; near 0
    /// when some direction is free, as along a corridor's walls). See [`translation_constraint`].
    pub loop_min_constraint: f64,
    /// ...and when the correction it implies is one the graph could have drifted into: the
    /// measured `from<-to` may differ from the graph's own by at most `loop_min_drift_m` plus
    /// this share of the distance driven from each end to its nearest keyframe with a GNSS
    /// factor (the first keyframe counts), 0..1. A place that merely looks the same (a lane of
    /// poles and walls) is tens of metres from where the graph knows the robot to be.
    pub loop_max_drift_per_m: f64,
    /// The smallest correction bound of that test, metres.
    pub loop_min_drift_m: f64,
    /// Loop factor translation sigma, metres.
    pub loop_sigma_trans_m: f64,
    /// Loop factor rotation sigma, radians.
    pub loop_sigma_rot_rad: f64,
    /// Cauchy kernel scale on a loop factor's Mahalanobis distance (sigmas).
    pub loop_cauchy_sigmas: f64,
    /// Solver: most LM iterations.
    pub max_iterations: usize,
    /// Keyframe clouds are voxel-thinned to this, metres (the agent's keyframes).
    pub keyframe_voxel_m: f64,
    /// A fix goes on a keyframe made within this of it, seconds (the agent's GNSS factors).
    pub gnss_max_age_s: f64,
    /// A GNSS factor this long after the previous one is RTK back after an outage: the graph is
    /// optimised then, seconds.
    pub outage_min_s: f64,
    /// The terrain map keeps a sweep for rebuilding after this much travel since the last kept
    /// one, metres (the agent's map rebuild after a correction).
    pub map_rebuild_spacing_m: f64,
    /// The terrain map is rebuilt when a correction moves some kept sweep by more than this,
    /// metres.
    pub map_rebuild_min_move_m: f64,
    /// A rebuild feeds at most this many kept sweeps to its shadow map per live sweep, sweeps
    /// (0: the whole rebuild inside the sweep that brought the correction).
    pub map_rebuild_sweeps_per_tick: usize,
    /// The kept sweeps hold at most this much, megabytes (10^6 bytes); over it the oldest half
    /// is thinned to every second sweep.
    pub map_rebuild_max_mb: f64,
}

impl Default for GraphConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            keyframe_min_travel_m: 2.0,
            keyframe_min_rotation_rad: 0.5,
            odom_sigma_trans_min_m: 0.01,
            odom_sigma_trans_per_m: 0.01,
            odom_sigma_rot_min_rad: 0.001,
            odom_sigma_rot_per_m_rad: 0.0005,
            anchor_sigma_m: 0.01,
            anchor_sigma_rad: 0.001,
            gnss_min_sigma_m: 0.02,
            gravity_sigma_rad: 0.0,
            place_max_range_m: 60.0,
            place_z_offset_m: 2.0,
            place_min_occupancy: 0.05,
            place_candidates: 10,
            place_max_distance: 0.3,
            loop_exclude_recent_s: 30.0,
            loop_search_radius_m: 5.0,
            loop_icp_max_match_dist_m: 3.0,
            loop_max_offset_m: 8.0,
            loop_submap_keyframes: 5,
            loop_min_inlier_ratio: 0.5,
            loop_max_rms_m: 0.15,
            loop_min_constraint: 0.01,
            loop_max_drift_per_m: 0.05,
            loop_min_drift_m: 1.0,
            loop_sigma_trans_m: 0.1,
            loop_sigma_rot_rad: 0.01,
            loop_cauchy_sigmas: 3.0,
            max_iterations: 50,
            keyframe_voxel_m: 0.3,
            gnss_max_age_s: 0.2,
            outage_min_s: 5.0,
            map_rebuild_spacing_m: 0.5,
            map_rebuild_min_move_m: 0.05,
            map_rebuild_sweeps_per_tick: 2,
            map_rebuild_max_mb: 64.0,
        }
    }
}

/// Why a loop candidate was not added.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub enum LoopRejection {
    /// The keyframe has no cloud or descriptor, or the descriptor is nearly empty.
    NoDescriptor,
    /// No stored place was close enough.
    NoCandidate,
    /// The verification ICP failed (status).
    IcpFailed(IcpStatus),
    /// It converged, but explains too little of the scan or fits too loosely.
    PoorFit {
        /// Share of the reading explained.
        inlier_ratio: f64,
        /// Weighted RMS residual, metres.
        rms_m: f64,
    },
    /// It fits, but some direction is left free (the fit could slide along it): see
    /// [`translation_constraint`].
    Degenerate {
        /// The weakest direction's share of the paired normals, 0..1/3.
        constraint: f64,
    },
    /// It fits, but it would move the robot further than the graph can have drifted since
    /// GNSS last held it (`loop_max_drift_per_m`): another place that looks the same.
    Inconsistent {
        /// How far the loop would move `to` against `from` from where the graph has it, metres.
        correction_m: f64,
        /// The most the graph can have drifted there, metres.
        allowed_m: f64,
    },
}

/// An accepted loop: the factor's ends, the measured `from<-to` and the verification numbers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopClosure {
    /// The earlier keyframe (the revisited place).
    pub from: usize,
    /// The current keyframe.
    pub to: usize,
    /// Measured `from<-to`.
    pub measured: Isometry3<f64>,
    /// Scan Context distance (NaN when a keyframe has no descriptor).
    pub descriptor_distance: f64,
    /// ICP inlier share.
    pub inlier_ratio: f64,
    /// ICP weighted RMS residual, metres.
    pub rms_m: f64,
}

/// Verifies a loop candidate: registers `reading` (the current keyframe's cloud, its frame)
/// against `target` (the candidate's cloud) from `init` = `target<-reading`, coarse then fine,
/// and gates on the fit. Returns the measured `target<-reading` and (inlier share, RMS).
pub fn verify_loop(
    reading: &OrientedCloud,
    target: &OrientedCloud,
    init: &Isometry3<f64>,
    cfg: &GraphConfig,
) -> Result<(Isometry3<f64>, f64, f64), LoopRejection> {
    let index = KdIndex::build(&target.points);
    let mut icp_cfg = IcpConfig {
        max_match_dist_m: crate::config::Auto::Fixed(cfg.loop_icp_max_match_dist_m),
        max_iterations: 60,
        max_correction_trans_m: cfg.loop_max_offset_m,
        max_correction_rot_rad: 0.6,
        min_inlier_ratio: 0.0,
        ..IcpConfig::default()
    };
    let coarse = icp::register(reading, target, &index, init, &icp_cfg);
    if !coarse.status.is_ok() {
        return Err(LoopRejection::IcpFailed(coarse.status));
    }
    icp_cfg.max_match_dist_m = crate::config::Auto::Fixed(cfg.loop_icp_max_match_dist_m / 3.0);
    let fine = icp::register(reading, target, &index, &coarse.pose, &icp_cfg);
    if !fine.status.is_ok() {
        return Err(LoopRejection::IcpFailed(fine.status));
    }
    if fine.inlier_ratio < cfg.loop_min_inlier_ratio || fine.residual_rms_m > cfg.loop_max_rms_m {
        return Err(LoopRejection::PoorFit {
            inlier_ratio: fine.inlier_ratio,
            rms_m: fine.residual_rms_m,
        });
    }
    let constraint = translation_constraint(
        reading,
        target,
        &index,
        &fine.pose,
        (cfg.loop_icp_max_match_dist_m / 3.0) as f32,
    );
    if constraint < cfg.loop_min_constraint {
        return Err(LoopRejection::Degenerate { constraint });
    }
    Ok((fine.pose, fine.inlier_ratio, fine.residual_rms_m))
}

/// How firmly a fit pins the reading in translation (the degeneracy test of Zhang, Kaess and
/// Singh, ICRA 2016, on the translation block of the point-to-plane Hessian): the reading's
/// points at `pose` are paired with their nearest target point within `max_dist_m`, and the
/// smallest eigenvalue of the mean `n n^T` of the paired target normals is returned (0 with no
/// pair). Each pair constrains the fit only along its normal, so a direction no normal points
/// along is free: along a corridor of walls (normals across it and up) the eigenvalue is near 0
/// and a fit there may have slid by any amount, however many points it explains; normals spread
/// evenly give 1/3. The inlier share alone cannot tell (a wall fits its wall at any offset).
pub fn translation_constraint(
    reading: &OrientedCloud,
    target: &OrientedCloud,
    index: &KdIndex,
    pose: &Isometry3<f64>,
    max_dist_m: f32,
) -> f64 {
    let t = pose.cast::<f32>();
    let mut m = Matrix3::<f64>::zeros();
    let mut n_pairs = 0usize;
    for p in &reading.points {
        let q = t * nalgebra::Point3::new(p[0], p[1], p[2]);
        let Some((j, d)) = index.nearest(&[q.x, q.y, q.z]) else {
            continue;
        };
        // Squared distances.
        if d > max_dist_m * max_dist_m {
            continue;
        }
        let n = target.normals[j as usize];
        if !n.iter().all(|c| c.is_finite()) {
            continue;
        }
        let n = Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
        m += n * n.transpose();
        n_pairs += 1;
    }
    if n_pairs == 0 {
        return 0.0;
    }
    (m / n_pairs as f64)
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .max(0.0)
}

/// A keyframe's (or a submap's) cloud with normals: `points` thinned to `voxel_m`, in its own
/// frame; PCA over the neighbours within three voxels, oriented toward `sensor_m`. Every point
/// is kept; one whose neighbourhood is no surface gets a zero normal (untrusted, §3.2).
pub fn keyframe_normals(points: Vec<[f32; 3]>, sensor_m: [f32; 3], voxel_m: f64) -> OrientedCloud {
    let cfg = FilterConfig {
        max_density_per_m3: 0.0,
        normal_max_dist_m: 3.0 * voxel_m,
        ..FilterConfig::default()
    };
    // No density thinning, so the generator is never drawn from.
    normals_and_density(points, sensor_m, &cfg, &mut StdRng::seed_from_u64(1))
}

/// The graph: keyframes, factors and the place database.
#[derive(Debug)]
pub struct PoseGraph {
    cfg: GraphConfig,
    keyframes: Vec<Keyframe>,
    factors: Vec<Factor>,
    places: PlaceDb,
    /// Per keyframe: odometry distance driven from the first keyframe, metres.
    travel_m: Vec<f64>,
    /// Per keyframe: held by an absolute factor (GNSS, or the first keyframe's prior).
    anchored: Vec<bool>,
    /// The last submap built: (centre keyframe, keyframes merged, the cloud). The descriptor
    /// proposes the same candidate again and again; an optimisation moves the poses and clears it.
    submap_cache: Option<(usize, Vec<usize>, Arc<OrientedCloud>)>,
}

impl PoseGraph {
    /// An empty graph.
    pub fn new(cfg: GraphConfig) -> Self {
        Self {
            cfg,
            keyframes: Vec::new(),
            factors: Vec::new(),
            places: PlaceDb::default(),
            travel_m: Vec::new(),
            anchored: Vec::new(),
            submap_cache: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &GraphConfig {
        &self.cfg
    }

    /// All keyframes, oldest first.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// All factors.
    pub fn factors(&self) -> &[Factor] {
        &self.factors
    }

    /// Adds a keyframe at the odometry pose `odom_pose` with its local `cloud` (keyframe frame)
    /// and returns its index. Its optimised pose starts as the previous keyframe's corrected
    /// pose composed with the odometry step; an odometry factor joins the two.
    pub fn add_keyframe(
        &mut self,
        stamp_s: f64,
        odom_pose: Isometry3<f64>,
        cloud: Option<Arc<OrientedCloud>>,
    ) -> usize {
        let idx = self.keyframes.len();
        self.anchored.push(idx == 0);
        let pose = match self.keyframes.last() {
            None => {
                self.travel_m.push(0.0);
                self.factors.push(Factor::Prior {
                    kf: idx,
                    pose: odom_pose,
                    info: information(self.cfg.anchor_sigma_rad, self.cfg.anchor_sigma_m),
                });
                odom_pose
            }
            Some(prev) => {
                let step = prev.odom_pose.inverse() * odom_pose;
                let dist = step.translation.vector.norm();
                self.travel_m.push(self.travel_m[idx - 1] + dist);
                let c = &self.cfg;
                self.factors.push(Factor::Between {
                    from: idx - 1,
                    to: idx,
                    measured: step,
                    info: information(
                        c.odom_sigma_rot_min_rad + c.odom_sigma_rot_per_m_rad * dist,
                        c.odom_sigma_trans_min_m + c.odom_sigma_trans_per_m * dist,
                    ),
                    kind: BetweenKind::Odometry,
                });
                prev.pose * step
            }
        };
        let descriptor = cloud.as_ref().map(|c| {
            ScanContext::new(
                &c.points,
                self.cfg.place_max_range_m,
                self.cfg.place_z_offset_m,
            )
        });
        if let Some(d) = &descriptor {
            if d.occupancy() >= self.cfg.place_min_occupancy {
                self.places.insert(idx, stamp_s, d.clone());
            }
        }
        self.keyframes.push(Keyframe {
            stamp_s,
            odom_pose,
            pose,
            cloud,
            descriptor,
        });
        idx
    }

    /// Adds a gravity factor on keyframe `kf`: `up` is the world's up direction in the
    /// keyframe's frame as the accelerometer measured it, `sigma_rad` its tilt uncertainty.
    /// Position factors alone leave the keyframes' roll and pitch to the odometry chain, and a
    /// rebuilt map then tilts the ground of a long stretch by SLAM's drift.
    pub fn add_gravity(&mut self, kf: usize, up: Vector3<f64>, sigma_rad: f64) {
        let n = up.norm();
        if kf >= self.keyframes.len() || !n.is_finite() || n < 1e-6 {
            return;
        }
        self.factors.push(Factor::Gravity {
            kf,
            up: up / n,
            info: 1.0 / sigma_rad.max(1e-9).powi(2),
        });
    }

    /// Adds a GNSS position factor on keyframe `kf`: `enu_m` in the graph's world frame with
    /// horizontal and vertical sigmas (floored at `gnss_min_sigma_m`). Only trusted fixes.
    pub fn add_gnss(&mut self, kf: usize, enu_m: Vector3<f64>, sigma_h_m: f64, sigma_v_m: f64) {
        if kf >= self.keyframes.len() || !enu_m.iter().all(|v| v.is_finite()) {
            return;
        }
        let h = sigma_h_m.max(self.cfg.gnss_min_sigma_m);
        let v = sigma_v_m.max(self.cfg.gnss_min_sigma_m);
        let info =
            Matrix3::from_diagonal(&Vector3::new(1.0 / (h * h), 1.0 / (h * h), 1.0 / (v * v)));
        self.factors.push(Factor::Position { kf, enu_m, info });
        self.anchored[kf] = true;
    }

    /// Adds a loop factor `from<-to` (robust kernel), e.g. from another recogniser.
    pub fn add_loop(&mut self, from: usize, to: usize, measured: Isometry3<f64>) {
        if from >= self.keyframes.len() || to >= self.keyframes.len() || from == to {
            return;
        }
        self.factors.push(Factor::Between {
            from,
            to,
            measured,
            info: information(self.cfg.loop_sigma_rot_rad, self.cfg.loop_sigma_trans_m),
            kind: BetweenKind::Loop,
        });
    }

    /// Looks for a place keyframe `kf` revisits and adds the loop factor when ICP verifies it.
    /// Two candidates: the best Scan Context match (finds a place however far the poses have
    /// drifted), then the nearest older keyframe by the graph's own poses within
    /// `loop_search_radius_m` (finds the revisit the descriptor misses: in an open, repetitive
    /// world the best descriptor match is often another place). Does not optimise. The error
    /// is why the last candidate failed.
    pub fn detect_loop(&mut self, kf: usize) -> Result<LoopClosure, LoopRejection> {
        let Some(k) = self.keyframes.get(kf) else {
            return Err(LoopRejection::NoDescriptor);
        };
        let Some(cloud) = k.cloud.clone() else {
            return Err(LoopRejection::NoDescriptor);
        };
        let before_s = k.stamp_s - self.cfg.loop_exclude_recent_s;
        let mut why = LoopRejection::NoDescriptor;
        let mut tried = None;
        let descriptor = k
            .descriptor
            .as_ref()
            .filter(|d| d.occupancy() >= self.cfg.place_min_occupancy);
        if let Some(desc) = descriptor {
            why = LoopRejection::NoCandidate;
            let m = self.places.query(
                desc,
                before_s,
                self.cfg.place_candidates,
                self.cfg.place_max_distance,
            );
            if let Some(m) = m {
                tried = Some(m.id);
                let init = Isometry3::from_parts(
                    Default::default(),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, m.yaw_rad),
                );
                match self.verify_with(m.id, kf, &cloud, &init, m.distance) {
                    Ok(c) => return Ok(c),
                    Err(e) => why = e,
                }
            }
        }
        if let Some(j) = self
            .nearest_older(kf, before_s)
            .filter(|j| Some(*j) != tried)
        {
            let init = self.keyframes[j].pose.inverse() * self.keyframes[kf].pose;
            let distance = self.keyframes[kf]
                .descriptor
                .as_ref()
                .zip(self.keyframes[j].descriptor.as_ref())
                .map_or(f64::NAN, |(a, b)| a.distance(b).0);
            match self.verify_with(j, kf, &cloud, &init, distance) {
                Ok(c) => return Ok(c),
                Err(e) => why = e,
            }
        }
        Err(why)
    }

    /// The older keyframe (stamp before `before_s`, with a cloud) nearest to `kf` by the
    /// optimised poses, within `loop_search_radius_m`.
    fn nearest_older(&self, kf: usize, before_s: f64) -> Option<usize> {
        let r = self.cfg.loop_search_radius_m;
        let p = self.keyframes.get(kf)?.pose.translation.vector;
        self.keyframes
            .iter()
            .enumerate()
            .take_while(|(_, k)| k.stamp_s < before_s)
            .filter(|(_, k)| k.cloud.is_some())
            .map(|(j, k)| (j, (k.pose.translation.vector - p).norm()))
            .filter(|&(_, d)| d <= r)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(j, _)| j)
    }

    /// Odometry distance from keyframe `kf` to the nearest keyframe (before or after it) held by
    /// an absolute factor: how far the graph's pose there can have drifted from the truth.
    fn travel_to_anchor_m(&self, kf: usize) -> f64 {
        let here = self.travel_m[kf];
        let before = self.anchored[..=kf]
            .iter()
            .rposition(|a| *a)
            .map(|j| here - self.travel_m[j]);
        let after = self.anchored[kf..]
            .iter()
            .position(|a| *a)
            .map(|j| self.travel_m[kf + j] - here);
        before
            .into_iter()
            .chain(after)
            .fold(f64::INFINITY, f64::min)
    }

    /// Keyframe `centre`'s cloud with those of up to `loop_submap_keyframes` keyframes on each
    /// side stamped before `before_s` (never the recent trajectory the loop would close onto),
    /// in `centre`'s frame by the graph's relative poses, thinned to `keyframe_voxel_m` with
    /// `centre`'s own points first, and its normals fitted again over the merged points: one
    /// sweep's ground rings are too far apart for a normal, the rings of several sweeps make a
    /// surface. `None` when `centre` has no cloud.
    fn submap(&mut self, centre: usize, before_s: f64) -> Option<Arc<OrientedCloud>> {
        let own = self.keyframes.get(centre)?.cloud.clone()?;
        let n = self.cfg.loop_submap_keyframes;
        if n == 0 {
            return Some(own);
        }
        // Nearest neighbours first, so where thinning has to choose, the nearer sweep's point stays.
        let members: Vec<usize> = (1..=n)
            .flat_map(|d| {
                [
                    centre.checked_sub(d),
                    Some(centre + d).filter(|j| *j < self.keyframes.len()),
                ]
            })
            .flatten()
            .filter(|&j| {
                let k = &self.keyframes[j];
                k.stamp_s < before_s && k.cloud.is_some()
            })
            .collect();
        if let Some((c, m, cloud)) = &self.submap_cache {
            if *c == centre && *m == members {
                return Some(cloud.clone());
            }
        }
        let centre_from_world = self.keyframes[centre].pose.inverse();
        let mut merged = own.points.clone();
        for &j in &members {
            let k = &self.keyframes[j];
            if let Some(c) = &k.cloud {
                let t = (centre_from_world * k.pose).cast::<f32>();
                merged.extend(c.points.iter().map(|p| {
                    let q = t * nalgebra::Point3::from(*p);
                    [q.x, q.y, q.z]
                }));
            }
        }
        let thinned = voxel_downsample(&merged, self.cfg.keyframe_voxel_m as f32);
        let cloud = Arc::new(keyframe_normals(
            thinned,
            [0.0; 3],
            self.cfg.keyframe_voxel_m,
        ));
        self.submap_cache = Some((centre, members, cloud.clone()));
        Some(cloud)
    }

    /// Verifies `from` (older) against `to` from `init` = `from<-to` and adds the loop factor.
    fn verify_with(
        &mut self,
        from: usize,
        to: usize,
        cloud: &OrientedCloud,
        init: &Isometry3<f64>,
        descriptor_distance: f64,
    ) -> Result<LoopClosure, LoopRejection> {
        let predicted = self.keyframes[from].pose.inverse() * self.keyframes[to].pose;
        let allowed_m = self.cfg.loop_min_drift_m
            + self.cfg.loop_max_drift_per_m
                * (self.travel_to_anchor_m(from) + self.travel_to_anchor_m(to));
        // Each of the ICP's two passes moves at most `loop_max_offset_m` from where it starts,
        // so a candidate further than that from the graph's place is refused without the ICP
        // (most of the descriptor's look-alikes: the verification is the costly part).
        let least_correction_m = (predicted.translation.vector - init.translation.vector).norm()
            - 2.0 * self.cfg.loop_max_offset_m;
        if least_correction_m > allowed_m {
            return Err(LoopRejection::Inconsistent {
                correction_m: least_correction_m,
                allowed_m,
            });
        }
        let before_s = self.keyframes[to].stamp_s - self.cfg.loop_exclude_recent_s;
        let Some(target) = self.submap(from, before_s) else {
            return Err(LoopRejection::NoDescriptor);
        };
        let (measured, inlier_ratio, rms_m) = verify_loop(cloud, &target, init, &self.cfg)?;
        let correction_m = (measured.translation.vector - predicted.translation.vector).norm();
        if correction_m > allowed_m {
            return Err(LoopRejection::Inconsistent {
                correction_m,
                allowed_m,
            });
        }
        self.add_loop(from, to, measured);
        Ok(LoopClosure {
            from,
            to,
            measured,
            descriptor_distance,
            inlier_ratio,
            rms_m,
        })
    }

    /// Optimises all keyframe poses.
    pub fn optimise(&mut self) -> SolveReport {
        let mut poses: Vec<Isometry3<f64>> = self.keyframes.iter().map(|k| k.pose).collect();
        let report = solve::optimise(
            &mut poses,
            &self.factors,
            &SolveOptions {
                max_iterations: self.cfg.max_iterations,
                min_relative_decrease: 1e-6,
                loop_cauchy_c: self.cfg.loop_cauchy_sigmas,
            },
        );
        for (k, p) in self.keyframes.iter_mut().zip(poses) {
            k.pose = p;
        }
        self.submap_cache = None;
        report
    }

    /// The correction `world<-slam_map` at keyframe `kf` (`pose * odom_pose^-1`).
    pub fn correction(&self, kf: usize) -> Option<Isometry3<f64>> {
        self.keyframes
            .get(kf)
            .map(|k| k.pose * k.odom_pose.inverse())
    }

    /// The correction at time `stamp_s`, interpolated between the keyframes around it (the
    /// first's before them, the last's after): what to apply to an odometry pose or a map
    /// cell made at that time.
    pub fn correction_at(&self, stamp_s: f64) -> Option<Isometry3<f64>> {
        let n = self.keyframes.len();
        if n == 0 {
            return None;
        }
        let i = self.keyframes.partition_point(|k| k.stamp_s <= stamp_s);
        if i == 0 {
            return self.correction(0);
        }
        if i == n {
            return self.correction(n - 1);
        }
        let (a, b) = (&self.keyframes[i - 1], &self.keyframes[i]);
        let (ca, cb) = (self.correction(i - 1)?, self.correction(i)?);
        let s = ((stamp_s - a.stamp_s) / (b.stamp_s - a.stamp_s).max(1e-9)).clamp(0.0, 1.0);
        Some(ca.lerp_slerp(&cb, s))
    }
}

#[cfg(test)]
mod tests;
