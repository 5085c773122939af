//! The per-scan SLAM step: prior, de-skew, reading filters, ICP against the map, map update.

use crate::adaptive::{self, Adaptive};
use crate::config::Config;
use crate::deskew::{deskew_constant, GyroTrack};
use crate::filters::{self, OrientedCloud};
use crate::icp::{self, IcpResult, IcpStatus};
use crate::map::{Map, MapUpdateStats};
use crate::se3;
use nalgebra::{Isometry3, UnitQuaternion, Vector3, Vector6};
use rand::rngs::StdRng;
use rand::SeedableRng;
use sensing::{OdomSample, Point, Scan};
use std::collections::VecDeque;

/// Why a scan could not be processed at all (ICP failures are reported in [`SlamOutput`]).
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum SlamError {
    /// The scan's time stamp is not after the previous scan's.
    #[error("scan stamp {stamp_s} s is not after the previous scan ({previous_s} s)")]
    NonMonotonicStamp {
        /// This scan.
        stamp_s: f64,
        /// The previous scan.
        previous_s: f64,
    },
    /// The scan stamp is not a finite number.
    #[error("scan stamp is not finite")]
    BadStamp,
    /// Too few points survived the reading filters to localise or map.
    #[error("only {0} points left after the reading filters")]
    TooFewPoints(usize),
}

/// Where the pose prior came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum PriorKind {
    /// First scan: the map frame is defined by it.
    First,
    /// Wheel odometry, composed with the last `map<-odom`.
    Odometry,
    /// Constant velocity from the last two poses.
    ConstantVelocity,
}

/// Per-scan diagnostics. Time spent is measured by the caller.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Diagnostics {
    /// Prior used.
    pub prior: PriorKind,
    /// How ICP ended (`None` on the first scan).
    pub status: Option<IcpStatus>,
    /// True when ICP failed and the pose is the prior.
    pub fell_back_to_prior: bool,
    /// ICP iterations.
    pub iterations: usize,
    /// Weighted RMS point-to-plane residual, metres.
    pub residual_rms_m: f64,
    /// Share of the reading explained by the map (0..1).
    pub inlier_ratio: f64,
    /// Some direction was unconstrained (the prior was kept there).
    pub degenerate: bool,
    /// Smallest / largest Hessian eigenvalue.
    pub eig_ratio: f64,
    /// Points of the filtered reading.
    pub reading_points: usize,
    /// Map points after the update.
    pub map_points: usize,
    /// The map update: the dynamic-point update on every localised scan, insertions only when
    /// `map_updated`.
    pub map_update: MapUpdateStats,
    /// True when this scan updated the map (see `map.update_min_travel_m`).
    pub map_updated: bool,
    /// True when the scan was de-skewed.
    pub deskewed: bool,
    /// True when the registration from the prior failed and a wider search (see
    /// `adaptive.recovery_attempts`) found the pose.
    pub recovered: bool,
    /// Correspondence gate used, metres (adaptive when `icp.max_match_dist_m` is `"auto"`).
    pub match_dist_m: f64,
    /// Voxel of the reading, metres (0: none).
    pub voxel_m: f64,
}

/// What SLAM reports for one scan.
#[derive(Clone, Debug, PartialEq)]
pub struct SlamOutput {
    /// Scan time, seconds.
    pub stamp_s: f64,
    /// `map<-base_link`.
    pub pose_map_base: Isometry3<f64>,
    /// `map<-lidar` (the scan's pose).
    pub pose_map_lidar: Isometry3<f64>,
    /// `map<-odom`, when wheel odometry is fed.
    pub pose_map_odom: Option<Isometry3<f64>>,
    /// The whole sweep de-skewed into the lidar frame at `stamp_s` (every return, unfiltered),
    /// when the scan had per-point times and de-skewing is on; the mapper wants this, not the
    /// smeared raw sweep.
    pub deskewed: Option<Vec<Point>>,
    /// ICP and map diagnostics.
    pub diagnostics: Diagnostics,
}

/// Scan-to-map SLAM. Feed odometry with [`Slam::push_odometry`] (optional) and scans in time
/// order with [`Slam::process`].
#[derive(Debug)]
pub struct Slam {
    cfg: Config,
    base_from_lidar: Isometry3<f64>,
    map: Map,
    rng: StdRng,
    odom: VecDeque<OdomSample>,
    /// Last two scan poses `(stamp, map<-lidar)`, newest last.
    history: VecDeque<(f64, Isometry3<f64>)>,
    map_from_odom: Isometry3<f64>,
    /// `(stamp, map<-lidar)` of the last scan that updated the map.
    last_map_update: Option<(f64, Isometry3<f64>)>,
    /// Gyroscope readings `(end of interval, rate in base_link)`, oldest first.
    gyro: VecDeque<(f64, Vector3<f64>)>,
    /// The gyroscope's bias as estimated so far, rad/s (`base_link` axes).
    gyro_bias: Vector3<f64>,
    /// Scans processed (the dynamic-point update runs on every `dynamic.every_n_scans`-th).
    scans: u64,
    /// Scan extent and match gate for the `"auto"` keys.
    adaptive: Adaptive,
}

/// Odometry older than this before the newest scan is dropped, seconds.
const ODOM_KEEP_S: f64 = 5.0;

/// Gyroscope readings further apart than this do not make a rotation prior, seconds: a dropped
/// stretch of IMU data would be read as standing still.
const GYRO_MAX_GAP_S: f64 = 0.2;

/// Share of one sweep's reading of the gyroscope's bias taken into the estimate: an average
/// over ~100 sweeps (10 s at 10 Hz).
const GYRO_BIAS_GAIN: f64 = 0.01;

/// Largest gyroscope bias the estimate may reach, rad/s (a consumer MEMS part is within a few
/// mrad/s; more is a wrong mount or a fault, not bias).
const GYRO_BIAS_MAX_RPS: f64 = 0.02;

impl Slam {
    /// A new SLAM session with an empty map.
    pub fn new(cfg: Config) -> Self {
        let base_from_lidar = se3::from_xyz_rpy(cfg.sensor.lidar_xyz_m, cfg.sensor.lidar_rpy_rad);
        // A voxel index caps neighbour searches at its cube: the widest gate the session may use.
        let cube_m = cfg
            .icp
            .max_match_dist_m
            .fixed()
            .unwrap_or(cfg.adaptive.max_match_dist_m);
        let map = Map::new(cfg.map.index, cube_m as f32);
        let rng = StdRng::seed_from_u64(cfg.filters.seed);
        Self {
            cfg,
            base_from_lidar,
            map,
            rng,
            odom: VecDeque::new(),
            history: VecDeque::new(),
            map_from_odom: Isometry3::identity(),
            last_map_update: None,
            gyro: VecDeque::new(),
            gyro_bias: Vector3::zeros(),
            scans: 0,
            adaptive: Adaptive::default(),
        }
    }

    /// Adds one gyroscope reading: the mean angular rate of `base_link` (rad/s, its own axes)
    /// over the interval ending at `t_s`. Non-finite or out-of-order readings are ignored.
    pub fn push_gyro(&mut self, t_s: f64, rate_rps: [f64; 3]) {
        let w = Vector3::from(rate_rps);
        if !t_s.is_finite()
            || !w.iter().all(|x| x.is_finite())
            || self.gyro.back().is_some_and(|(t, _)| t_s <= *t)
        {
            return;
        }
        self.gyro.push_back((t_s, w));
        while self
            .gyro
            .front()
            .is_some_and(|(t, _)| *t < t_s - ODOM_KEEP_S)
        {
            self.gyro.pop_front();
        }
    }

    /// The body's turn from `t0` to `t1` (`base(t0)<-base(t1)`), integrated over the gyroscope
    /// readings (each the mean rate since the one before); `None` unless they cover the whole
    /// span without a gap longer than `GYRO_MAX_GAP_S`.
    fn gyro_turn_base(&self, t0: f64, t1: f64) -> Option<UnitQuaternion<f64>> {
        if t1 <= t0 || self.gyro.front()?.0 > t0 || self.gyro.back()?.0 < t1 {
            return None;
        }
        let mut q = UnitQuaternion::identity();
        let i = self
            .gyro
            .partition_point(|(t, _)| *t <= t0)
            .saturating_sub(1);
        let mut prev = self.gyro[i].0;
        for (t, w) in self.gyro.range(i + 1..) {
            if t - prev > GYRO_MAX_GAP_S {
                return None;
            }
            let span = t.min(t1) - prev.max(t0);
            if span > 0.0 {
                q *= UnitQuaternion::from_scaled_axis((w - self.gyro_bias) * span);
            }
            if *t >= t1 {
                break;
            }
            prev = *t;
        }
        Some(q)
    }

    /// Moves the gyroscope's bias estimate towards what the registered turn from `last` (at
    /// `t_last`) to `now` (at `t_s`, both `map<-lidar`) says it is.
    ///
    /// Each pair is a noisy reading of the bias (registration's own rotation error over one
    /// sweep interval is of its order), so the estimate is a slow average: `GYRO_BIAS_GAIN` per
    /// sweep, bounded by `GYRO_BIAS_MAX_RPS`.
    fn learn_gyro_bias(
        &mut self,
        t_last: f64,
        last: &Isometry3<f64>,
        t_s: f64,
        now: &Isometry3<f64>,
    ) {
        let dt = t_s - t_last;
        if !(dt > 1e-3 && dt <= GYRO_MAX_GAP_S * 5.0) {
            return;
        }
        let Some(gyro) = self.gyro_turn_base(t_last, t_s) else {
            return;
        };
        let to_base = self.base_from_lidar.inverse();
        let registered = ((last * to_base).inverse() * (now * to_base)).rotation;
        let rate_error = (registered.inverse() * gyro).scaled_axis() / dt;
        self.gyro_bias += rate_error * GYRO_BIAS_GAIN;
        self.gyro_bias = self
            .gyro_bias
            .map(|b| b.clamp(-GYRO_BIAS_MAX_RPS, GYRO_BIAS_MAX_RPS));
    }

    /// The gyroscope's bias as estimated from registration so far, rad/s (`base_link` axes).
    pub fn gyro_bias_rps(&self) -> [f64; 3] {
        self.gyro_bias.into()
    }

    /// True when the scan at `pose` / `t_s` should update the map: the first one, then once the
    /// sensor moved or turned enough, or enough time passed (dynamic points keep being cleared
    /// while the robot stands).
    fn wants_map_update(&self, t_s: f64, pose: &Isometry3<f64>) -> bool {
        let c = &self.cfg.map;
        let Some((t0, p0)) = &self.last_map_update else {
            return true;
        };
        let d = p0.inverse() * pose;
        se3::translation_norm(&d) >= c.update_min_travel_m
            || se3::rotation_angle(&d) >= c.update_min_rotation_rad
            || t_s - t0 >= c.update_max_interval_s
    }

    /// The configuration in use.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Map points within `map.output_radius_m` of the robot's last scanned pose (`base_link`),
    /// map frame, for a traversability mapper fed map clouds; empty before the first scan or
    /// with a radius of 0. Built on request: the agent maps from the de-skewed sweep, and
    /// building it with every scan cost ~0.3 ms.
    pub fn map_cloud(&self) -> Vec<Point> {
        let r = self.cfg.map.output_radius_m;
        match self.history.back() {
            Some((_, map_lidar)) if r > 0.0 => {
                let base = map_lidar * self.base_from_lidar.inverse();
                self.map.cloud_around(&base.translation.vector, r)
            }
            _ => Vec::new(),
        }
    }

    /// The map.
    pub fn map(&self) -> &Map {
        &self.map
    }

    /// Adds one wheel-odometry sample (time order; out-of-order samples are ignored).
    pub fn push_odometry(&mut self, s: OdomSample) {
        if !s.t_s.is_finite() || self.odom.back().is_some_and(|b| s.t_s <= b.t_s) {
            return;
        }
        self.odom.push_back(s);
    }

    /// `odom<-base_link` at time `t_s`, interpolated (or extrapolated with the last speeds).
    fn odom_base_at(&self, t_s: f64) -> Option<Isometry3<f64>> {
        let last = self.odom.back()?;
        let pose = if t_s >= last.t_s {
            last.pose_odom
                .integrate(last.v_mps, last.omega_rps, t_s - last.t_s)
        } else {
            let i = self.odom.partition_point(|s| s.t_s <= t_s);
            if i == 0 {
                let f = self.odom.front()?;
                f.pose_odom
            } else {
                let (a, b) = (&self.odom[i - 1], &self.odom[i]);
                let u = (t_s - a.t_s) / (b.t_s - a.t_s);
                let rel = a.pose_odom.inverse().compose(&b.pose_odom);
                let step = common::geom::Pose2::new(rel.x_m * u, rel.y_m * u, rel.yaw_rad * u);
                a.pose_odom.compose(&step)
            }
        };
        Some(pose.to_isometry3(0.0))
    }

    /// Prior `map<-lidar` at `t_s` and where it came from: the motion model's position and
    /// heading, with the roll and pitch the gyroscope turned the last pose to since the last
    /// scan when its readings cover that span.
    ///
    /// Wheel odometry knows nothing of pitch and roll, and a constant velocity nothing of a
    /// jolt: a robot whose front wheels climb a 5 cm curb pitches several degrees between two
    /// sweeps. The heading stays the motion model's: a gyroscope's bias turns every prior the
    /// same way, and what registration leaves of that adds up to a heading drift.
    fn prior(&self, t_s: f64) -> (Isometry3<f64>, PriorKind) {
        let (prior, kind) = self.motion_prior(t_s);
        let tilted = self.history.back().and_then(|(t_last, last)| {
            let turn = self.gyro_turn_base(*t_last, t_s)?;
            let base_last = last * self.base_from_lidar.inverse();
            let base_prior = prior * self.base_from_lidar.inverse();
            let (roll, pitch, _) = (base_last.rotation * turn).euler_angles();
            let (_, _, heading) = base_prior.rotation.euler_angles();
            Some(
                Isometry3::from_parts(
                    base_prior.translation,
                    UnitQuaternion::from_euler_angles(roll, pitch, heading),
                ) * self.base_from_lidar,
            )
        });
        (tilted.unwrap_or(prior), kind)
    }

    /// Prior `map<-lidar` at `t_s` from odometry or a constant velocity, and which.
    fn motion_prior(&self, t_s: f64) -> (Isometry3<f64>, PriorKind) {
        if let Some(odom_base) = self.odom_base_at(t_s) {
            if !self.history.is_empty() {
                return (
                    self.map_from_odom * odom_base * self.base_from_lidar,
                    PriorKind::Odometry,
                );
            }
        }
        match (self.history.len(), self.history.back()) {
            (0, _) | (_, None) => (self.base_from_lidar, PriorKind::First),
            (1, Some((_, last))) => (*last, PriorKind::ConstantVelocity),
            (_, Some((t1, last))) => {
                let (t0, prev) = self.history[self.history.len() - 2];
                let ratio = if t1 > &t0 {
                    (t_s - t1) / (t1 - t0)
                } else {
                    1.0
                };
                let delta = se3::log(&(prev.inverse() * last)) * ratio;
                (last * se3::exp(&delta), PriorKind::ConstantVelocity)
            }
        }
    }

    /// Body twist of the lidar per second (from the prior motion), for de-skewing.
    fn twist_per_s(&self, prior: &Isometry3<f64>, t_s: f64) -> Option<Vector6<f64>> {
        let (t_last, last) = self.history.back()?;
        let dt = t_s - t_last;
        (dt > 1e-6).then(|| se3::log(&(last.inverse() * prior)) / dt)
    }

    /// Localises one scan against the map and updates the map.
    pub fn process(&mut self, scan: &Scan) -> Result<SlamOutput, SlamError> {
        if !scan.stamp_s.is_finite() {
            return Err(SlamError::BadStamp);
        }
        if let Some((prev, _)) = self.history.back() {
            if scan.stamp_s <= *prev {
                return Err(SlamError::NonMonotonicStamp {
                    stamp_s: scan.stamp_s,
                    previous_s: *prev,
                });
            }
        }
        self.scans += 1;
        let (prior, prior_kind) = self.prior(scan.stamp_s);

        // De-skew: express every return in the lidar frame at `stamp_s`. The translation during
        // the sweep is the prior motion's; the rotation is the gyroscope's readings through the
        // sweep when it has any newer than the stamp, the prior motion's otherwise.
        let swept = self.cfg.sensor.deskew && scan.points.iter().any(|p| p.t_s != 0.0);
        let deskewed: Option<Vec<Point>> = if swept {
            let twist = self.twist_per_s(&prior, scan.stamp_s);
            let span_s = scan
                .points
                .iter()
                .map(|p| f64::from(p.t_s))
                .fold(0.0, f64::max);
            match GyroTrack::new(
                &self.gyro,
                &self.gyro_bias,
                &self.base_from_lidar.rotation,
                scan.stamp_s,
                span_s,
            ) {
                Some(track) => {
                    let v =
                        twist.map_or_else(Vector3::zeros, |xi| xi.fixed_rows::<3>(3).into_owned());
                    Some(track.deskew(&scan.points, &v.cast::<f32>()))
                }
                None => twist.map(|xi| deskew_constant(&scan.points, &xi)),
            }
        } else {
            None
        };
        let raw: &[Point] = deskewed.as_deref().unwrap_or(&scan.points);

        let res = self.adaptive.resolve(
            raw,
            &self.cfg.filters,
            &self.cfg.icp,
            &self.cfg.map,
            &self.cfg.adaptive,
        );
        let sampled = filters::sample(raw, &self.base_from_lidar, &res.filters, &mut self.rng);
        let reading = filters::normals_and_density(sampled, [0.0; 3], &res.filters, &mut self.rng);
        if reading.len() < self.cfg.icp.min_matched_points.max(6) {
            return Err(SlamError::TooFewPoints(reading.len()));
        }

        // The second scan's prior assumes standing still (no motion is known yet): at 2 Hz the
        // sensor may be metres away, so it is registered coarse to fine.
        let unknown_motion = prior_kind == PriorKind::ConstantVelocity && self.history.len() < 2;
        let mut icp_res: Option<IcpResult> = (!self.map.is_empty()).then(|| {
            let map = &self.map;
            let reg = |init: &Isometry3<f64>, c: &crate::config::IcpConfig| {
                icp::register(&reading, map.cloud(), map, init, c)
            };
            if unknown_motion {
                adaptive::coarse_to_fine(reg, &prior, &res.icp, self.cfg.adaptive.max_match_dist_m)
            } else {
                reg(&prior, &res.icp)
            }
        });
        // A bad prediction: retry wider before falling back to the prior.
        let mut recovered = false;
        if let Some(r) = icp_res.as_mut().filter(|r| !r.status.is_ok()) {
            let map = &self.map;
            let retry = |init: &Isometry3<f64>, c: &crate::config::IcpConfig| {
                icp::register(&reading, map.cloud(), map, init, c)
            };
            if let Some(better) = adaptive::recover(retry, &prior, &res.icp, &self.cfg.adaptive) {
                *r = better;
                recovered = true;
            }
        }
        let pose_map_lidar = icp_res.as_ref().map_or(prior, |r| r.pose);
        let failed = icp_res.as_ref().is_some_and(|r| !r.status.is_ok());
        if let (false, Some(_), Some((t_last, previous))) =
            (failed, icp_res.as_ref(), self.history.back().copied())
        {
            self.adaptive
                .observe(&prior, &pose_map_lidar, &previous, &self.cfg.adaptive);
            self.learn_gyro_bias(t_last, &previous, scan.stamp_s, &pose_map_lidar);
        }

        // A failed scan must not write a misplaced copy of the world into the map.
        let map_updated = !failed && self.wants_map_update(scan.stamp_s, &pose_map_lidar);
        let map_update = if map_updated {
            self.last_map_update = Some((scan.stamp_s, pose_map_lidar));
            let reading_map: OrientedCloud = reading.transformed(&pose_map_lidar);
            self.map.update(
                &reading_map,
                raw,
                &pose_map_lidar,
                scan.stamp_s,
                &res.map,
                &self.cfg.dynamic,
            )
        } else if !failed
            && self
                .scans
                .is_multiple_of(self.cfg.dynamic.every_n_scans.max(1) as u64)
        {
            self.map.observe(raw, &pose_map_lidar, &self.cfg.dynamic)
        } else {
            MapUpdateStats::default()
        };
        let was_deskewed = deskewed.is_some();
        let pose_map_base = pose_map_lidar * self.base_from_lidar.inverse();
        let pose_map_odom = self
            .odom_base_at(scan.stamp_s)
            .map(|odom_base| pose_map_base * odom_base.inverse());
        if let Some(m) = pose_map_odom {
            self.map_from_odom = m;
        }
        self.history.push_back((scan.stamp_s, pose_map_lidar));
        while self.history.len() > 2 {
            self.history.pop_front();
        }
        while self.odom.len() > 2
            && self
                .odom
                .get(1)
                .is_some_and(|s| s.t_s < scan.stamp_s - ODOM_KEEP_S)
        {
            self.odom.pop_front();
        }
        let r = icp_res.as_ref();
        Ok(SlamOutput {
            stamp_s: scan.stamp_s,
            pose_map_base,
            pose_map_lidar,
            pose_map_odom,
            deskewed,
            diagnostics: Diagnostics {
                prior: prior_kind,
                status: r.map(|r| r.status),
                fell_back_to_prior: failed,
                iterations: r.map_or(0, |r| r.iterations),
                residual_rms_m: r.map_or(0.0, |r| r.residual_rms_m),
                inlier_ratio: r.map_or(1.0, |r| r.inlier_ratio),
                degenerate: r.is_some_and(|r| r.degenerate),
                eig_ratio: r.map_or(0.0, |r| r.eig_ratio),
                reading_points: reading.len(),
                map_points: self.map.len(),
                map_update,
                map_updated,
                deskewed: was_deskewed,
                recovered,
                match_dist_m: res.icp.match_dist_m(),
                voxel_m: res.filters.voxel_size_m.fixed().unwrap_or(0.0),
            },
        })
    }
}

/// Registers one scan pair with the reading filters of `cfg` applied to both (each in its own
/// sensor frame): returns `target<-source`, starting from `init`.
pub fn register_pair(
    source: &[Point],
    target: &[Point],
    init: &Isometry3<f64>,
    cfg: &Config,
) -> IcpResult {
    let mut rng = StdRng::seed_from_u64(cfg.filters.seed);
    let id = Isometry3::identity();
    // "auto" keys from the source scan (both are scans of one sensor); no prediction error is
    // known for a single pair, so the gate is the initial one.
    let res = Adaptive::default().resolve(source, &cfg.filters, &cfg.icp, &cfg.map, &cfg.adaptive);
    let prep = |pts: &[Point], rng: &mut StdRng| {
        let s = filters::sample(pts, &id, &res.filters, rng);
        filters::normals_and_density(s, [0.0; 3], &res.filters, rng)
    };
    let src = prep(source, &mut rng);
    let tgt = prep(target, &mut rng);
    let index = crate::index::KdIndex::build(&tgt.points);
    let first = icp::register(&src, &tgt, &index, init, &res.icp);
    if first.status.is_ok() {
        return first;
    }
    let retry =
        |i: &Isometry3<f64>, c: &crate::config::IcpConfig| icp::register(&src, &tgt, &index, i, c);
    adaptive::recover(retry, init, &res.icp, &cfg.adaptive).unwrap_or(first)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prior_turns_with_the_gyroscope_since_the_last_scan() {
        let mut s = Slam::new(Config::default());
        let blf = s.base_from_lidar;
        // The base pitching at 0.5 rad/s (a curb under the front wheels) and turning at
        // 0.3 rad/s, readings at 50 Hz.
        for k in 0..=15 {
            s.push_gyro(0.9 + 0.02 * f64::from(k), [0.0, 0.5, 0.3]);
        }
        s.push_gyro(1.12, [0.0, 5.0, 0.0]); // out of order: ignored
        s.push_gyro(1.4, [0.0, f64::NAN, 0.0]); // not finite: ignored
        assert_eq!(s.gyro.len(), 16);
        s.history.push_back((1.0, blf));
        let (prior, kind) = s.prior(1.1);
        assert_eq!(kind, PriorKind::ConstantVelocity);
        let base = prior * blf.inverse();
        // The pitch is the gyroscope's, the heading the motion model's (still).
        let (roll, pitch, yaw) = base.rotation.euler_angles();
        assert!(
            roll.abs() < 1e-3 && (pitch - 0.05).abs() < 1e-3,
            "{roll} {pitch}"
        );
        assert!(yaw.abs() < 1e-12, "{yaw}");
        assert!(base.translation.vector.norm() < 1e-9, "{base}");
        // Past the newest reading (1.2 s: the refused one at 1.4 s does not count) the turn is
        // unknown: the motion model's prior as it was.
        let (later, _) = s.prior(1.3);
        assert!((later * blf.inverse()).rotation.angle() < 1e-12);
    }

    #[test]
    fn a_gap_in_the_gyroscope_readings_makes_no_turn() {
        let mut s = Slam::new(Config::default());
        for t in [0.9, 0.92, 0.94, 1.3, 1.32] {
            s.push_gyro(t, [0.0, 0.5, 0.0]);
        }
        assert!(s.gyro_turn_base(0.95, 1.31).is_none());
        let q = s.gyro_turn_base(0.91, 0.93).unwrap();
        assert!((q.angle() - 0.01).abs() < 1e-12, "{}", q.angle());
    }

    #[test]
    fn the_gyro_bias_is_learnt_from_registered_turns() {
        let mut s = Slam::new(Config::default());
        let blf = s.base_from_lidar;
        let bias = Vector3::new(0.003, -0.002, 0.004);
        let turn = Vector3::new(0.0, 0.0, 0.2);
        let pose = |t: f64| {
            Isometry3::from_parts(
                nalgebra::Translation3::identity(),
                UnitQuaternion::from_scaled_axis(turn * t),
            ) * blf
        };
        // Turning at 0.2 rad/s; the gyroscope reads that plus its bias, at 50 Hz.
        let mut t_gyro = 0.0;
        for k in 0..1000 {
            let t = 0.1 * f64::from(k + 1);
            while t_gyro < t + 0.11 {
                t_gyro += 0.02;
                s.push_gyro(t_gyro, (turn + bias).into());
            }
            s.learn_gyro_bias(t, &pose(t), t + 0.1, &pose(t + 0.1));
        }
        let learnt = Vector3::from(s.gyro_bias_rps());
        assert!((learnt - bias).norm() < 0.1 * bias.norm(), "{learnt}");
    }
}
