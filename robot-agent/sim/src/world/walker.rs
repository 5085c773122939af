//! Pedestrians walking polylines, and their state at a time.

use super::solid::{Shape, Solid, SolidKind};
use crate::scenario::{WalkMode, WalkerSpec};

/// A pedestrian on a polyline.
#[derive(Clone, Debug)]
pub struct Walker {
    points: Vec<[f64; 2]>,
    /// Cumulative length at each vertex (loop: includes the closing segment).
    cum_m: Vec<f64>,
    speed_mps: f64,
    mode: WalkMode,
    phase_m: f64,
    /// Body radius, metres.
    pub radius_m: f64,
    /// Body height, metres.
    pub height_m: f64,
}

impl Walker {
    pub(super) fn new(spec: &WalkerSpec) -> Self {
        let mut points = spec.points.clone();
        if spec.mode == WalkMode::Loop {
            points.push(spec.points[0]);
        }
        let mut cum_m = vec![0.0];
        for w in points.windows(2) {
            let l = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            cum_m.push(cum_m.last().copied().unwrap_or(0.0) + l);
        }
        Self {
            points,
            cum_m,
            speed_mps: spec.speed_mps,
            mode: spec.mode,
            phase_m: spec.phase_m,
            radius_m: spec.radius_m,
            height_m: spec.height_m,
        }
    }

    /// Position (x, y) at time `t_s`.
    pub fn position(&self, t_s: f64) -> [f64; 2] {
        let total = self.cum_m.last().copied().unwrap_or(0.0);
        if total <= 1e-9 {
            return self.points[0];
        }
        let s = self.phase_m + self.speed_mps * t_s;
        let s = match self.mode {
            WalkMode::Loop => s.rem_euclid(total),
            WalkMode::PingPong => {
                let u = s.rem_euclid(2.0 * total);
                if u > total {
                    2.0 * total - u
                } else {
                    u
                }
            }
        };
        let k = self
            .cum_m
            .partition_point(|&c| c <= s)
            .clamp(1, self.points.len() - 1);
        let l = self.cum_m[k] - self.cum_m[k - 1];
        let f = if l > 1e-12 {
            (s - self.cum_m[k - 1]) / l
        } else {
            0.0
        };
        let a = self.points[k - 1];
        let b = self.points[k];
        [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f]
    }
}

/// A walker's state at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WalkerState {
    /// Index in the scenario's `[[walker]]` list.
    pub id: usize,
    /// Position x, metres (map frame).
    pub x_m: f64,
    /// Position y, metres.
    pub y_m: f64,
    /// Ground height under the walker, metres.
    pub z_m: f64,
    /// Body radius, metres.
    pub radius_m: f64,
    /// Body height, metres.
    pub height_m: f64,
}

impl WalkerState {
    /// The walker as a solid cylinder.
    pub fn solid(&self) -> Solid {
        Solid {
            shape: Shape::Cylinder {
                cx: self.x_m,
                cy: self.y_m,
                r: self.radius_m,
            },
            z0_m: self.z_m - 0.05,
            z1_m: self.z_m + self.height_m,
            kind: SolidKind::Box,
            feature: self.id as u32,
        }
    }
}
