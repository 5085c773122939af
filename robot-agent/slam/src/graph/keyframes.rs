//! Keyframes: when the odometry has moved enough to start a new one, and what one holds.

use crate::filters::OrientedCloud;
use crate::place::ScanContext;
use crate::se3;
use nalgebra::Isometry3;
use std::sync::Arc;

/// One node of the graph.
#[derive(Clone, Debug)]
pub struct Keyframe {
    /// Time of the scan it was made from, seconds.
    pub stamp_s: f64,
    /// The scan-to-map odometry's pose when it was made (`slam_map<-base_link`); never changed.
    pub odom_pose: Isometry3<f64>,
    /// The optimised pose in the graph's world frame (`world<-base_link`).
    pub pose: Isometry3<f64>,
    /// Local cloud in the keyframe's own frame (loop verification); shared, never copied.
    pub cloud: Option<Arc<OrientedCloud>>,
    /// Place descriptor of that cloud.
    pub descriptor: Option<ScanContext>,
}

/// Decides when the odometry has moved far enough for a new keyframe.
#[derive(Clone, Debug, Default)]
pub struct KeyframeSelector {
    last: Option<Isometry3<f64>>,
}

impl KeyframeSelector {
    /// True (and remembers `pose`) when `pose` is the first, or is at least `min_travel_m` or
    /// `min_rotation_rad` from the last keyframe's.
    pub fn accept(
        &mut self,
        pose: &Isometry3<f64>,
        min_travel_m: f64,
        min_rotation_rad: f64,
    ) -> bool {
        let take = match &self.last {
            None => true,
            Some(last) => {
                let d = last.inverse() * pose;
                se3::translation_norm(&d) >= min_travel_m
                    || se3::rotation_angle(&d) >= min_rotation_rad
            }
        };
        if take {
            self.last = Some(*pose);
        }
        take
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selector_takes_first_and_then_by_travel_or_turn() {
        let mut s = KeyframeSelector::default();
        let p = |x: f64, yaw: f64| se3::from_xyz_rpy([x, 0.0, 0.0], [0.0, 0.0, yaw]);
        assert!(s.accept(&p(0.0, 0.0), 2.0, 0.5));
        assert!(!s.accept(&p(1.0, 0.0), 2.0, 0.5));
        assert!(s.accept(&p(2.1, 0.0), 2.0, 0.5));
        assert!(!s.accept(&p(2.1, 0.3), 2.0, 0.5));
        assert!(s.accept(&p(2.1, 0.6), 2.0, 0.5));
    }
}
