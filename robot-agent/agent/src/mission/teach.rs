//! Teach: record the driven route as waypoints spaced by distance and heading change.

use crate::command::RoutePoint;
use common::geom::{wrap_angle, Pose2};
use serde::Deserialize;

/// How densely a taught route is sampled.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TeachConfig {
    /// A new waypoint after this distance driven since the last one, metres.
    pub spacing_m: f64,
    /// ... or after this heading change since the last one, degrees (keeps corners sharp).
    pub heading_change_deg: f64,
    /// Never closer than this, metres (turning on the spot adds no waypoints).
    pub min_spacing_m: f64,
}

impl Default for TeachConfig {
    fn default() -> Self {
        Self {
            spacing_m: 1.0,
            heading_change_deg: 15.0,
            min_spacing_m: 0.2,
        }
    }
}

/// Records waypoints while the operator drives.
#[derive(Clone, Debug)]
pub struct RouteRecorder {
    cfg: TeachConfig,
    name: String,
    points: Vec<RoutePoint>,
    last: Option<Pose2>,
}

impl RouteRecorder {
    /// Starts a recording named `name`.
    pub fn new(cfg: TeachConfig, name: impl Into<String>) -> Self {
        Self {
            cfg,
            name: name.into(),
            points: Vec::new(),
            last: None,
        }
    }

    /// The route's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Waypoints so far.
    pub fn points(&self) -> &[RoutePoint] {
        &self.points
    }

    /// Offers the current pose (map frame) with its geodetic position (lat, lon, h) when the map
    /// is anchored; returns true when it became a waypoint.
    pub fn offer(&mut self, pose_map: Pose2, lla: Option<(f64, f64, f64)>, t_unix_ms: u64) -> bool {
        let take = match self.last {
            None => true,
            Some(last) => {
                let d = last.distance_to(&pose_map);
                let turn = wrap_angle(pose_map.yaw_rad - last.yaw_rad)
                    .abs()
                    .to_degrees();
                d >= self.cfg.spacing_m
                    || (d >= self.cfg.min_spacing_m && turn >= self.cfg.heading_change_deg)
            }
        };
        if take {
            self.push(pose_map, lla, t_unix_ms);
        }
        take
    }

    /// Ends the recording; the final pose is always the last waypoint.
    pub fn finish(
        mut self,
        pose_map: Pose2,
        lla: Option<(f64, f64, f64)>,
        t_unix_ms: u64,
    ) -> Vec<RoutePoint> {
        if self.last.is_none_or(|l| l.distance_to(&pose_map) > 1e-3) {
            self.push(pose_map, lla, t_unix_ms);
        }
        self.points
    }

    fn push(&mut self, pose_map: Pose2, lla: Option<(f64, f64, f64)>, t_unix_ms: u64) {
        self.points.push(RoutePoint {
            x_m: pose_map.x_m,
            y_m: pose_map.y_m,
            lat_deg: lla.map(|l| l.0),
            lon_deg: lla.map(|l| l.1),
            h_m: lla.map(|l| l.2),
            yaw_rad: pose_map.yaw_rad,
            t_unix_ms,
        });
        self.last = Some(pose_map);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacing_by_distance_and_heading() {
        let mut r = RouteRecorder::new(TeachConfig::default(), "t");
        // Straight 10 m in 1 cm steps: a point per metre.
        for i in 0..=1000 {
            r.offer(Pose2::new(i as f64 * 0.01, 0.0, 0.0), None, i);
        }
        assert_eq!(r.points().len(), 11);
        // A 90-degree turn on an arc of radius 1 m: heading triggers before distance does.
        let n_before = r.points().len();
        for i in 1..=100 {
            let a = i as f64 / 100.0 * std::f64::consts::FRAC_PI_2;
            r.offer(Pose2::new(10.0 + a.sin(), 1.0 - a.cos(), a), None, 2000 + i);
        }
        let added = r.points().len() - n_before;
        assert!((4..=7).contains(&added), "{added} waypoints on the corner");
        // Turning on the spot adds nothing.
        let mut spin = RouteRecorder::new(TeachConfig::default(), "spin");
        for i in 0..100 {
            spin.offer(Pose2::new(11.0, 1.0, i as f64 * 0.05), None, 3000);
        }
        assert_eq!(spin.points().len(), 1);
        let pts = r.finish(Pose2::new(11.0, 5.0, 1.5), Some((48.0, 11.0, 500.0)), 4000);
        assert_eq!(pts.last().unwrap().y_m, 5.0);
        assert_eq!(pts.last().unwrap().lat_deg, Some(48.0));
    }
}
