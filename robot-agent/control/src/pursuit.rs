//! Pure pursuit: a target point one look-ahead distance along the path, an arc through it.
//!
//! With the target at lateral offset `dy` in the robot frame, the arc radius is
//! `R = d_l^2 / (2 dy)` and `omega = K_p v / R` (docs/algorithms.md §6.1). Speed is limited by
//! `v_max`, by the operator's limit, by curvature (`|omega| <= omega_max` forces
//! `v <= omega_max R`), by the clearance to the nearest obstacle, and by the distance left to the
//! goal.

use crate::safety::SafetyConfig;
use common::geom::{wrap_angle, Pose2};
use serde::Deserialize;

/// Controller parameters (`config/control.toml`).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Look-ahead distance `d_l`, metres.
    pub lookahead_m: f64,
    /// Shortest look-ahead near the path's end, metres.
    pub min_lookahead_m: f64,
    /// Gain `K_p` on the pure-pursuit curvature.
    pub k_p: f64,
    /// Maximum forward speed `v_max`, m/s.
    pub v_max_mps: f64,
    /// Maximum turn rate `omega_max`, rad/s.
    pub omega_max_rps: f64,
    /// Slowest forward speed while following (below it the robot would stall on grass), m/s.
    pub v_min_mps: f64,
    /// Heading error beyond which the robot turns in place first, radians.
    pub rotate_in_place_rad: f64,
    /// Clearance below which speed is scaled down linearly, metres.
    pub slow_clearance_m: f64,
    /// Deceleration used to approach the goal, m/s^2.
    pub goal_decel_mps2: f64,
    /// Lateral-error gain added to the pursuit curvature (1/m^2), for tight tracking of taught routes.
    pub k_lateral: f64,
    /// Safety stop.
    pub safety: SafetyConfig,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            lookahead_m: 1.0,
            min_lookahead_m: 0.4,
            k_p: 1.0,
            v_max_mps: 0.5,
            omega_max_rps: 0.3,
            v_min_mps: 0.05,
            rotate_in_place_rad: 1.0,
            slow_clearance_m: 1.0,
            goal_decel_mps2: 0.3,
            k_lateral: 0.5,
            safety: SafetyConfig::default(),
        }
    }
}

/// A velocity command.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FollowerCmd {
    /// Forward speed, m/s.
    pub v_mps: f64,
    /// Turn rate, rad/s.
    pub omega_rps: f64,
}

/// Follows a polyline path.
#[derive(Clone, Debug)]
pub struct Follower {
    cfg: Config,
}

/// The point where a circle of radius `r` around `p` leaves the path, searching from the path
/// segment nearest to `p`; the path's end when the circle contains it.
pub fn lookahead_point(path: &[(f64, f64)], p: (f64, f64), r: f64) -> ((f64, f64), usize) {
    let mut best = (0, f64::INFINITY);
    for (i, w) in path.windows(2).enumerate() {
        let d = seg_dist(w[0], w[1], p);
        if d < best.1 - 1e-9 {
            best = (i, d);
        }
    }
    for (i, w) in path.windows(2).enumerate().skip(best.0) {
        let (a, b) = (w[0], w[1]);
        // Far intersection of the segment with the circle.
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (fx, fy) = (a.0 - p.0, a.1 - p.1);
        let qa = dx * dx + dy * dy;
        if qa < 1e-12 {
            continue;
        }
        let qb = 2.0 * (fx * dx + fy * dy);
        let qc = fx * fx + fy * fy - r * r;
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let t = (-qb + disc.sqrt()) / (2.0 * qa);
            if (0.0..=1.0).contains(&t) {
                return ((a.0 + t * dx, a.1 + t * dy), i);
            }
        }
    }
    (*path.last().unwrap_or(&p), path.len().saturating_sub(2))
}

fn seg_dist(a: (f64, f64), b: (f64, f64), p: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a.0 + t * dx - p.0).hypot(a.1 + t * dy - p.1)
}

/// Signed lateral offset of `p` from the nearest path segment (left positive), metres.
pub fn cross_track_m(path: &[(f64, f64)], p: (f64, f64)) -> f64 {
    let mut best = (f64::INFINITY, 0.0);
    for w in path.windows(2) {
        let (a, b) = (w[0], w[1]);
        let d = seg_dist(a, b, p);
        if d < best.0 {
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let side = (dx * (p.1 - a.1) - dy * (p.0 - a.0)).signum();
            best = (d, side * d);
        }
    }
    best.1
}

/// The speed that keeps `|omega| = |K_p v curvature| <= omega_max`.
pub fn curvature_limited_speed(
    v_mps: f64,
    curvature_1pm: f64,
    k_p: f64,
    omega_max_rps: f64,
) -> f64 {
    let k = (k_p * curvature_1pm).abs();
    if k < 1e-9 {
        v_mps
    } else {
        v_mps.min(omega_max_rps / k)
    }
}

impl Follower {
    /// A follower.
    pub fn new(cfg: Config) -> Self {
        Self { cfg }
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The command to follow `path` (map frame, first point near the robot) from `pose`.
    /// `limit_mps` is the operator's speed limit, `clearance_m` the distance from the body to the
    /// nearest obstacle point; `to_end` makes the robot slow down to stop at the path's end.
    pub fn command(
        &self,
        pose: &Pose2,
        path: &[(f64, f64)],
        limit_mps: f64,
        clearance_m: f64,
        to_end: bool,
    ) -> FollowerCmd {
        let c = &self.cfg;
        if path.len() < 2 {
            return FollowerCmd::default();
        }
        let p = (pose.x_m, pose.y_m);
        let end = *path.last().unwrap_or(&p);
        let to_goal = (end.0 - p.0).hypot(end.1 - p.1);
        let ld = c.lookahead_m.min(to_goal.max(c.min_lookahead_m));
        let (target, _) = lookahead_point(path, p, ld);
        let (dx, dy) = (target.0 - p.0, target.1 - p.1);
        let alpha = wrap_angle(dy.atan2(dx) - pose.yaw_rad);
        if alpha.abs() > c.rotate_in_place_rad {
            return FollowerCmd {
                v_mps: 0.0,
                omega_rps: c.omega_max_rps * alpha.signum(),
            };
        }
        let dist = dx.hypot(dy).max(1e-3);
        // Lateral offset of the target in the robot frame, and R = d_l^2 / (2 dy).
        let lat = dist * alpha.sin();
        let mut curvature = 2.0 * lat / (dist * dist);
        // A little cross-track feedback keeps the robot on the line (taught routes need cm).
        curvature -= c.k_lateral * cross_track_m(path, p) * alpha.cos().max(0.0);
        let mut v = c.v_max_mps.min(limit_mps.max(0.0));
        if clearance_m.is_finite() && clearance_m < c.slow_clearance_m {
            v *= (clearance_m / c.slow_clearance_m).clamp(0.2, 1.0);
        }
        if to_end {
            v = v.min((2.0 * c.goal_decel_mps2 * to_goal).sqrt());
        }
        v = curvature_limited_speed(v, curvature, c.k_p, c.omega_max_rps);
        if v < c.v_min_mps && to_goal > 0.05 {
            v = c.v_min_mps.min(limit_mps.max(0.0));
        }
        let omega = (c.k_p * v * curvature).clamp(-c.omega_max_rps, c.omega_max_rps);
        FollowerCmd {
            v_mps: v,
            omega_rps: omega,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(f: &Follower, path: &[(f64, f64)], mut pose: Pose2, steps: usize) -> (Pose2, f64) {
        let mut max_err: f64 = 0.0;
        for _ in 0..steps {
            let c = f.command(&pose, path, 1.0, f64::INFINITY, true);
            assert!(
                c.v_mps <= 0.5 + 1e-12 && c.omega_rps.abs() <= 0.3 + 1e-12,
                "limits: {c:?}"
            );
            pose = pose.integrate(c.v_mps, c.omega_rps, 0.05);
            max_err = max_err.max(cross_track_m(path, (pose.x_m, pose.y_m)).abs());
        }
        (pose, max_err)
    }

    #[test]
    fn converges_to_a_straight_line() {
        let f = Follower::new(Config::default());
        let path = [(0.0, 0.0), (30.0, 0.0)];
        let (end, _) = drive(&f, &path, Pose2::new(0.0, 0.5, 0.0), 1400);
        assert!(
            (end.x_m - 30.0).abs() < 0.1 && end.y_m.abs() < 0.03,
            "{end:?}"
        );
    }

    #[test]
    fn tracks_a_gentle_circle_closely() {
        let f = Follower::new(Config::default());
        // Radius 5 m: curvature 0.2, at 0.5 m/s omega 0.1 < omega_max.
        let path: Vec<(f64, f64)> = (0..=100)
            .map(|i| {
                let a = f64::from(i) / 100.0 * std::f64::consts::PI;
                (5.0 * a.sin(), 5.0 - 5.0 * a.cos())
            })
            .collect();
        let (_, max_err) = drive(&f, &path, Pose2::new(0.0, 0.0, 0.0), 600);
        assert!(max_err < 0.08, "max cross-track {max_err}");
    }

    #[test]
    fn turns_in_place_when_the_path_is_behind() {
        let f = Follower::new(Config::default());
        let c = f.command(
            &Pose2::new(0.0, 0.0, 0.0),
            &[(0.0, 0.0), (-5.0, 0.1)],
            1.0,
            9.0,
            true,
        );
        assert_eq!(c.v_mps, 0.0);
        assert!((c.omega_rps.abs() - 0.3).abs() < 1e-12);
    }

    #[test]
    fn slows_near_obstacles_and_respects_the_limit() {
        let f = Follower::new(Config::default());
        let path = [(0.0, 0.0), (10.0, 0.0)];
        let free = f.command(&Pose2::default(), &path, 1.0, 5.0, false).v_mps;
        let near = f.command(&Pose2::default(), &path, 1.0, 0.3, false).v_mps;
        let limited = f.command(&Pose2::default(), &path, 0.2, 5.0, false).v_mps;
        assert!((free - 0.5).abs() < 1e-9 && near < 0.2 && (limited - 0.2).abs() < 1e-9);
    }

    #[test]
    fn curvature_limit() {
        assert!((curvature_limited_speed(0.5, 1.0, 1.0, 0.3) - 0.3).abs() < 1e-12);
        assert_eq!(curvature_limited_speed(0.5, 0.0, 1.0, 0.3), 0.5);
    }
}
