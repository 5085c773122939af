//! The map frame's tilt from an accelerometer: where gravity points according to the IMU,
//! against where the estimated attitude says "up" is.
//!
//! Scan-to-map ICP keeps whatever attitude it started with and lets it drift slowly; the map
//! frame's anchoring gets the pitch from the dual-antenna baseline but no roll. A tilt of 0.5 deg
//! puts ground 10 m to the side 9 cm too high or too low, which is a false step where it meets
//! ground mapped at another tilt. An accelerometer measures the specific force `f = R^T (a + g)`;
//! averaged over a second, a ground robot's own acceleration is small and known from its
//! odometry (forward speed change, centripetal `v * omega`), so the rest is gravity.
//!
//! [`GravityTilt`] takes each sample already rotated into the map frame with the estimated
//! attitude of that moment. If the estimate were right, the window's mean, less the kinematic
//! acceleration, would point straight up; the rotation that takes it to straight up is the
//! attitude error, and applying it about the robot corrects the frame. Windows in which the
//! estimated attitude itself swung (a ramp's foot, a curb) are not used: the estimate lags the
//! sensor between scans there, and the lag would read as tilt.

use nalgebra::{UnitQuaternion, Vector3};
use serde::Deserialize;
use std::collections::VecDeque;

/// Standard gravity, m/s^2.
pub const G_MPS2: f64 = 9.806_65;

/// Gravity-tilt parameters (`[gravity]` in `config/slam.toml`).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct GravityConfig {
    /// Use the IMU's accelerometer for the frame's roll and pitch when one reports.
    pub enabled: bool,
    /// Samples averaged for one gravity direction, seconds.
    pub window_s: f64,
    /// A window's mean, less the odometry's acceleration, must be within this of `g` (bumps,
    /// skids and unmodelled accelerations otherwise read as tilt), m/s^2.
    pub accel_gate_mps2: f64,
    /// Windows in which the estimated up axis turned more than this are skipped, degrees.
    pub max_attitude_change_deg: f64,
    /// Share of the measured tilt error corrected per update.
    pub gain: f64,
    /// Largest correction per update, degrees.
    pub max_step_deg: f64,
}

impl Default for GravityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            window_s: 1.0,
            accel_gate_mps2: 0.15,
            max_attitude_change_deg: 1.0,
            gain: 0.05,
            max_step_deg: 0.05,
        }
    }
}

/// One accelerometer sample with what the agent knew at that instant.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    t_s: f64,
    /// Specific force rotated into the map frame with the estimated attitude, m/s^2.
    f_map: Vector3<f64>,
    /// The estimated body up axis in the map frame.
    up_est: Vector3<f64>,
    /// Odometry forward speed, m/s.
    v_mps: f64,
    /// Odometry turn rate, rad/s.
    omega_rps: f64,
    /// Estimated heading, radians.
    yaw_rad: f64,
}

/// Why a window gave no tilt.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GravityGap {
    /// Fewer samples than the window needs.
    TooFewSamples,
    /// The mean is not `g`: the robot accelerated in a way the odometry does not explain.
    Accelerating {
        /// |mean - kinematic| - g, m/s^2.
        excess_mps2: f64,
    },
    /// The estimated attitude turned during the window.
    AttitudeSwing {
        /// Degrees.
        change_deg: f64,
    },
}

/// The frame tilt measured by the accelerometer.
#[derive(Clone, Debug)]
pub struct GravityTilt {
    cfg: GravityConfig,
    samples: VecDeque<Sample>,
    /// Expected sample interval (from the stream), seconds.
    dt_s: Option<f64>,
}

impl GravityTilt {
    /// An empty filter.
    pub fn new(cfg: GravityConfig) -> Self {
        Self {
            cfg,
            samples: VecDeque::new(),
            dt_s: None,
        }
    }

    /// The parameters.
    pub fn config(&self) -> &GravityConfig {
        &self.cfg
    }

    /// Adds one sample: the specific force `f_body` (base_link, m/s^2), the estimated attitude
    /// `map<-base_link` at that instant, and the odometry's speed and turn rate. Non-finite
    /// samples and samples older than the newest are dropped (returns false).
    pub fn push(
        &mut self,
        t_s: f64,
        f_body: &Vector3<f64>,
        attitude: &UnitQuaternion<f64>,
        v_mps: f64,
        omega_rps: f64,
    ) -> bool {
        let finite = t_s.is_finite()
            && f_body.iter().all(|x| x.is_finite())
            && v_mps.is_finite()
            && omega_rps.is_finite();
        if !finite {
            return false;
        }
        if let Some(last) = self.samples.back() {
            if t_s <= last.t_s {
                return false;
            }
            let dt = t_s - last.t_s;
            self.dt_s = Some(self.dt_s.map_or(dt, |d| 0.9 * d + 0.1 * dt));
        }
        let x = attitude * Vector3::x();
        self.samples.push_back(Sample {
            t_s,
            f_map: attitude * f_body,
            up_est: attitude * Vector3::z(),
            v_mps,
            omega_rps,
            yaw_rad: x.y.atan2(x.x),
        });
        while self
            .samples
            .front()
            .is_some_and(|s| s.t_s < t_s - self.cfg.window_s)
        {
            self.samples.pop_front();
        }
        true
    }

    /// The up direction in the map frame as the accelerometer sees it over the last window
    /// (straight up when the estimated attitude is right), or why there is none. `min_fill` is the
    /// share of the window's samples needed (1.0 for corrections; less at start-up).
    pub fn measured_up(&self, min_fill: f64) -> Result<Vector3<f64>, GravityGap> {
        let (Some(first), Some(last), Some(dt)) =
            (self.samples.front(), self.samples.back(), self.dt_s)
        else {
            return Err(GravityGap::TooFewSamples);
        };
        let n = self.samples.len();
        let want = (self.cfg.window_s / dt).floor() * min_fill.clamp(0.0, 1.0);
        if n < 3 || (n as f64) < want {
            return Err(GravityGap::TooFewSamples);
        }
        let change_deg = first.up_est.angle(&last.up_est).to_degrees();
        if change_deg > self.cfg.max_attitude_change_deg {
            return Err(GravityGap::AttitudeSwing { change_deg });
        }
        let mut mean = Vector3::zeros();
        for s in &self.samples {
            // Centripetal acceleration points left of the heading.
            let (c, si) = (s.yaw_rad.cos(), s.yaw_rad.sin());
            let a_lat = s.v_mps * s.omega_rps;
            mean += s.f_map - Vector3::new(-si * a_lat, c * a_lat, 0.0);
        }
        mean /= n as f64;
        // Forward acceleration: the speed change across the window, along the mean heading.
        let span = last.t_s - first.t_s;
        if span > 1e-6 {
            let a_fwd = (last.v_mps - first.v_mps) / span;
            let yaw = first.yaw_rad + 0.5 * common::geom::wrap_angle(last.yaw_rad - first.yaw_rad);
            mean -= Vector3::new(yaw.cos() * a_fwd, yaw.sin() * a_fwd, 0.0);
        }
        let excess_mps2 = mean.norm() - G_MPS2;
        if excess_mps2.abs() > self.cfg.accel_gate_mps2 {
            return Err(GravityGap::Accelerating { excess_mps2 });
        }
        Ok(mean.normalize())
    }

    /// The small rotation (axis times angle, map frame, horizontal axis) to apply to the frame
    /// about the robot now: `gain` of the measured error, at most `max_step_deg`.
    pub fn correction(&self) -> Result<Vector3<f64>, GravityGap> {
        let up = self.measured_up(1.0)?;
        let full = tilt_to_vertical(&up);
        let step = (full.norm() * self.cfg.gain).min(self.cfg.max_step_deg.to_radians());
        Ok(if full.norm() > 1e-12 {
            full.normalize() * step
        } else {
            Vector3::zeros()
        })
    }

    /// Re-expresses the stored samples after the agent rotated its map frame by `q` (a GNSS
    /// or gravity correction), so the window reads as if they had been taken in the new frame
    /// and one correction is not counted again by the next.
    pub fn rotate_frame(&mut self, q: &UnitQuaternion<f64>) {
        let x = q * Vector3::x();
        let dyaw = x.y.atan2(x.x);
        for s in &mut self.samples {
            s.f_map = q * s.f_map;
            s.up_est = q * s.up_est;
            s.yaw_rad += dyaw;
        }
    }

    /// Forgets every sample (after a relocalisation or a frame change that makes the stored
    /// map-frame forces stale).
    pub fn clear(&mut self) {
        self.samples.clear();
    }
}

/// The rotation (axis times angle) that turns `up` into the map's z axis.
pub fn tilt_to_vertical(up: &Vector3<f64>) -> Vector3<f64> {
    let axis = up.cross(&Vector3::z());
    let s = axis.norm();
    if s < 1e-12 {
        return Vector3::zeros();
    }
    axis / s * s.atan2(up.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot(roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_euler_angles(
            roll_deg.to_radians(),
            pitch_deg.to_radians(),
            yaw_deg.to_radians(),
        )
    }

    /// What an accelerometer at rest or in steady motion reads: gravity (and the centripetal
    /// acceleration of a turn), in the body frame of the true attitude.
    fn specific_force(truth: &UnitQuaternion<f64>, a_world: Vector3<f64>) -> Vector3<f64> {
        truth.inverse() * (a_world + Vector3::new(0.0, 0.0, G_MPS2))
    }

    #[test]
    fn standing_on_a_slope_with_a_wrong_roll_reads_the_roll() {
        let truth = rot(3.0, -5.0, 40.0);
        let est = rot(3.6, -5.0, 40.0);
        let mut g = GravityTilt::new(GravityConfig::default());
        for k in 0..60 {
            let f = specific_force(&truth, Vector3::zeros());
            assert!(g.push(f64::from(k) * 0.02, &f, &est, 0.0, 0.0));
        }
        let up = g.measured_up(1.0).expect("a full window");
        let err = tilt_to_vertical(&up);
        // Applying the full correction to the estimate puts the map's up axis where the truth
        // has it in the body (the heading may shift by a second-order amount; yaw is not ours).
        let fixed = UnitQuaternion::from_scaled_axis(err) * est;
        let off = (fixed.inverse() * Vector3::z()).angle(&(truth.inverse() * Vector3::z()));
        assert!(off.to_degrees() < 1e-6, "left {} deg", off.to_degrees());
        assert!((err.norm().to_degrees() - 0.6).abs() < 0.01, "{err:?}");
        // The applied step is the gain's share, capped.
        let c = g.correction().unwrap();
        assert!((c.norm() - err.norm() * 0.05).abs() < 1e-9);
    }

    #[test]
    fn a_turn_at_speed_is_not_tilt() {
        // 1 m/s round a 2 m radius: 0.5 m/s^2 sideways, a 2.9 deg "tilt" if uncompensated.
        let (v, w) = (1.0, 0.5);
        let mut g = GravityTilt::new(GravityConfig::default());
        for k in 0..60 {
            let t = f64::from(k) * 0.02;
            let yaw = w * t;
            let att = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
            let a_world = Vector3::new(-yaw.sin(), yaw.cos(), 0.0) * (v * w);
            g.push(t, &specific_force(&att, a_world), &att, v, w);
        }
        let up = g.measured_up(1.0).unwrap();
        assert!(up.angle(&Vector3::z()).to_degrees() < 0.01, "{up:?}");
        // And without the odometry, the same forces would read as tilt and be refused or wrong.
        let mut blind = GravityTilt::new(GravityConfig::default());
        for k in 0..60 {
            let t = f64::from(k) * 0.02;
            let att = UnitQuaternion::from_euler_angles(0.0, 0.0, w * t);
            let a_world = Vector3::new(-(w * t).sin(), (w * t).cos(), 0.0) * (v * w);
            blind.push(t, &specific_force(&att, a_world), &att, 0.0, 0.0);
        }
        let tilt = blind
            .measured_up(1.0)
            .map(|u| u.angle(&Vector3::z()).to_degrees());
        assert!(tilt.is_ok_and(|d| d > 2.0), "{tilt:?}");
    }

    #[test]
    fn speeding_up_is_compensated_and_a_bump_is_refused() {
        let att = rot(0.0, 0.0, 90.0);
        let mut g = GravityTilt::new(GravityConfig::default());
        for k in 0..60 {
            let t = f64::from(k) * 0.02;
            // 0.5 m/s^2 forward (north).
            let f = specific_force(&att, Vector3::new(0.0, 0.5, 0.0));
            g.push(t, &f, &att, 0.5 * t, 0.0);
        }
        let up = g.measured_up(1.0).unwrap();
        assert!(up.angle(&Vector3::z()).to_degrees() < 0.05, "{up:?}");
        // A hard vertical jolt the odometry cannot explain.
        let mut b = GravityTilt::new(GravityConfig::default());
        for k in 0..60 {
            let t = f64::from(k) * 0.02;
            let jolt = if k == 30 { 30.0 } else { 0.0 };
            b.push(
                t,
                &specific_force(&att, Vector3::new(0.0, 0.0, jolt)),
                &att,
                0.0,
                0.0,
            );
        }
        assert!(matches!(
            b.measured_up(1.0),
            Err(GravityGap::Accelerating { .. })
        ));
    }

    #[test]
    fn a_swinging_estimate_is_not_used_and_gaps_are_reported() {
        let mut g = GravityTilt::new(GravityConfig::default());
        assert_eq!(g.measured_up(1.0), Err(GravityGap::TooFewSamples));
        for k in 0..60 {
            let t = f64::from(k) * 0.02;
            // Driving onto a ramp: the pitch turns by 4 deg in the window.
            let att = rot(0.0, -4.0 * t, 0.0);
            g.push(t, &specific_force(&att, Vector3::zeros()), &att, 0.5, 0.0);
        }
        assert!(matches!(
            g.measured_up(1.0),
            Err(GravityGap::AttitudeSwing { .. })
        ));
        assert!(!g.push(0.5, &Vector3::z(), &UnitQuaternion::identity(), 0.0, 0.0));
        assert!(!g.push(
            2.0,
            &Vector3::new(f64::NAN, 0.0, 9.8),
            &UnitQuaternion::identity(),
            0.0,
            0.0
        ));
    }
}
