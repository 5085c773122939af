//! The per-scan SLAM step: prior, de-skew, reading filters, ICP against the map, map update.

use crate::adaptive::{self, Adaptive};
use crate::config::Config;
use crate::filters::{self, OrientedCloud};
use crate::icp::{self, IcpResult, IcpStatus};
use crate::map::{Map, MapUpdateStats};
use crate::se3;
use nalgebra::{Isometry3, Vector3, Vector6};
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
    /// Scans processed (the dynamic-point update runs on every `dynamic.every_n_scans`-th).
    scans: u64,
    /// Scan extent and match gate for the `"auto"` keys.
    adaptive: Adaptive,
}

/// Odometry older than this before the newest scan is dropped, seconds.
const ODOM_KEEP_S: f64 = 5.0;

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

    /// The mean body rate over `[t0, t1]` in the lidar frame, from the readings whose
    /// intervals end inside it (and the first one after it, which covers its end); `None`
    /// without a reading newer than `t0`.
    fn gyro_rate_lidar(&self, t0: f64, t1: f64) -> Option<Vector3<f64>> {
        let i = self.gyro.partition_point(|(t, _)| *t <= t0);
        let mut sum = Vector3::zeros();
        let mut n = 0.0;
        for (t, w) in self.gyro.range(i..) {
            sum += w;
            n += 1.0;
            if *t >= t1 {
                break;
            }
        }
        (n > 0.0).then(|| self.base_from_lidar.rotation.inverse() * (sum / n))
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

    /// Prior `map<-lidar` at `t_s` and where it came from.
    fn prior(&self, t_s: f64) -> (Isometry3<f64>, PriorKind) {
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

        // De-skew: express every return in the lidar frame at `stamp_s`.
        let swept = self.cfg.sensor.deskew && scan.points.iter().any(|p| p.t_s != 0.0);
        let twist = if swept {
            // The sweep's rotation from the gyroscope when there is one: wheel odometry knows
            // nothing of pitch and roll, and a robot cresting a ramp pitches ~2 deg within one
            // sweep, which registration would otherwise split into a 1 deg error of the pose.
            let span_s = scan
                .points
                .iter()
                .map(|p| f64::from(p.t_s))
                .fold(0.0, f64::max);
            let gyro = self.gyro_rate_lidar(scan.stamp_s, scan.stamp_s + span_s);
            match (self.twist_per_s(&prior, scan.stamp_s), gyro) {
                (Some(mut xi), Some(w)) => {
                    xi.fixed_rows_mut::<3>(0).copy_from(&w);
                    Some(xi)
                }
                (None, Some(w)) => Some(Vector6::new(w.x, w.y, w.z, 0.0, 0.0, 0.0)),
                (xi, None) => xi,
            }
        } else {
            None
        };
        let deskewed: Option<Vec<Point>> = twist.map(|xi| {
            scan.points
                .iter()
                .map(|p| {
                    let q = se3::exp_apply(
                        &xi,
                        f64::from(p.t_s),
                        &Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)),
                    );
                    Point {
                        x: q.x as f32,
                        y: q.y as f32,
                        z: q.z as f32,
                        ..*p
                    }
                })
                .collect()
        });
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
        if let (false, Some(_), Some((_, previous))) =
            (failed, icp_res.as_ref(), self.history.back())
        {
            self.adaptive
                .observe(&prior, &pose_map_lidar, previous, &self.cfg.adaptive);
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
    fn the_sweep_rate_is_the_mean_gyro_reading_in_the_lidar_frame() {
        let mut cfg = Config::default();
        // A lidar turned 90 deg about z: the body's x rate is the lidar's -y rate.
        cfg.sensor.lidar_rpy_rad = [0.0, 0.0, std::f64::consts::FRAC_PI_2];
        let mut s = Slam::new(cfg);
        assert!(s.gyro_rate_lidar(0.0, 0.1).is_none());
        for (t, wx) in [
            (0.98, 9.0),
            (1.02, 0.1),
            (1.06, 0.3),
            (1.10, 0.2),
            (1.14, 9.0),
        ] {
            s.push_gyro(t, [wx, 0.0, 0.0]);
        }
        s.push_gyro(1.12, [5.0, 0.0, 0.0]); // out of order: ignored
        s.push_gyro(1.2, [f64::NAN, 0.0, 0.0]); // not finite: ignored
        let w = s.gyro_rate_lidar(1.0, 1.1).unwrap();
        assert!((w - Vector3::new(0.0, -0.2, 0.0)).norm() < 1e-9, "{w}");
        // Nothing newer than the sweep's start: no rate.
        assert!(s.gyro_rate_lidar(1.14, 1.24).is_none());
    }
}
