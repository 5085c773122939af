//! Anchoring SLAM's frame (the first sweep's `base_link`) in the `map` frame at the first sweep.
//!
//! With a fresh RTK fixed fix (enough satellites) and a dual-antenna heading, `map` is ENU at the
//! datum (the operator's, shared by several robots, or the fix itself) and the start pose comes
//! from GNSS: position from the primary antenna less its lever arm, heading from the baseline,
//! pitch from the baseline's tilt (one baseline: no roll), or roll and pitch from the
//! accelerometer when it has a window of samples. Otherwise `map` is the first pose and GNSS
//! goals are refused.

use super::gnss::GnssTracker;
use super::FrameKind;
use common::geo::LocalFrame;
use common::msg::Datum;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// How the SLAM frame sits in the map frame.
#[derive(Clone, Debug)]
pub struct Anchor {
    /// `map <- slam`.
    pub map_from_slam: Isometry3<f64>,
    /// How `map` is anchored.
    pub frame: FrameKind,
    /// ENU at the datum, when anchored by GNSS.
    pub local: Option<LocalFrame>,
}

/// The anchor at the first sweep (time `t_s`).
pub fn anchor_frame(
    gnss: &GnssTracker,
    gravity: &slam::gravity::GravityTilt,
    datum: Option<Datum>,
    antenna_xyz_m: [f64; 3],
    t_s: f64,
) -> Anchor {
    let fix = gnss.fix(t_s);
    let yaw = gnss.yaw_enu_rad(t_s);
    match (gnss.can_anchor(t_s), fix, yaw) {
        (true, Some(fix), Some(yaw)) => {
            let datum = datum.unwrap_or(fix.lla);
            let local = LocalFrame::new(datum);
            let enu = local.lla_to_enu(&fix.lla);
            // The baseline's tilt gives the pitch (one baseline: no roll), so the map's z is up
            // along the heading from the start rather than tilted with the ground.
            let pitch = gnss.pitch_rad(t_s).unwrap_or(0.0);
            let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
                * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch);
            // An accelerometer gives the roll too (and the pitch, better than a 1 m baseline).
            let rot = match gravity.measured_up(0.0) {
                Ok(up_body) => {
                    let level =
                        UnitQuaternion::from_scaled_axis(slam::gravity::tilt_to_vertical(&up_body));
                    let x = level * Vector3::x();
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw - x.y.atan2(x.x))
                        * level
                }
                Err(_) => rot,
            };
            let [ax, ay, az] = antenna_xyz_m;
            let base = enu - rot * Vector3::new(ax, ay, az);
            tracing::info!(
                "map frame: ENU at datum {:.7}, {:.7}, {:.2} m; start pose ({:.2}, {:.2}) yaw {:.1} deg from GNSS",
                datum.lat_deg, datum.lon_deg, datum.h_m, base.x, base.y, yaw.to_degrees()
            );
            Anchor {
                map_from_slam: Isometry3::from_parts(Translation3::from(base), rot),
                frame: FrameKind::EnuAtDatum,
                local: Some(local),
            }
        }
        _ => {
            tracing::warn!("no RTK fix with heading at the first scan: the map frame is the first pose; GNSS goals are refused");
            Anchor {
                map_from_slam: Isometry3::identity(),
                frame: FrameKind::FirstPose,
                local: None,
            }
        }
    }
}
