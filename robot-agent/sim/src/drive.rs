//! A scripted driver: pure pursuit along a polyline using the truth pose (evaluation drives,
//! recordings, teach drives). Not the robot's controller (that is `control`).

use common::geom::{wrap_angle, Pose2};

/// Follows a polyline at a cruise speed.
#[derive(Clone, Debug)]
pub struct PathDriver {
    points: Vec<[f64; 2]>,
    speed_mps: f64,
    lookahead_m: f64,
    max_omega_rps: f64,
    goal_tolerance_m: f64,
    /// Index of the segment the robot is on (monotonic: loops in the path are followed in order).
    seg: usize,
    done: bool,
}

impl PathDriver {
    /// A driver for `points` (map frame) at `speed_mps`, look-ahead 1 m, turn rate up to 1 rad/s.
    pub fn new(points: &[[f64; 2]], speed_mps: f64) -> Self {
        Self {
            points: points.to_vec(),
            speed_mps,
            lookahead_m: 1.0,
            max_omega_rps: 1.0,
            goal_tolerance_m: 0.3,
            seg: 0,
            done: points.len() < 2,
        }
    }

    /// Changes the look-ahead distance, metres.
    pub fn with_lookahead(mut self, lookahead_m: f64) -> Self {
        self.lookahead_m = lookahead_m.max(0.1);
        self
    }

    /// True once the end of the path is reached.
    pub fn is_done(&self) -> bool {
        self.done
    }

    /// The command (v m/s, omega rad/s) for the current truth pose.
    pub fn command(&mut self, pose: &Pose2) -> (f64, f64) {
        if self.done {
            return (0.0, 0.0);
        }
        let p = [pose.x_m, pose.y_m];
        // Advance along segments while the projection is past a segment's end.
        while self.seg + 2 < self.points.len() {
            let (a, b) = (self.points[self.seg], self.points[self.seg + 1]);
            if proj(p, a, b) >= 1.0 {
                self.seg += 1;
            } else {
                break;
            }
        }
        let last = self.points[self.points.len() - 1];
        let to_goal = (last[0] - p[0]).hypot(last[1] - p[1]);
        if self.seg + 2 >= self.points.len() && to_goal < self.goal_tolerance_m {
            self.done = true;
            return (0.0, 0.0);
        }
        let target = self.lookahead_point(p);
        let dx = target[0] - p[0];
        let dy = target[1] - p[1];
        let alpha = wrap_angle(dy.atan2(dx) - pose.yaw_rad);
        if alpha.abs() > std::f64::consts::FRAC_PI_2 {
            return (0.0, self.max_omega_rps * alpha.signum());
        }
        let ld = dx.hypot(dy).max(1e-3);
        let v = self.speed_mps.min(0.5 + to_goal).min(self.speed_mps);
        let omega = (2.0 * v * alpha.sin() / ld).clamp(-self.max_omega_rps, self.max_omega_rps);
        (v, omega)
    }

    /// The point one look-ahead distance along the path from the robot's projection.
    fn lookahead_point(&self, p: [f64; 2]) -> [f64; 2] {
        let (a, b) = (self.points[self.seg], self.points[self.seg + 1]);
        let t = proj(p, a, b).clamp(0.0, 1.0);
        let mut cur = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
        let mut left = self.lookahead_m;
        let mut k = self.seg + 1;
        while k < self.points.len() {
            let n = self.points[k];
            let l = (n[0] - cur[0]).hypot(n[1] - cur[1]);
            if l >= left {
                let f = left / l;
                return [cur[0] + f * (n[0] - cur[0]), cur[1] + f * (n[1] - cur[1])];
            }
            left -= l;
            cur = n;
            k += 1;
        }
        cur
    }
}

fn proj(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let l2 = dx * dx + dy * dy;
    if l2 < 1e-12 {
        return 1.0;
    }
    ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn follows_an_l_path_to_its_end() {
        let pts = [[0.0, 0.0], [10.0, 0.0], [10.0, 8.0]];
        let mut d = PathDriver::new(&pts, 0.8);
        let mut pose = Pose2::new(0.0, 0.5, 0.3);
        let mut max_dev: f64 = 0.0;
        for _ in 0..5000 {
            let (v, w) = d.command(&pose);
            pose = pose.integrate(v, w, 0.02);
            let dev = if pose.x_m < 9.0 { pose.y_m.abs() } else { 0.0 };
            if pose.x_m > 2.0 {
                max_dev = max_dev.max(dev);
            }
            if d.is_done() {
                break;
            }
        }
        assert!(d.is_done());
        assert!(
            (pose.x_m - 10.0).abs() < 0.4 && (pose.y_m - 8.0).abs() < 0.4,
            "{pose:?}"
        );
        assert!(max_dev < 0.15, "{max_dev}");
    }
}
