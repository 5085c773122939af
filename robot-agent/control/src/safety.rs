//! The safety stop (docs/algorithms.md §6.2): raw scan points too close to the robot body stop it
//! at once, whatever the plan says; rotating in place stays allowed.

use serde::Deserialize;

/// Safety-stop parameters (robot frame: x forward, y left, z up from the ground).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyConfig {
    /// Body length, metres (Husky 1.0).
    pub body_length_m: f64,
    /// Body width, metres (Husky 0.7).
    pub body_width_m: f64,
    /// Stop when a point is within this distance ahead of the body's front, metres.
    pub stop_ahead_m: f64,
    /// ... or within this margin beside the body, metres.
    pub stop_side_m: f64,
    /// Points lower than this are ground, not obstacles, metres (above the base frame).
    pub min_height_m: f64,
    /// Points higher than this pass over the robot, metres.
    pub max_height_m: f64,
    /// Points needed to stop (one stray return must not stop the robot).
    pub min_points: usize,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            body_length_m: 1.0,
            body_width_m: 0.7,
            stop_ahead_m: 0.25,
            stop_side_m: 0.08,
            min_height_m: 0.15,
            max_height_m: 1.1,
            min_points: 3,
        }
    }
}

/// What the last sweep says about the space around the body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafetyVerdict {
    /// Stop forward motion now.
    pub stop: bool,
    /// Points inside the stop zone.
    pub points_in_zone: usize,
    /// Distance from the body outline to the nearest obstacle point (in the height band), metres.
    pub clearance_m: f64,
    /// Something stands inside the circle the body's corners sweep when turning in place (plus
    /// `stop_side_m`): turning would hit it, so the robot must not turn either.
    pub turn_blocked: bool,
    /// Points inside that circle (outside the body).
    pub points_in_swept: usize,
    /// The stop-zone point nearest the body (`base_link` x, y), for telling the planner where
    /// a stop that lasts stands.
    pub zone_nearest_m: Option<(f64, f64)>,
}

impl Default for SafetyVerdict {
    fn default() -> Self {
        Self {
            stop: false,
            points_in_zone: 0,
            clearance_m: f64::INFINITY,
            turn_blocked: false,
            points_in_swept: 0,
            zone_nearest_m: None,
        }
    }
}

/// Checks points given in the robot frame (`base_link`).
pub fn check(
    cfg: &SafetyConfig,
    points_base: impl IntoIterator<Item = (f64, f64, f64)>,
) -> SafetyVerdict {
    let (hl, hw) = (cfg.body_length_m / 2.0, cfg.body_width_m / 2.0);
    let swept_r2 = (hl.hypot(hw) + cfg.stop_side_m).powi(2);
    let mut v = SafetyVerdict::default();
    let mut zone_gap = f64::INFINITY;
    for (x, y, z) in points_base {
        if !(x.is_finite() && y.is_finite() && z.is_finite())
            || z < cfg.min_height_m
            || z > cfg.max_height_m
        {
            continue;
        }
        let ex = (x.abs() - hl).max(0.0);
        let ey = (y.abs() - hw).max(0.0);
        if ex == 0.0 && ey == 0.0 {
            // Inside the body outline: the robot's own parts (sensor mast, bumpers).
            continue;
        }
        let gap = ex.hypot(ey);
        v.clearance_m = v.clearance_m.min(gap);
        let ahead = x > hl && x <= hl + cfg.stop_ahead_m && y.abs() <= hw + cfg.stop_side_m;
        let beside = x.abs() <= hl && ey > 0.0 && ey <= cfg.stop_side_m;
        if ahead || beside {
            v.points_in_zone += 1;
            if gap < zone_gap {
                zone_gap = gap;
                v.zone_nearest_m = Some((x, y));
            }
        }
        if x * x + y * y <= swept_r2 {
            v.points_in_swept += 1;
        }
    }
    v.stop = v.points_in_zone >= cfg.min_points;
    v.turn_blocked = v.points_in_swept >= cfg.min_points;
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stops_for_points_ahead_only_in_the_height_band() {
        let c = SafetyConfig::default();
        let wall: Vec<_> = (0..10)
            .map(|i| (0.65, -0.3 + f64::from(i) * 0.06, 0.5))
            .collect();
        let v = check(&c, wall.clone());
        assert!(v.stop && (v.clearance_m - 0.15).abs() < 1e-9);
        assert_eq!(v.zone_nearest_m.map(|p| p.0), Some(0.65));
        let far: Vec<_> = wall.iter().map(|p| (1.5, p.1, p.2)).collect();
        assert!(!check(&c, far).stop);
        let ground: Vec<_> = wall.iter().map(|p| (p.0, p.1, 0.05)).collect();
        assert!(!check(&c, ground).stop);
        let canopy: Vec<_> = wall.iter().map(|p| (p.0, p.1, 2.0)).collect();
        assert!(!check(&c, canopy).stop);
        let own_mast = vec![(0.0, 0.0, 0.7); 20];
        assert!(!check(&c, own_mast).stop);
        assert!(!check(&c, vec![(0.6, 0.0, 0.5)]).stop, "one stray return");
        assert!(!check(&c, vec![(f64::NAN, 0.0, 0.5); 5]).stop);
    }

    #[test]
    fn a_person_at_the_corner_blocks_turning_but_not_one_beyond_the_swept_circle() {
        let c = SafetyConfig::default();
        // Beside the front corner, 0.15 m out: outside the stop zones, inside the swept circle
        // (radius 0.61 m + 0.08 m).
        let near: Vec<_> = (0..6)
            .map(|i| (0.3, 0.5 + f64::from(i) * 0.01, 0.8))
            .collect();
        let v = check(&c, near);
        assert!(!v.stop && v.turn_blocked, "{v:?}");
        let far: Vec<_> = (0..6)
            .map(|i| (0.3, 0.8 + f64::from(i) * 0.01, 0.8))
            .collect();
        assert!(!check(&c, far).turn_blocked);
    }
}
