//! Sensor models: VLP-16, SR4000 depth camera, wheel odometry, dual-antenna RTK GNSS.

use crate::world::{HitKind, Solid, SolidKind, World};
use common::geo::{format_avr, format_gga, Avr, Gga, LocalFrame, UtcTime};
use common::geom::Pose2;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::rngs::SmallRng;
use rand::Rng;
use rand_distr::StandardNormal;
use sensing::{GnssSentence, ImuSample, OdomSample, Point};
use serde::Deserialize;

/// VLP-16 laser elevations in firing order (laser id 0..15), degrees.
pub const VLP16_ELEVATIONS_DEG: [f64; 16] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];
/// Time between two lasers' firings in one VLP-16 firing sequence, seconds.
pub const VLP16_LASER_DT_S: f64 = 2.304e-6;

/// VLP-16 model parameters.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LidarConfig {
    /// Produce scans at all.
    pub enabled: bool,
    /// Rotation rate, Hz.
    pub rate_hz: f64,
    /// Firing columns per rotation (0.2 deg at 10 Hz = 1800).
    pub columns: usize,
    /// Maximum range, metres.
    pub max_range_m: f64,
    /// Minimum range, metres (closer returns are dropped, as the sensor does).
    pub min_range_m: f64,
    /// Range noise standard deviation, metres (+-3 cm at 2 sigma).
    pub range_noise_sigma_m: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            columns: 1800,
            max_range_m: 100.0,
            min_range_m: 0.4,
            range_noise_sigma_m: 0.015,
        }
    }
}

/// SR4000 depth-camera parameters.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthConfig {
    /// Produce frames at all.
    pub enabled: bool,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// Image width, pixels.
    pub width_px: usize,
    /// Image height, pixels.
    pub height_px: usize,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
    /// Vertical field of view, degrees.
    pub vfov_deg: f64,
    /// Maximum range, metres.
    pub max_range_m: f64,
    /// Range noise standard deviation, metres.
    pub range_noise_sigma_m: f64,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            width_px: 176,
            height_px: 144,
            hfov_deg: 69.0,
            vfov_deg: 56.0,
            max_range_m: 5.0,
            range_noise_sigma_m: 0.005,
        }
    }
}

/// Wheel-odometry error model.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdomConfig {
    /// Produce samples at all.
    pub enabled: bool,
    /// Sample rate, Hz (at most one sample per `step`).
    pub rate_hz: f64,
    /// Distance scale error (0.02 = odometry reads 2 % long).
    pub scale_error: f64,
    /// Constant yaw-rate bias, rad/s.
    pub yaw_drift_rps: f64,
    /// White noise on the measured speed, m/s.
    pub v_noise_mps: f64,
    /// White noise on the measured turn rate, rad/s.
    pub omega_noise_rps: f64,
}

impl Default for OdomConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 50.0,
            scale_error: 0.02,
            yaw_drift_rps: 0.002,
            v_noise_mps: 0.01,
            omega_noise_rps: 0.005,
        }
    }
}

/// IMU accelerometer error model (a MEMS unit of the kind ground robots carry).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuConfig {
    /// Produce samples at all.
    pub enabled: bool,
    /// Sample rate, Hz (at most one sample per simulator sub-step of 20 ms).
    pub rate_hz: f64,
    /// White noise per sample and axis, m/s^2.
    pub accel_noise_mps2: f64,
    /// Standard deviation of the constant per-axis bias drawn at start-up, m/s^2
    /// (0.01 m/s^2 reads as a 0.06 deg tilt).
    pub accel_bias_mps2: f64,
    /// Gyroscope white noise per sample and axis, rad/s.
    pub gyro_noise_rps: f64,
    /// Standard deviation of the gyroscope's constant per-axis bias, rad/s (0.002: 0.1 deg/s,
    /// an uncalibrated MEMS part after warm-up).
    pub gyro_bias_rps: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 50.0,
            accel_noise_mps2: 0.02,
            accel_bias_mps2: 0.01,
            gyro_noise_rps: 0.002,
            gyro_bias_rps: 0.002,
        }
    }
}

/// GNSS receiver model.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssConfig {
    /// Produce sentences at all.
    pub enabled: bool,
    /// Epoch rate, Hz.
    pub rate_hz: f64,
    /// UTC time of day at simulation time 0, seconds.
    pub utc_start_s: f64,
    /// Geoid separation written into GGA, metres (GGA altitude = ellipsoidal height - this).
    pub geoid_separation_m: f64,
    /// RTK fixed: horizontal noise standard deviation, metres.
    pub rtk_sigma_m: f64,
    /// RTK float: noise standard deviation, metres.
    pub float_sigma_m: f64,
    /// Single point: noise standard deviation, metres.
    pub single_sigma_m: f64,
    /// Heading noise standard deviation with RTK fixed, degrees.
    pub heading_sigma_deg: f64,
    /// RTK is lost within this distance of a tall structure (wall or box >= 2 m), metres.
    pub rtk_loss_distance_m: f64,
    /// No fix at all within this distance, metres.
    pub no_fix_distance_m: f64,
    /// After RTK loss, seconds of RTK float before fixed again.
    pub float_after_loss_s: f64,
    /// Seconds of RTK float at start.
    pub initial_float_s: f64,
}

impl Default for GnssConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            utc_start_s: 12.0 * 3600.0,
            geoid_separation_m: 0.0,
            rtk_sigma_m: 0.01,
            float_sigma_m: 0.15,
            single_sigma_m: 1.5,
            heading_sigma_deg: 0.2,
            rtk_loss_distance_m: 4.0,
            no_fix_distance_m: 1.5,
            float_after_loss_s: 10.0,
            initial_float_s: 0.0,
        }
    }
}

fn intensity(kind: HitKind, world: &World) -> f32 {
    match kind {
        HitKind::Ground { grass: true } => 15.0,
        HitKind::Ground { grass: false } => 35.0,
        HitKind::Walker(_) => 45.0,
        HitKind::Solid(i) => match world.solids()[i].kind {
            SolidKind::Wall => 80.0,
            SolidKind::Pole => 120.0,
            SolidKind::Trunk => 55.0,
            SolidKind::Canopy => 25.0,
            SolidKind::Box => 70.0,
            SolidKind::Car => 150.0,
        },
    }
}

/// Candidate solids per map-frame azimuth bucket, rebuilt for each short chunk of a sweep.
struct Buckets {
    n: usize,
    lists: Vec<Vec<u32>>,
    walker_lists: Vec<Vec<u32>>,
    all: Vec<u32>,
    all_walkers: Vec<u32>,
}

impl Buckets {
    fn new(n: usize) -> Self {
        Self {
            n,
            lists: vec![Vec::new(); n],
            walker_lists: vec![Vec::new(); n],
            all: Vec::new(),
            all_walkers: Vec::new(),
        }
    }

    fn fill(
        &mut self,
        o: &Point3<f64>,
        solids: &[Solid],
        walkers: &[Solid],
        max_range_m: f64,
        pad_m: f64,
    ) {
        for l in &mut self.lists {
            l.clear();
        }
        for l in &mut self.walker_lists {
            l.clear();
        }
        self.all.clear();
        self.all_walkers.clear();
        let bw = std::f64::consts::TAU / self.n as f64;
        for (is_walker, set) in [(false, solids), (true, walkers)] {
            for (i, s) in set.iter().enumerate() {
                let (cx, cy, r) = s.bounds();
                let r = r + pad_m;
                let d = (cx - o.x).hypot(cy - o.y);
                if d - r > max_range_m {
                    continue;
                }
                if d <= r {
                    if is_walker {
                        &mut self.all_walkers
                    } else {
                        &mut self.all
                    }
                    .push(i as u32);
                    continue;
                }
                let a = (cy - o.y).atan2(cx - o.x) + std::f64::consts::PI;
                let half = (r / d).asin();
                let b0 = ((a - half) / bw).floor() as i64 - 1;
                let b1 = ((a + half) / bw).floor() as i64 + 1;
                for b in b0..=b1 {
                    let k = b.rem_euclid(self.n as i64) as usize;
                    if is_walker {
                        &mut self.walker_lists[k]
                    } else {
                        &mut self.lists[k]
                    }
                    .push(i as u32);
                }
            }
        }
    }

    fn bucket(&self, d: &Vector3<f64>) -> usize {
        let a = d.y.atan2(d.x) + std::f64::consts::PI;
        ((a / std::f64::consts::TAU * self.n as f64) as usize).min(self.n - 1)
    }
}

/// The VLP-16 sweep state.
pub(crate) struct Lidar {
    cfg: LidarConfig,
    extrinsic: Isometry3<f64>,
    /// Per column: (cos az, sin az) in the sensor frame (clockwise rotation).
    az: Vec<(f64, f64)>,
    /// Per laser id: (cos el, sin el, ring).
    el: Vec<(f64, f64, u16)>,
    rev_start_s: f64,
    next_col: usize,
    points: Vec<Point>,
    buckets: Buckets,
    scratch_ids: Vec<u32>,
    scratch_walkers: Vec<u32>,
}

impl Lidar {
    pub(crate) fn new(cfg: &LidarConfig, extrinsic: Isometry3<f64>) -> Self {
        let n = cfg.columns.max(1);
        let az = (0..n)
            .map(|j| {
                let a = -std::f64::consts::TAU * j as f64 / n as f64;
                (a.cos(), a.sin())
            })
            .collect();
        let mut order: Vec<usize> = (0..16).collect();
        order.sort_by(|&a, &b| VLP16_ELEVATIONS_DEG[a].total_cmp(&VLP16_ELEVATIONS_DEG[b]));
        let mut ring = [0u16; 16];
        for (r, &id) in order.iter().enumerate() {
            ring[id] = r as u16;
        }
        let el = VLP16_ELEVATIONS_DEG
            .iter()
            .enumerate()
            .map(|(id, e)| (e.to_radians().cos(), e.to_radians().sin(), ring[id]))
            .collect();
        Self {
            cfg: cfg.clone(),
            extrinsic,
            az,
            el,
            rev_start_s: 0.0,
            next_col: 0,
            points: Vec::with_capacity(n * 16),
            buckets: Buckets::new(720),
            scratch_ids: Vec::new(),
            scratch_walkers: Vec::new(),
        }
    }

    fn col_dt(&self) -> f64 {
        1.0 / (self.cfg.rate_hz * self.az.len() as f64)
    }

    /// Casts the columns whose firing time lies in `[t0, t1)`, the base moving from `base0` to
    /// `base1`; returns the scan completed in this interval, if any.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn sweep(
        &mut self,
        world: &World,
        walkers: &[Solid],
        t0: f64,
        t1: f64,
        base0: &Isometry3<f64>,
        base1: &Isometry3<f64>,
        rng: &mut SmallRng,
    ) -> Option<sensing::Scan> {
        let mut done = None;
        let cdt = self.col_dt();
        let s0 = base0 * self.extrinsic;
        let s1 = base1 * self.extrinsic;
        let o_mid = Point3::from((s0.translation.vector + s1.translation.vector) * 0.5);
        // Pad bounding circles by the sensor's motion in the chunk plus a walker's (1.3 m/s x 20 ms).
        let pad = (s1.translation.vector - s0.translation.vector).norm() + 0.1;
        self.buckets
            .fill(&o_mid, world.solids(), walkers, self.cfg.max_range_m, pad);
        let span = (t1 - t0).max(1e-12);
        loop {
            let tc = self.rev_start_s + self.next_col as f64 * cdt;
            if tc >= t1 {
                break;
            }
            let f = ((tc - t0) / span).clamp(0.0, 1.0);
            let pose = s0.lerp_slerp(&s1, f);
            let o = Point3::from(pose.translation.vector);
            let rot = pose.rotation.to_rotation_matrix();
            let up_s = rot.inverse() * Vector3::z();
            let (ca, sa) = self.az[self.next_col];
            for (id, &(ce, se, ring)) in self.el.iter().enumerate() {
                let ds = Vector3::new(ce * ca, ce * sa, se);
                let dm = rot * ds;
                let b = self.buckets.bucket(&dm);
                self.scratch_ids.clear();
                self.scratch_ids.extend_from_slice(&self.buckets.lists[b]);
                self.scratch_ids.extend_from_slice(&self.buckets.all);
                self.scratch_walkers.clear();
                self.scratch_walkers
                    .extend_from_slice(&self.buckets.walker_lists[b]);
                self.scratch_walkers
                    .extend_from_slice(&self.buckets.all_walkers);
                let Some(hit) = world.raycast_candidates(
                    &o,
                    &dm,
                    self.cfg.max_range_m,
                    &self.scratch_ids,
                    walkers,
                    &self.scratch_walkers,
                ) else {
                    continue;
                };
                let n: f64 = rng.sample(StandardNormal);
                let r = hit.range_m + n * self.cfg.range_noise_sigma_m;
                if r < self.cfg.min_range_m || r > self.cfg.max_range_m {
                    continue;
                }
                let mut p = ds * r;
                if let HitKind::Ground { grass: true } = hit.kind {
                    p += up_s * (rng.random::<f64>() * world.grass_amplitude_m);
                }
                self.points.push(Point {
                    x: p.x as f32,
                    y: p.y as f32,
                    z: p.z as f32,
                    intensity: intensity(hit.kind, world),
                    ring,
                    t_s: (tc - self.rev_start_s + id as f64 * VLP16_LASER_DT_S) as f32,
                });
            }
            self.next_col += 1;
            if self.next_col == self.az.len() {
                done = Some(sensing::Scan {
                    stamp_s: self.rev_start_s,
                    points: std::mem::take(&mut self.points),
                });
                self.points.reserve(self.az.len() * 16);
                self.next_col = 0;
                self.rev_start_s += 1.0 / self.cfg.rate_hz;
            }
        }
        done
    }
}

/// Renders one depth-camera frame at a camera pose (`map <- camera`), in the camera frame.
pub(crate) fn depth_frame(
    cfg: &DepthConfig,
    world: &World,
    walkers: &[Solid],
    cam: &Isometry3<f64>,
    t_s: f64,
    rng: &mut SmallRng,
) -> sensing::Scan {
    let o = Point3::from(cam.translation.vector);
    let rot = cam.rotation.to_rotation_matrix();
    let near = |s: &Solid| {
        let (cx, cy, r) = s.bounds();
        (cx - o.x).hypot(cy - o.y) <= r + cfg.max_range_m
    };
    let ids: Vec<u32> = (0..world.solids().len() as u32)
        .filter(|&i| near(&world.solids()[i as usize]))
        .collect();
    let wids: Vec<u32> = (0..walkers.len() as u32)
        .filter(|&i| near(&walkers[i as usize]))
        .collect();
    let fx = 0.5 * cfg.width_px as f64 / (0.5 * cfg.hfov_deg.to_radians()).tan();
    let fy = 0.5 * cfg.height_px as f64 / (0.5 * cfg.vfov_deg.to_radians()).tan();
    let (cu, cv) = (0.5 * cfg.width_px as f64, 0.5 * cfg.height_px as f64);
    let mut points = Vec::with_capacity(cfg.width_px * cfg.height_px);
    for v in 0..cfg.height_px {
        for u in 0..cfg.width_px {
            let ds = Vector3::new(
                1.0,
                -(u as f64 + 0.5 - cu) / fx,
                -(v as f64 + 0.5 - cv) / fy,
            )
            .normalize();
            let dm = rot * ds;
            let Some(hit) =
                world.raycast_candidates(&o, &dm, cfg.max_range_m, &ids, walkers, &wids)
            else {
                continue;
            };
            let n: f64 = rng.sample(StandardNormal);
            let r = hit.range_m + n * cfg.range_noise_sigma_m;
            if r <= 0.0 || r > cfg.max_range_m {
                continue;
            }
            let p = ds * r;
            points.push(Point {
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                intensity: intensity(hit.kind, world),
                ring: v as u16,
                t_s: 0.0,
            });
        }
    }
    sensing::Scan {
        stamp_s: t_s,
        points,
    }
}

/// The IMU: the accelerometer reads the true specific force of `base_link` (from the plant's
/// motion, bumps included), the gyroscope its true angular rate, each averaged over the sample
/// interval, plus bias and noise.
pub(crate) struct Imu {
    cfg: ImuConfig,
    bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    /// The gyroscope's own noise stream, so the accelerometer's readings stay what they were
    /// before the simulator had a gyroscope.
    gyro_rng: SmallRng,
    /// World velocity over the previous sub-step, for the acceleration of the next.
    v_prev: Option<Vector3<f64>>,
    sum: Vector3<f64>,
    sum_rate: Vector3<f64>,
    sum_t_s: f64,
    next_t_s: f64,
}

impl Imu {
    pub(crate) fn new(cfg: &ImuConfig, rng: &mut SmallRng, mut gyro_rng: SmallRng) -> Self {
        let mut b = || rng.sample::<f64, _>(StandardNormal) * cfg.accel_bias_mps2;
        let bias = Vector3::new(b(), b(), b());
        let mut g = || gyro_rng.sample::<f64, _>(StandardNormal) * cfg.gyro_bias_rps;
        let gyro_bias = Vector3::new(g(), g(), g());
        Self {
            cfg: cfg.clone(),
            bias,
            gyro_bias,
            gyro_rng,
            v_prev: None,
            sum: Vector3::zeros(),
            sum_rate: Vector3::zeros(),
            sum_t_s: 0.0,
            next_t_s: 1.0 / cfg.rate_hz.max(1e-3),
        }
    }

    /// One plant sub-step from `base0` to `base1` (`map<-base_link`) over `dt_s`, ending at `t_end_s`.
    pub(crate) fn step(
        &mut self,
        t_end_s: f64,
        dt_s: f64,
        base0: &Isometry3<f64>,
        base1: &Isometry3<f64>,
        rng: &mut SmallRng,
    ) -> Option<ImuSample> {
        let v = (base1.translation.vector - base0.translation.vector) / dt_s;
        let a = self.v_prev.map_or(Vector3::zeros(), |vp| (v - vp) / dt_s);
        self.v_prev = Some(v);
        let f_world = a + Vector3::new(0.0, 0.0, GRAVITY_MPS2);
        let rot = base0.rotation.slerp(&base1.rotation, 0.5);
        self.sum += (rot.inverse() * f_world) * dt_s;
        // The body rate over the sub-step: the rotation from base0 to base1, in base_link.
        self.sum_rate += (base0.rotation.inverse() * base1.rotation).scaled_axis();
        self.sum_t_s += dt_s;
        if t_end_s + 1e-9 < self.next_t_s {
            return None;
        }
        self.next_t_s += 1.0 / self.cfg.rate_hz;
        if self.next_t_s < t_end_s {
            self.next_t_s = t_end_s + 1.0 / self.cfg.rate_hz;
        }
        let mean = self.sum / self.sum_t_s;
        let rate = self.sum_rate / self.sum_t_s;
        self.sum = Vector3::zeros();
        self.sum_rate = Vector3::zeros();
        self.sum_t_s = 0.0;
        let mut n = || rng.sample::<f64, _>(StandardNormal) * self.cfg.accel_noise_mps2;
        let f = mean + self.bias + Vector3::new(n(), n(), n());
        let (gr, sd) = (&mut self.gyro_rng, self.cfg.gyro_noise_rps);
        let mut gn = || gr.sample::<f64, _>(StandardNormal) * sd;
        let w = rate + self.gyro_bias + Vector3::new(gn(), gn(), gn());
        Some(ImuSample {
            t_s: t_end_s,
            accel_mps2: [f.x, f.y, f.z],
            gyro_rps: Some([w.x, w.y, w.z]),
        })
    }
}

/// Standard gravity, m/s^2.
const GRAVITY_MPS2: f64 = 9.806_65;

/// Wheel odometry: integrates the measured (biased, noisy) speed and turn rate.
pub(crate) struct Odometry {
    cfg: OdomConfig,
    pose: Pose2,
    next_t_s: f64,
    v_meas: f64,
    w_meas: f64,
}

impl Odometry {
    pub(crate) fn new(cfg: &OdomConfig) -> Self {
        Self {
            cfg: cfg.clone(),
            pose: Pose2::default(),
            next_t_s: 0.0,
            v_meas: 0.0,
            w_meas: 0.0,
        }
    }

    /// Integrates one plant step with the true speeds; emits a sample when one is due.
    pub(crate) fn step(
        &mut self,
        t_end_s: f64,
        dt_s: f64,
        v_true: f64,
        w_true: f64,
        rng: &mut SmallRng,
    ) -> Option<OdomSample> {
        let n1: f64 = rng.sample(StandardNormal);
        let n2: f64 = rng.sample(StandardNormal);
        let moving = v_true.abs() > 1e-6 || w_true.abs() > 1e-6;
        // A robot standing still reads zero: encoders do not drift, the bias is a slip effect.
        let (v, w) = if moving {
            (
                v_true * (1.0 + self.cfg.scale_error) + n1 * self.cfg.v_noise_mps,
                w_true * (1.0 + self.cfg.scale_error)
                    + self.cfg.yaw_drift_rps
                    + n2 * self.cfg.omega_noise_rps,
            )
        } else {
            (0.0, 0.0)
        };
        self.pose = self.pose.integrate(v, w, dt_s);
        self.v_meas = v;
        self.w_meas = w;
        if t_end_s + 1e-9 >= self.next_t_s {
            self.next_t_s += 1.0 / self.cfg.rate_hz;
            if self.next_t_s < t_end_s {
                self.next_t_s = t_end_s + 1.0 / self.cfg.rate_hz;
            }
            return Some(OdomSample {
                t_s: t_end_s,
                pose_odom: self.pose,
                v_mps: self.v_meas,
                omega_rps: self.w_meas,
            });
        }
        None
    }
}

/// RTK state of the simulated receiver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GnssFix {
    /// No position.
    None,
    /// Autonomous single-point fix (GGA quality 1).
    Single,
    /// RTK float (GGA 5).
    Float,
    /// RTK fixed (GGA 4).
    Fixed,
}

impl GnssFix {
    /// Quality order: None < Single < Float < Fixed.
    fn rank(self) -> u8 {
        match self {
            GnssFix::None => 0,
            GnssFix::Single => 1,
            GnssFix::Float => 2,
            GnssFix::Fixed => 3,
        }
    }
}

/// Dual-antenna GNSS receiver emitting GGA + `$PTNL,AVR`.
pub(crate) struct Gnss {
    cfg: GnssConfig,
    frame: LocalFrame,
    primary: Vector3<f64>,
    secondary: Vector3<f64>,
    next_t_s: f64,
    bias: Vector3<f64>,
    last_loss_t_s: f64,
    pub(crate) fix: GnssFix,
    /// Scenario areas without RTK: polygon (map frame) and the best fix inside.
    denied: Vec<(Vec<(f64, f64)>, GnssFix)>,
}

impl Gnss {
    pub(crate) fn new(
        cfg: &GnssConfig,
        datum: common::msg::Datum,
        primary: [f64; 3],
        secondary: [f64; 3],
    ) -> Self {
        Self {
            cfg: cfg.clone(),
            frame: LocalFrame::new(datum),
            primary: Vector3::from(primary),
            secondary: Vector3::from(secondary),
            next_t_s: 0.0,
            bias: Vector3::zeros(),
            last_loss_t_s: cfg.initial_float_s - cfg.float_after_loss_s,
            fix: GnssFix::Fixed,
            denied: Vec::new(),
        }
    }

    /// Adds the scenario's `gnss_denied` areas: inside one the fix is at best its `fix`.
    pub(crate) fn with_denied_areas(mut self, areas: &[crate::scenario::GnssDeniedSpec]) -> Self {
        self.denied = areas
            .iter()
            .map(|a| {
                let fix = match a.fix {
                    crate::scenario::DeniedFix::None => GnssFix::None,
                    crate::scenario::DeniedFix::Single => GnssFix::Single,
                };
                (a.polygon(), fix)
            })
            .collect();
        self
    }

    /// The best fix the denied areas allow at (x, y) (`Fixed` outside all of them).
    fn denied_cap(&self, x: f64, y: f64) -> GnssFix {
        let mut cap = GnssFix::Fixed;
        for (poly, fix) in &self.denied {
            if common::zone::contains(poly, (x, y)) && fix.rank() < cap.rank() {
                cap = *fix;
            }
        }
        cap
    }

    /// Distance from (x, y) to the nearest structure tall enough to shade the sky.
    fn sky_block_distance(world: &World, x: f64, y: f64) -> f64 {
        let mut best = f64::INFINITY;
        for s in world.solids() {
            if !matches!(s.kind, SolidKind::Wall | SolidKind::Box) || s.z1_m - s.z0_m < 2.0 {
                continue;
            }
            let d = match s.shape {
                crate::world::Shape::Box {
                    cx,
                    cy,
                    hx,
                    hy,
                    yaw,
                } => crate::world::Obb {
                    cx,
                    cy,
                    hx,
                    hy,
                    yaw,
                }
                .distance_to(x, y),
                crate::world::Shape::Cylinder { cx, cy, r }
                | crate::world::Shape::Ellipsoid { cx, cy, r } => {
                    ((cx - x).hypot(cy - y) - r).max(0.0)
                }
            };
            best = best.min(d);
        }
        best
    }

    /// Emits the sentences of an epoch if one falls at or before `t_s`.
    pub(crate) fn step(
        &mut self,
        world: &World,
        t_s: f64,
        base: &Isometry3<f64>,
        rng: &mut SmallRng,
    ) -> Vec<GnssSentence> {
        if t_s + 1e-9 < self.next_t_s {
            return Vec::new();
        }
        let dt = 1.0 / self.cfg.rate_hz;
        self.next_t_s += dt;
        if self.next_t_s < t_s {
            self.next_t_s = t_s + dt;
        }
        let p1 = base * Point3::from(self.primary);
        let p2 = base * Point3::from(self.secondary);
        let d = Self::sky_block_distance(world, p1.x, p1.y);
        let cap = self.denied_cap(p1.x, p1.y);
        let fix = if d < self.cfg.no_fix_distance_m || cap == GnssFix::None {
            GnssFix::None
        } else if d < self.cfg.rtk_loss_distance_m || cap == GnssFix::Single {
            GnssFix::Single
        } else if t_s - self.last_loss_t_s < self.cfg.float_after_loss_s {
            GnssFix::Float
        } else {
            GnssFix::Fixed
        };
        if matches!(fix, GnssFix::None | GnssFix::Single) {
            self.last_loss_t_s = t_s;
        }
        // Gauss-Markov bias per fix type: corrections drift slowly, single-point wanders.
        let (sigma, tau) = match fix {
            GnssFix::Fixed => (self.cfg.rtk_sigma_m, 5.0),
            GnssFix::Float => (self.cfg.float_sigma_m, 10.0),
            GnssFix::Single | GnssFix::None => (self.cfg.single_sigma_m, 60.0),
        };
        if fix != self.fix {
            self.bias *= 0.0;
        }
        self.fix = fix;
        let a = (-dt / tau).exp();
        let q = sigma * (1.0 - a * a).sqrt();
        let mut gauss = || -> f64 { rng.sample(StandardNormal) };
        self.bias = self.bias * a + Vector3::new(gauss() * q, gauss() * q, gauss() * q * 1.5);
        let white = Vector3::new(gauss(), gauss(), gauss() * 1.5) * (0.3 * sigma);
        let meas = p1.coords + self.bias + white;
        let lla = self.frame.enu_to_lla(&meas);
        let time = Some(UtcTime::from_seconds_of_day(self.cfg.utc_start_s + t_s));
        let (quality, sats, hdop, age) = match fix {
            GnssFix::Fixed => (4, 16, 0.7, Some(1.0)),
            GnssFix::Float => (5, 14, 0.9, Some(1.0)),
            GnssFix::Single => (1, 7, 2.4, None),
            GnssFix::None => (0, 0, 0.0, None),
        };
        let has = fix != GnssFix::None;
        let gga = Gga {
            talker: "GP".into(),
            time,
            lat_deg: has.then_some(lla.lat_deg),
            lon_deg: has.then_some(lla.lon_deg),
            quality,
            satellites: Some(sats),
            hdop: has.then_some(hdop),
            alt_msl_m: has.then_some(lla.h_m - self.cfg.geoid_separation_m),
            geoid_sep_m: has.then_some(self.cfg.geoid_separation_m),
            dgps_age_s: age,
            dgps_station: age.map(|_| 1),
        };
        let rtk = matches!(fix, GnssFix::Fixed | GnssFix::Float);
        let bl = p1 - p2;
        let hsig = if fix == GnssFix::Fixed {
            self.cfg.heading_sigma_deg
        } else {
            5.0 * self.cfg.heading_sigma_deg
        };
        let yaw_enu_deg = bl.y.atan2(bl.x).to_degrees() + gauss() * hsig;
        let tilt_deg = bl.z.atan2(bl.x.hypot(bl.y)).to_degrees() + gauss() * hsig;
        let avr = Avr {
            time,
            yaw_deg: rtk.then_some((90.0 - yaw_enu_deg).rem_euclid(360.0)),
            tilt_deg: rtk.then_some(tilt_deg),
            roll_deg: None,
            range_m: rtk.then_some(bl.norm() + gauss() * 0.002),
            quality: match fix {
                GnssFix::Fixed => 3,
                GnssFix::Float => 4,
                _ => 0,
            },
            pdop: has.then_some(hdop * 1.4),
            satellites: Some(sats),
        };
        vec![
            GnssSentence {
                t_s,
                text: format_gga(&gga).trim_end().to_string(),
            },
            GnssSentence {
                t_s,
                text: format_avr(&avr).trim_end().to_string(),
            },
        ]
    }
}
