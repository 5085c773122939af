//! GNSS-aided localisation: a complementary filter on the frame's anchoring.
//!
//! Each fresh RTK fixed fix pulls the SLAM frame's anchor a little towards where GNSS puts the
//! robot, so SLAM drift stays bounded by RTK accuracy while GNSS is available; on loss, SLAM and
//! odometry carry on alone. Per fix, with `d` the GNSS-minus-estimate position difference of
//! `base_link` (the antenna's lever arm removed with the estimated attitude):
//!
//! - x, y move by `fusion_gain * d`, the height by `height_gain * d_z` (far smaller: a height step
//!   between sweeps would read as a step in the terrain, so the height only creeps towards GNSS to
//!   cancel SLAM's slow vertical drift);
//! - the heading turns by `heading_gain` times the dual-antenna heading difference (ignored when
//!   larger than 10 deg: a heading that far off is a receiver glitch, not drift);
//! - without an IMU, the frame tilts by the GNSS track fit's step ([`super::tilt`]);
//! - a fix farther than `fusion_gate_m` from the estimate is an outlier and moves nothing.
//!
//! The correction rotates about the robot, so the robot's own position moves only by `k * d`.

use super::gnss::GnssConfig;
use super::tilt::TiltEstimator;
use super::PoseMap;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// What one fix brings.
pub struct FusionInput<'a> {
    /// Gains and the gate.
    pub cfg: &'a GnssConfig,
    /// The primary antenna's position from the fix, ENU at the datum, metres.
    pub fix_enu: Vector3<f64>,
    /// Primary antenna in `base_link`, metres.
    pub antenna_xyz_m: [f64; 3],
    /// The pose estimate now.
    pub est: &'a PoseMap,
    /// The dual-antenna heading, ENU, radians, when fresh.
    pub yaw_enu_rad: Option<f64>,
    /// `map <- slam` before this fix.
    pub map_from_slam: &'a Isometry3<f64>,
    /// The GNSS track tilt estimator (fed with every accepted fix).
    pub tilt: &'a mut TiltEstimator,
    /// Whether the track fit's tilt is applied (false while the accelerometer is live).
    pub track_tilt: bool,
}

/// The outcome of one fix.
#[derive(Clone, Copy, Debug)]
pub struct Correction {
    /// Horizontal distance from the estimate to the fix, metres.
    pub residual_m: f64,
    /// The frame correction (`map <- corrected map`); None when the fix was gated out.
    pub delta: Option<Isometry3<f64>>,
}

/// One fix's correction of the frame (see the module docs).
pub fn correction(input: FusionInput<'_>) -> Correction {
    let cfg = input.cfg;
    let est_p = input.est.iso.translation.vector;
    let [ax, ay, az] = input.antenna_xyz_m;
    let meas = input.fix_enu - input.est.iso.rotation * Vector3::new(ax, ay, az);
    let d = meas - est_p;
    let residual_m = d.xy().norm();
    if residual_m > cfg.fusion_gate_m {
        return Correction {
            residual_m,
            delta: None,
        };
    }
    let dyaw = input
        .yaw_enu_rad
        .map(|y| common::geom::wrap_angle(y - input.est.planar.yaw_rad))
        .filter(|dy| dy.abs() < 10f64.to_radians())
        .map_or(0.0, |dy| dy * cfg.heading_gain);
    let k = Vector3::new(cfg.fusion_gain, cfg.fusion_gain, cfg.height_gain);
    input.tilt.push(
        input
            .map_from_slam
            .inverse_transform_point(&est_p.into())
            .coords,
        meas,
    );
    let tilt = if input.track_tilt {
        input
            .tilt
            .step(&input.map_from_slam.rotation.to_rotation_matrix())
            .unwrap_or_default()
    } else {
        Vector3::zeros()
    };
    let delta = Isometry3::from_parts(
        Translation3::from(est_p + d.component_mul(&k)),
        UnitQuaternion::from_scaled_axis(tilt)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), dyaw),
    ) * Isometry3::from_parts(Translation3::from(-est_p), UnitQuaternion::identity());
    Correction {
        residual_m,
        delta: Some(delta),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64, y: f64, yaw: f64) -> PoseMap {
        PoseMap::from_iso(Isometry3::from_parts(
            Translation3::new(x, y, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        ))
    }

    #[test]
    fn a_fix_pulls_by_the_gains_and_an_outlier_by_nothing() {
        let cfg = GnssConfig::default();
        let mut tilt = TiltEstimator::new(cfg.tilt.clone());
        let est = pose(10.0, 0.0, 0.0);
        let ident = Isometry3::identity();
        // GNSS says the antenna (0.9 m up) is 1 m further east.
        let c = correction(FusionInput {
            cfg: &cfg,
            fix_enu: Vector3::new(11.0, 0.0, 0.9),
            antenna_xyz_m: [0.0, 0.0, 0.9],
            est: &est,
            yaw_enu_rad: None,
            map_from_slam: &ident,
            tilt: &mut tilt,
            track_tilt: false,
        });
        assert!((c.residual_m - 1.0).abs() < 1e-9);
        let moved = c.delta.unwrap() * est.iso;
        assert!((moved.translation.x - (10.0 + cfg.fusion_gain)).abs() < 1e-9);
        let far = correction(FusionInput {
            cfg: &cfg,
            fix_enu: Vector3::new(20.0, 0.0, 0.9),
            antenna_xyz_m: [0.0, 0.0, 0.9],
            est: &est,
            yaw_enu_rad: None,
            map_from_slam: &ident,
            tilt: &mut tilt,
            track_tilt: false,
        });
        assert!(far.delta.is_none());
    }

    #[test]
    fn heading_follows_the_baseline_by_its_gain_but_not_a_glitch() {
        let cfg = GnssConfig::default();
        let mut tilt = TiltEstimator::new(cfg.tilt.clone());
        let est = pose(0.0, 0.0, 0.0);
        let ident = Isometry3::identity();
        let mut turn = |yaw: f64| {
            let c = correction(FusionInput {
                cfg: &cfg,
                fix_enu: Vector3::new(0.0, 0.0, 0.9),
                antenna_xyz_m: [0.0, 0.0, 0.9],
                est: &est,
                yaw_enu_rad: Some(yaw),
                map_from_slam: &ident,
                tilt: &mut tilt,
                track_tilt: false,
            });
            PoseMap::from_iso(c.delta.unwrap() * est.iso).planar.yaw_rad
        };
        let small = 2f64.to_radians();
        assert!((turn(small) - small * cfg.heading_gain).abs() < 1e-9);
        assert!(turn(30f64.to_radians()).abs() < 1e-12);
    }
}
