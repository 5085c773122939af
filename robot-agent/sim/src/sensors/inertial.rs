//! The IMU (true specific force and rate plus bias and noise) and wheel odometry.

use super::{ImuConfig, OdomConfig};
use common::geom::Pose2;
use nalgebra::{Isometry3, Vector3};
use rand::rngs::SmallRng;
use rand::Rng;
use rand_distr::StandardNormal;
use sensing::{ImuSample, OdomSample};

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
