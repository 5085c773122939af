//! Tilt of the SLAM frame against GNSS: SLAM keeps its start attitude, and the map frame's
//! anchoring at the first scan knows the pitch from the antenna baseline but not the roll (one
//! baseline), so a start on a side slope leaves the map tilted. Driving then reads as climbing or
//! descending (1 deg is 1.7 cm per metre): the height drifts decimetres from the truth within a
//! few tens of metres, and ground seen again later no longer meets the cells seen before.
//!
//! The estimator compares the vertical part of the SLAM track with the RTK track over the last
//! `tilt_window_m` of driving and returns the small rotation (about the horizontal axes) that best
//! makes them agree, least squares with a ridge so that the axis the track has not yet spread
//! along stays unchanged. The SLAM positions are kept in SLAM's own frame and rotated by the
//! current anchoring on every estimate, so corrections applied since do not bias it.

use nalgebra::{Matrix2, Rotation3, Vector2, Vector3};
use serde::Deserialize;
use std::collections::VecDeque;

/// Tilt estimation parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TiltConfig {
    /// Track samples are kept this far apart (horizontal SLAM distance), metres.
    pub sample_spacing_m: f64,
    /// Track length compared, metres.
    pub window_m: f64,
    /// The track must spread this far (RMS distance from its centre) before a tilt is estimated, metres.
    pub min_spread_m: f64,
    /// Ridge weight, square metres: with little spread along an axis the estimate stays near zero.
    pub ridge_m2: f64,
    /// Share of the estimated tilt corrected per RTK fix.
    pub gain: f64,
    /// Largest correction per fix, degrees (a bad estimate cannot swing the map).
    pub max_step_deg: f64,
}

impl Default for TiltConfig {
    fn default() -> Self {
        Self {
            sample_spacing_m: 0.5,
            window_m: 40.0,
            min_spread_m: 2.0,
            ridge_m2: 20.0,
            gain: 0.02,
            max_step_deg: 0.02,
        }
    }
}

/// Pairs of SLAM-frame and GNSS (ENU, base_link) positions along the track.
#[derive(Clone, Debug, Default)]
pub struct TiltEstimator {
    cfg: TiltConfig,
    samples: VecDeque<(Vector3<f64>, Vector3<f64>)>,
}

impl TiltEstimator {
    /// An empty estimator.
    pub fn new(cfg: TiltConfig) -> Self {
        Self {
            cfg,
            samples: VecDeque::new(),
        }
    }

    /// Adds one fix: `slam` is base_link in SLAM's frame, `gnss` the fix's base_link position in
    /// the map frame. Kept when the robot has moved `sample_spacing_m` since the last sample.
    pub fn push(&mut self, slam: Vector3<f64>, gnss: Vector3<f64>) {
        if !(slam.iter().chain(gnss.iter()).all(|v| v.is_finite())) {
            return;
        }
        if let Some((last, _)) = self.samples.back() {
            if (slam - last).xy().norm() < self.cfg.sample_spacing_m {
                return;
            }
        }
        self.samples.push_back((slam, gnss));
        let keep = (self.cfg.window_m / self.cfg.sample_spacing_m.max(1e-3)).ceil() as usize + 1;
        while self.samples.len() > keep.max(2) {
            self.samples.pop_front();
        }
    }

    /// The rotation (axis-angle vector, radians, z component zero) that, applied to the map
    /// frame's anchoring about the robot, makes the rotated SLAM track's heights agree with
    /// GNSS; `None` until the track has spread `min_spread_m`. `rot` is the anchoring's
    /// rotation (map <- SLAM).
    pub fn estimate(&self, rot: &Rotation3<f64>) -> Option<Vector3<f64>> {
        let n = self.samples.len();
        if n < 3 {
            return None;
        }
        let inv = 1.0 / n as f64;
        let (mut cs, mut cg) = (Vector3::zeros(), 0.0);
        for (s, g) in &self.samples {
            cs += s * inv;
            cg += g.z * inv;
        }
        // Height error of each sample after a small rotation w: e - (w x a).z, with
        // (w x a).z = w.x a.y - w.y a.x.
        let mut ata = Matrix2::zeros();
        let mut atb = Vector2::zeros();
        let mut spread2 = 0.0;
        for (s, g) in &self.samples {
            let a = rot * (s - cs);
            let e = (g.z - cg) - a.z;
            let row = Vector2::new(a.y, -a.x);
            ata += row * row.transpose();
            atb += row * e;
            spread2 += a.xy().norm_squared() * inv;
        }
        if spread2.sqrt() < self.cfg.min_spread_m {
            return None;
        }
        let w = (ata + Matrix2::identity() * self.cfg.ridge_m2).try_inverse()? * atb;
        w.iter()
            .all(|v| v.is_finite())
            .then(|| Vector3::new(w.x, w.y, 0.0))
    }

    /// The correction to apply for one fix: the estimate times `gain`, clamped.
    pub fn step(&self, rot: &Rotation3<f64>) -> Option<Vector3<f64>> {
        let w = self.estimate(rot)? * self.cfg.gain;
        let max = self.cfg.max_step_deg.to_radians();
        let norm = w.norm();
        Some(if norm > max { w * (max / norm) } else { w })
    }

    /// Forgets the track (a new session, or GNSS lost for long).
    pub fn clear(&mut self) {
        self.samples.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A track driven on flat ground whose SLAM frame is rolled and pitched.
    fn tilted_track(
        roll_deg: f64,
        pitch_deg: f64,
        pts: &[(f64, f64)],
    ) -> (Rotation3<f64>, TiltEstimator) {
        let truth_from_slam =
            Rotation3::from_euler_angles(roll_deg.to_radians(), pitch_deg.to_radians(), 0.3);
        // The anchoring believes yaw only.
        let anchoring = Rotation3::from_euler_angles(0.0, 0.0, 0.3);
        let mut est = TiltEstimator::new(TiltConfig::default());
        for &(x, y) in pts {
            let truth = Vector3::new(x, y, 0.0);
            est.push(truth_from_slam.inverse() * truth, truth);
        }
        (anchoring, est)
    }

    fn apply(w: Vector3<f64>, rot: &Rotation3<f64>) -> Rotation3<f64> {
        Rotation3::new(w) * rot
    }

    #[test]
    fn an_l_shaped_track_recovers_roll_and_pitch() {
        let mut pts: Vec<(f64, f64)> = (0..40).map(|i| (f64::from(i) * 0.5, 0.0)).collect();
        pts.extend((0..40).map(|i| (20.0, f64::from(i) * 0.5)));
        let (mut rot, est) = tilted_track(1.0, -0.7, &pts);
        let tilt_before = (rot.inverse()
            * Rotation3::from_euler_angles(1f64.to_radians(), -0.7f64.to_radians(), 0.3))
        .angle();
        for _ in 0..20 {
            let w = est.estimate(&rot).unwrap();
            rot = apply(w, &rot);
        }
        // The corrected anchoring maps SLAM's vertical to truth's.
        let truth = Rotation3::from_euler_angles(1f64.to_radians(), -0.7f64.to_radians(), 0.3);
        let up_err = (rot * (truth.inverse() * Vector3::z())).angle(&Vector3::z());
        assert!(tilt_before > 1.1f64.to_radians());
        assert!(up_err < 0.02f64.to_radians(), "{} deg", up_err.to_degrees());
    }

    #[test]
    fn a_straight_track_corrects_only_along_it() {
        let pts: Vec<(f64, f64)> = (0..60).map(|i| (f64::from(i) * 0.5, 0.0)).collect();
        let (rot, est) = tilted_track(0.0, 0.8, &pts);
        let w = est.estimate(&rot).unwrap();
        // The tilt about the axis across the track is recovered; the rotation about the track
        // itself is not observable and is left alone.
        let along = Vector3::x();
        assert!(w.dot(&along).abs() < 0.05f64.to_radians(), "{w:?}");
        assert!(w.norm() > 0.6f64.to_radians(), "{w:?}");
    }

    #[test]
    fn no_estimate_before_the_track_spreads_and_no_correction_when_level() {
        let pts: Vec<(f64, f64)> = (0..6).map(|i| (f64::from(i) * 0.5, 0.0)).collect();
        let (rot, est) = tilted_track(0.0, 1.0, &pts);
        assert!(est.estimate(&rot).is_none());
        let pts: Vec<(f64, f64)> = (0..60)
            .map(|i| (f64::from(i) * 0.5, f64::from(i % 7)))
            .collect();
        let (_, est) = tilted_track(0.0, 0.0, &pts);
        let w = est
            .estimate(&Rotation3::from_euler_angles(0.0, 0.0, 0.3))
            .unwrap();
        assert!(w.norm() < 1e-9);
    }

    #[test]
    fn steps_are_clamped_and_bad_input_is_ignored() {
        let pts: Vec<(f64, f64)> = (0..60).map(|i| (f64::from(i) * 0.5, 0.0)).collect();
        let (rot, mut est) = tilted_track(0.0, 5.0, &pts);
        est.push(Vector3::new(f64::NAN, 0.0, 0.0), Vector3::zeros());
        let s = est.step(&rot).unwrap();
        assert!((s.norm() - 0.02f64.to_radians()).abs() < 1e-12);
    }
}
