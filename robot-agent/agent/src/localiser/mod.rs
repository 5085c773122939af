//! The localiser: where the robot is, in which frame, and whether that may be trusted.
//!
//! In: wheel odometry, IMU specific force, GNSS sentences, LiDAR sweeps. Out: the pose of
//! `base_link` in `map` ([`PoseMap`]) at each sweep and between sweeps (odometry on top,
//! docs/algorithms.md §1), the map frame's anchoring (ENU at a datum or the first pose), and
//! whether a sweep's pose may be mapped and a teach waypoint taken from it.
//!
//! Parts: scan-to-map ICP SLAM (`slam`), its frame anchored at the first sweep ([`anchor`]),
//! pulled towards RTK fixes ([`fusion`]), tilted by gravity (`slam::gravity`) or, without an IMU,
//! by the GNSS track ([`tilt`]). Every correction of the frame is handed back as a
//! [`FrameShift`] so that what was built in the old frame (the terrain map's recent heights)
//! can follow it.

pub mod anchor;
pub mod fusion;
pub mod gnss;
pub mod graph;
pub mod tilt;

use crate::config::AgentConfig;
use anchor::Anchor;
use common::geo::LocalFrame;
use common::geom::Pose2;
use common::msg::Datum;
use gnss::{Fix, GnssConfig, GnssTracker};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use sensing::{GnssSentence, ImuSample, OdomSample, Point, Scan};

/// The robot pose at one instant, map frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseMap {
    /// `map<-base_link`.
    pub iso: Isometry3<f64>,
    /// Planar part.
    pub planar: Pose2,
}

impl PoseMap {
    /// The pose and its planar part.
    pub fn from_iso(iso: Isometry3<f64>) -> Self {
        Self {
            planar: Pose2::from_isometry3(&iso),
            iso,
        }
    }
}

/// How the map frame is anchored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// ENU at the datum: GNSS goals work, tiles line up with other robots on the datum.
    EnuAtDatum,
    /// The first pose (no RTK fix with heading at the first sweep): GNSS goals are refused.
    FirstPose,
}

/// GNSS fix quality, as the status shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FixKind {
    /// No receiver, or no fresh fix.
    #[default]
    None,
    /// Autonomous.
    Single,
    /// Differential.
    Dgps,
    /// RTK float.
    RtkFloat,
    /// RTK fixed.
    RtkFixed,
}

impl FixKind {
    /// From a GGA fix quality (0-9).
    pub fn from_gga_quality(q: u8) -> Self {
        match q {
            1 => FixKind::Single,
            2 | 3 | 9 => FixKind::Dgps,
            4 => FixKind::RtkFixed,
            5 => FixKind::RtkFloat,
            _ => FixKind::None,
        }
    }
}

/// SLAM health after the last sweep.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct SlamHealth {
    /// False when the last sweep fell back to the prior (or failed).
    pub ok: bool,
    /// Inlier ratio of the last registration, 0-1.
    pub inlier_ratio: f64,
    /// ICP iterations of the last registration.
    pub iterations: u32,
    /// Geometry degenerate in some direction.
    pub degenerate: bool,
    /// Smallest / largest eigenvalue of the last registration's Hessian (how well the geometry
    /// constrained its weakest direction).
    pub eig_ratio: f64,
    /// Sweeps that fell back to the prior or failed since start.
    pub failures: u32,
}

/// A move of the map frame's anchoring: `map <- corrected map`. Whatever was placed in the map
/// frame recently must move by it too (the terrain map's recent heights follow it).
pub type FrameShift = Isometry3<f64>;

/// One sweep, localised.
#[derive(Clone, Debug)]
pub struct Localised {
    /// `map<-base_link` at the sweep's stamp.
    pub pose: PoseMap,
    /// `map<-lidar` at the sweep's stamp.
    pub pose_map_lidar: Isometry3<f64>,
    /// The sweep de-skewed into the lidar frame at its stamp, when SLAM made one.
    pub deskewed: Option<Vec<Point>>,
    /// Whether the pose may be mapped (and taught from): it passed the trust gates.
    pub trusted: bool,
    /// How far the pose landed from where odometry carried the previous one, metres.
    pub jump_m: f64,
    /// SLAM fell back to its prior for this sweep.
    pub fell_back: bool,
    /// Frame corrections made while localising this sweep (apply before mapping it).
    pub shifts: Vec<FrameShift>,
    /// `slam<-base_link` at the sweep's stamp: SLAM's own pose, which the pose graph's
    /// corrections apply to ([`Localiser::graph_map_from_slam_at`]).
    pub slam_from_base: Isometry3<f64>,
    /// The pose graph was optimised at this sweep: poses of the past may have moved.
    pub graph_optimised: bool,
}

/// Why a sweep could not be localised.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LocaliseError {
    /// SLAM refused or failed the sweep.
    #[error("SLAM: {0}")]
    Slam(#[from] slam::SlamError),
}

/// What a GNSS sentence did.
#[derive(Clone, Debug, Default)]
pub struct GnssUpdate {
    /// The frame correction it caused (an RTK fixed fix), if any.
    pub shift: Option<FrameShift>,
    /// A fresh fix arrived with this sentence.
    pub new_fix: Option<Fix>,
}

/// The accelerometer's tilt counts as live this long after its last correction (the GNSS track
/// fit then leaves the tilt alone), seconds.
const GRAVITY_FRESH_S: f64 = 5.0;

/// Where the robot is. See the module docs.
pub struct Localiser {
    gnss_cfg: GnssConfig,
    datum: Option<Datum>,
    antenna_xyz_m: [f64; 3],
    base_from_lidar: Isometry3<f64>,
    gravity_enabled: bool,
    slam: slam::Slam,
    gnss: GnssTracker,
    tilt: tilt::TiltEstimator,
    gravity: slam::gravity::GravityTilt,
    /// When the accelerometer last corrected the tilt (it then supersedes the GNSS track fit).
    gravity_t_s: f64,
    /// Set at the first sweep.
    anchor: Option<Anchor>,
    /// Pose at the last SLAM update.
    at_scan: Option<PoseMap>,
    /// `map<-odom` from the last SLAM update.
    map_from_odom: Option<Isometry3<f64>>,
    last_odom: Option<OdomSample>,
    health: SlamHealth,
    /// When the last RTK fixed fix came and how far (horizontally) the pose was from it, metres.
    gnss_residual: Option<(f64, f64)>,
    /// Whether the last sweep's pose passed the trust gates (the pose until the next sweep is
    /// built on it, so no teach waypoint is taken from it either).
    scan_pose_trusted: bool,
    gnss_rejected: u32,
    imu_rejected: u64,
    scans: u32,
    /// The pose graph, when `[graph] enabled` in slam.toml.
    graph: Option<graph::GraphLocaliser>,
}

impl Localiser {
    /// A localiser with no pose yet.
    pub fn new(cfg: &AgentConfig) -> Self {
        let s = &cfg.slam.sensor;
        let [x, y, z] = s.lidar_xyz_m;
        let [r, p, yw] = s.lidar_rpy_rad;
        Self {
            gnss_cfg: cfg.gnss.clone(),
            datum: cfg.datum,
            antenna_xyz_m: cfg.profile.gnss.primary_xyz_m,
            base_from_lidar: Isometry3::from_parts(
                Translation3::new(x, y, z),
                UnitQuaternion::from_euler_angles(r, p, yw),
            ),
            gravity_enabled: cfg.slam.gravity.enabled,
            slam: slam::Slam::new(cfg.slam.clone()),
            gnss: GnssTracker::new(cfg.gnss.clone()),
            tilt: tilt::TiltEstimator::new(cfg.gnss.tilt.clone()),
            gravity: slam::gravity::GravityTilt::new(cfg.slam.gravity.clone()),
            gravity_t_s: f64::NEG_INFINITY,
            anchor: None,
            at_scan: None,
            map_from_odom: None,
            last_odom: None,
            health: SlamHealth {
                ok: true,
                ..SlamHealth::default()
            },
            gnss_residual: None,
            scan_pose_trusted: true,
            gnss_rejected: 0,
            imu_rejected: 0,
            scans: 0,
            graph: graph::GraphLocaliser::new(&cfg.slam.graph),
        }
    }

    /// Feeds one wheel-odometry sample.
    pub fn on_odom(&mut self, o: OdomSample) {
        self.slam.push_odometry(o);
        self.last_odom = Some(o);
    }

    /// The newest odometry sample.
    pub fn last_odom(&self) -> Option<&OdomSample> {
        self.last_odom.as_ref()
    }

    /// Feeds one IMU sample, kept with the attitude estimated at that moment (identity before
    /// the first sweep: the body frame, which the anchor then turns into the map frame). `Err`:
    /// refused (non-finite or out of order), counted.
    pub fn on_imu(&mut self, s: &ImuSample) -> Result<(), String> {
        if let Some(w) = s.gyro_rps {
            // The sweep's rotation for de-skewing (pitch and roll that odometry cannot see).
            self.slam.push_gyro(s.t_s, w);
        }
        if !self.gravity_enabled {
            return Ok(());
        }
        let att = self
            .pose_now()
            .map_or_else(UnitQuaternion::identity, |p| p.iso.rotation);
        let (v, w) = self
            .last_odom
            .map_or((0.0, 0.0), |o| (o.v_mps, o.omega_rps));
        if self
            .gravity
            .push(s.t_s, &Vector3::from(s.accel_mps2), &att, v, w)
        {
            Ok(())
        } else {
            self.imu_rejected += 1;
            Err(format!(
                "IMU: sample at {:.3} s refused (non-finite or out of order)",
                s.t_s
            ))
        }
    }

    /// Feeds one NMEA sentence; a bad one is an `Err` (counted by the tracker), never fatal.
    pub fn on_gnss(&mut self, s: &GnssSentence) -> Result<GnssUpdate, String> {
        self.gnss
            .on_sentence(s.t_s, &s.text)
            .map_err(|e| format!("GNSS: {e}"))?;
        let new_fix = self.gnss.fix(s.t_s).filter(|f| f.t_s == s.t_s);
        Ok(GnssUpdate {
            shift: self.fuse_gnss(s.t_s),
            new_fix,
        })
    }

    /// Feeds one fix a driver decoded (`NavSatFix`, gpsd), as a GGA sentence would be.
    pub fn on_gnss_fix(&mut self, f: &sensing::GnssFixSample) -> Result<GnssUpdate, String> {
        self.gnss.on_fix(f)?;
        let new_fix = self.gnss.fix(f.t_s).filter(|x| x.t_s == f.t_s);
        Ok(GnssUpdate {
            shift: self.fuse_gnss(f.t_s),
            new_fix,
        })
    }

    /// Feeds one true heading a driver decoded.
    pub fn on_gnss_heading(&mut self, h: &sensing::GnssHeadingSample) -> Result<(), String> {
        self.gnss.on_heading(h)
    }

    /// GNSS-aided localisation: each fresh RTK fixed fix pulls the frame's anchor a little
    /// towards where GNSS puts the robot ([`fusion::correction`]).
    fn fuse_gnss(&mut self, t_s: f64) -> Option<FrameShift> {
        let fix = self.gnss.fix(t_s)?;
        self.feed_graph_fix(t_s, &fix);
        // Once per fix (the sentence that brought it), RTK fixed only.
        if fix.t_s != t_s
            || fix.quality != common::geo::nmea::QUALITY_RTK_FIXED
            || self.gnss_cfg.fusion_gain <= 0.0
        {
            return None;
        }
        let est = self.pose_now()?;
        let anchor = self.anchor.as_ref()?;
        let local = anchor.local.as_ref()?;
        let c = fusion::correction(fusion::FusionInput {
            cfg: &self.gnss_cfg,
            fix_enu: local.lla_to_enu(&fix.lla),
            antenna_xyz_m: self.antenna_xyz_m,
            est: &est,
            yaw_enu_rad: self.gnss.yaw_enu_rad(t_s),
            map_from_slam: &anchor.map_from_slam,
            tilt: &mut self.tilt,
            // The accelerometer measures the tilt directly; the track fit is for robots without one.
            track_tilt: t_s - self.gravity_t_s >= GRAVITY_FRESH_S,
        });
        self.gnss_residual = Some((t_s, c.residual_m));
        let Some(delta) = c.delta else {
            self.gnss_rejected += 1;
            return None;
        };
        self.move_frame(&delta);
        Some(delta)
    }

    /// Hands a fresh RTK fixed fix to the pose graph, as base_link's position in the map.
    fn feed_graph_fix(&mut self, t_s: f64, fix: &Fix) {
        if fix.t_s != t_s || fix.quality != common::geo::nmea::QUALITY_RTK_FIXED {
            return;
        }
        let (Some(g), Some(est), Some(local)) = (
            self.graph.as_mut(),
            self.at_scan,
            self.anchor.as_ref().and_then(|a| a.local.as_ref()),
        ) else {
            return;
        };
        let [ax, ay, az] = self.antenna_xyz_m;
        let base = local.lla_to_enu(&fix.lla) - est.iso.rotation * Vector3::new(ax, ay, az);
        g.on_fix(t_s, base);
    }

    /// The pose graph's best `map<-slam` for a SLAM pose made at `t_s`, when the graph runs
    /// and has a keyframe: where a sweep mapped then belongs after its corrections.
    pub fn graph_map_from_slam_at(&self, t_s: f64) -> Option<Isometry3<f64>> {
        self.graph.as_ref()?.map_from_slam_at(t_s)
    }

    /// Whether the pose graph runs (`[graph] enabled`).
    pub fn graph_enabled(&self) -> bool {
        self.graph.is_some()
    }

    /// The pose graph's counters, when it runs.
    pub fn graph_stats(&self) -> Option<graph::GraphStats> {
        self.graph.as_ref().map(|g| g.stats())
    }

    /// The pose at the last sweep's stamp, as localised then.
    pub fn pose_at_scan(&self) -> Option<PoseMap> {
        self.at_scan
    }

    /// The pose graph, when it runs (evaluation: its keyframes against the truth).
    pub fn graph(&self) -> Option<&graph::GraphLocaliser> {
        self.graph.as_ref()
    }

    /// Moves the map frame's anchoring by `delta`: the SLAM anchor, the odometry frame, the
    /// last pose and the stored IMU samples all follow.
    fn move_frame(&mut self, delta: &Isometry3<f64>) {
        if let Some(a) = self.anchor.as_mut() {
            a.map_from_slam = delta * a.map_from_slam;
        }
        if let Some(m) = self.map_from_odom.as_mut() {
            *m = delta * *m;
        }
        if let Some(p) = self.at_scan.as_mut() {
            *p = PoseMap::from_iso(delta * p.iso);
        }
        self.gravity.rotate_frame(&delta.rotation);
    }

    /// Tilts the frame about the robot at `pose` by the accelerometer's correction, when the
    /// last window gives one.
    fn correct_tilt_from_gravity(&mut self, t_s: f64, pose: &PoseMap) -> Option<FrameShift> {
        let tilt = self.gravity.correction().ok()?;
        let p = pose.iso.translation.vector;
        let delta = Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_scaled_axis(tilt),
        ) * Isometry3::from_parts(Translation3::from(-p), UnitQuaternion::identity());
        self.move_frame(&delta);
        self.gravity_t_s = t_s;
        Some(delta)
    }

    /// Localises one sweep: anchoring at the first, SLAM, the gravity tilt, the trust gates.
    pub fn on_scan(&mut self, scan: &Scan) -> Result<Localised, LocaliseError> {
        if self.anchor.is_none() {
            let a = anchor::anchor_frame(
                &self.gnss,
                &self.gravity,
                self.datum,
                self.antenna_xyz_m,
                scan.stamp_s,
            );
            // IMU samples so far were kept in the body frame (no attitude yet).
            self.gravity.rotate_frame(&a.map_from_slam.rotation);
            self.anchor = Some(a);
        }
        let out = match self.slam.process(scan) {
            Ok(o) => o,
            Err(e) => {
                self.health.ok = false;
                self.health.failures += 1;
                return Err(e.into());
            }
        };
        self.scans += 1;
        let d = &out.diagnostics;
        self.health = SlamHealth {
            ok: !d.fell_back_to_prior,
            inlier_ratio: d.inlier_ratio,
            iterations: d.iterations as u32,
            degenerate: d.degenerate,
            eig_ratio: d.eig_ratio,
            failures: self.health.failures + u32::from(d.fell_back_to_prior),
        };
        let anchored = |a: &Option<Anchor>| {
            a.as_ref()
                .map_or_else(Isometry3::identity, |a| a.map_from_slam)
        };
        let mut map_from_slam = anchored(&self.anchor);
        let mut pose = PoseMap::from_iso(map_from_slam * out.pose_map_base);
        let jump_m = self.pose_now().map_or(0.0, |p| {
            (p.iso.translation.vector - pose.iso.translation.vector)
                .xy()
                .norm()
        });
        let mut shifts = Vec::new();
        if let Some(s) = self.correct_tilt_from_gravity(scan.stamp_s, &pose) {
            shifts.push(s);
            map_from_slam = anchored(&self.anchor);
            pose = PoseMap::from_iso(map_from_slam * out.pose_map_base);
        }
        let mut graph_optimised = false;
        if let Some(g) = self.graph.as_mut() {
            let points = out.deskewed.as_deref().unwrap_or(&scan.points);
            // The pose's tilt was set from the accelerometer lately: its up is the measurement.
            let up_base = (scan.stamp_s - self.gravity_t_s < GRAVITY_FRESH_S)
                .then(|| pose.iso.rotation.inverse() * Vector3::z());
            let step = g.on_scan(
                scan.stamp_s,
                &out.pose_map_base,
                points,
                &self.base_from_lidar,
                &map_from_slam,
                up_base,
            );
            if let Some(m) = step.map_from_slam {
                graph_optimised = true;
                // The graph's correction at this keyframe becomes the anchoring: the frame moves
                // by the difference, and what follows frame shifts follows it.
                let delta = m * map_from_slam.inverse();
                self.move_frame(&delta);
                shifts.push(delta);
                map_from_slam = anchored(&self.anchor);
                pose = PoseMap::from_iso(map_from_slam * out.pose_map_base);
            }
        }
        self.at_scan = Some(pose);
        self.map_from_odom = out.pose_map_odom.map(|m| map_from_slam * m);
        // A sweep placed with a pose SLAM has just thrown off (or GNSS is still pulling back)
        // would paint the ground it saw, misplaced, as steps against what the map holds.
        let pitch_off = self.gnss.pitch_rad(scan.stamp_s).is_some_and(|gp| {
            let (_, pitch, _) = pose.iso.rotation.euler_angles();
            common::geom::wrap_angle(pitch - gp).abs()
                > self.gnss_cfg.pose_trust_pitch_deg.to_radians()
        });
        self.scan_pose_trusted = !(jump_m > self.gnss_cfg.pose_jump_max_m
            || pitch_off
            || !self.pose_trusted(scan.stamp_s));
        Ok(Localised {
            pose,
            pose_map_lidar: map_from_slam * out.pose_map_lidar,
            deskewed: out.deskewed,
            trusted: self.scan_pose_trusted,
            jump_m,
            fell_back: d.fell_back_to_prior,
            shifts,
            slam_from_base: out.pose_map_base,
            graph_optimised,
        })
    }

    /// The pose now: `map<-base = map<-odom * odom<-base` with the newest odometry, so the
    /// controller sees the robot move between SLAM updates (docs/algorithms.md §1).
    pub fn pose_now(&self) -> Option<PoseMap> {
        if let (Some(m), Some(o)) = (self.map_from_odom, self.last_odom) {
            return Some(PoseMap::from_iso(m * o.pose_odom.to_isometry3(0.0)));
        }
        self.at_scan
    }

    /// Whether the pose agrees with the last RTK fixed fix (or there is no fresh one to ask).
    fn pose_trusted(&self, t_s: f64) -> bool {
        self.gnss_residual.is_none_or(|(t, r)| {
            t_s - t > self.gnss_cfg.fix_timeout_s || r <= self.gnss_cfg.pose_trust_residual_m
        })
    }

    /// Whether a teach waypoint may be taken from the pose now: the last sweep passed the trust
    /// gates and the pose agrees with a fresh RTK fix.
    pub fn pose_teachable(&self, t_s: f64) -> bool {
        self.pose_trusted(t_s) && self.scan_pose_trusted
    }

    /// The map frame's anchoring, once the first sweep has arrived.
    pub fn frame(&self) -> Option<(FrameKind, Option<Datum>)> {
        self.anchor
            .as_ref()
            .map(|a| (a.frame, a.local.as_ref().map(|l| l.datum())))
    }

    /// The local ENU frame at the datum, when the map is anchored by GNSS.
    pub fn local_frame(&self) -> Option<&LocalFrame> {
        self.anchor.as_ref().and_then(|a| a.local.as_ref())
    }

    /// Latitude, longitude and height of a map pose, when the map is anchored by GNSS.
    pub fn lla_of(&self, p: &PoseMap) -> Option<(f64, f64, f64)> {
        let l = self.local_frame()?;
        let t = p.iso.translation.vector;
        let d = l.enu_to_lla(&Vector3::new(t.x, t.y, t.z));
        Some((d.lat_deg, d.lon_deg, d.h_m))
    }

    /// The latest fix if fresh at `t_s`.
    pub fn fix(&self, t_s: f64) -> Option<Fix> {
        self.gnss.fix(t_s)
    }

    /// Fix quality at `t_s`.
    pub fn fix_kind(&self, t_s: f64) -> FixKind {
        self.gnss.fix_kind(t_s)
    }

    /// Whether a fresh RTK fixed fix and a heading at `t_s` would anchor the map frame in ENU
    /// at the first sweep (so a runtime can hold the first sweep until they come).
    pub fn can_anchor(&self, t_s: f64) -> bool {
        self.gnss.can_anchor(t_s)
    }

    /// True when the map was anchored by GNSS and there is no fresh fix: the robot carries on
    /// with SLAM and odometry alone.
    pub fn gnss_lost(&self, t_s: f64) -> bool {
        self.anchor
            .as_ref()
            .is_some_and(|a| a.frame == FrameKind::EnuAtDatum)
            && self.gnss.fix(t_s).is_none()
    }

    /// The GNSS configuration (goal freezing, timeouts).
    pub fn gnss_config(&self) -> &GnssConfig {
        &self.gnss_cfg
    }

    /// `base_link <- lidar`.
    pub fn base_from_lidar(&self) -> &Isometry3<f64> {
        &self.base_from_lidar
    }

    /// SLAM health after the last sweep.
    pub fn health(&self) -> &SlamHealth {
        &self.health
    }

    /// Sweeps localised.
    pub fn scans(&self) -> u32 {
        self.scans
    }

    /// IMU samples refused.
    pub fn imu_rejected(&self) -> u64 {
        self.imu_rejected
    }

    /// RTK fixes refused as outliers (beyond the fusion gate).
    pub fn gnss_rejected(&self) -> u32 {
        self.gnss_rejected
    }

    /// GNSS sentences that failed to parse.
    pub fn gnss_bad_sentences(&self) -> u32 {
        self.gnss.bad_sentences
    }

    /// The SLAM state (evaluation).
    pub fn slam(&self) -> &slam::Slam {
        &self.slam
    }
}
