//! Negative obstacles (docs/algorithms.md §4.9, the source's step 6): unknown cells in the sensor's
//! reach whose neighbour towards the robot is observed ground and beyond which the surface is
//! missing or much lower (a platform edge, a hole, a missing manhole cover), and the lip beside
//! them.

use super::cell_data::CellData;
use super::{norm2, Mapper, RobotPose};
use crate::classify::Class;

impl Mapper {
    /// Unknown cells in reach of the sensor whose neighbour towards the robot is observed
    /// ground and beyond which the surface is missing or much lower: a drop-off, hole or
    /// platform edge. Returns the cells whose class changed.
    pub(super) fn negative_obstacles(&mut self, robot: &RobotPose) -> Vec<(i64, i64)> {
        let l = self.cfg.grid_size_m;
        let r_min = self.cfg.blind_radius_m() + l;
        let r_max = self.cfg.negative_obstacle_distance_m;
        if r_max <= r_min {
            return Vec::new();
        }
        let tan_phi = self.cfg.phi_max_deg.to_radians().tan();
        let drop_m = self.cfg.max_step_m.max(self.cfg.h_max_m()) * 2.0;
        let beyond_cells = (3.0 / l).ceil() as i64;
        let (x0, y0) = self.lattice.cell_of(robot.x_m - r_max, robot.y_m - r_max);
        let (x1, y1) = self.lattice.cell_of(robot.x_m + r_max, robot.y_m + r_max);
        let mut changed = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let (px, py) = self.center_m(cx, cy);
                let (dx, dy) = (px - robot.x_m, py - robot.y_m);
                let dist = norm2(dx, dy);
                if dist < r_min || dist > r_max {
                    continue;
                }
                let old = self.data(cx, cy).map(|d| d.class).unwrap_or_default();
                if old != Class::Unknown && old != Class::NegativeObstacle {
                    continue;
                }
                if self
                    .data(cx, cy)
                    .is_some_and(|d| d.evidence().n > 0 || d.driven)
                {
                    continue;
                }
                let (ux, uy) = (dx / dist, dy / dist);
                // The neighbour nearest the robot must be observed, drivable ground (or the lip
                // this pass marked before: observed ground too). A neighbour, not the cell one
                // step along the ray: on an oblique ray that step often lands beside the edge.
                let is_ground = |d: &CellData| {
                    d.class == Class::Traversable
                        || (d.class == Class::NegativeObstacle && (d.evidence().n > 0 || d.driven))
                };
                let mut best: Option<(f64, i64, i64)> = None;
                for (ex, ey) in [
                    (1, 0),
                    (-1, 0),
                    (0, 1),
                    (0, -1),
                    (1, 1),
                    (1, -1),
                    (-1, 1),
                    (-1, -1),
                ] {
                    let (nx, ny) = (cx + ex, cy + ey);
                    if !self.data(nx, ny).is_some_and(is_ground) {
                        continue;
                    }
                    let (qx, qy) = self.center_m(nx, ny);
                    let dq = norm2(qx - robot.x_m, qy - robot.y_m);
                    if dq < dist && best.is_none_or(|b| dq < b.0) {
                        best = Some((dq, nx, ny));
                    }
                }
                let Some((_, bx, by)) = best else {
                    continue;
                };
                let Some(edge) = self.data(bx, by) else {
                    continue;
                };
                let edge_was_lip = edge.class == Class::NegativeObstacle;
                let h_edge = if edge.evidence().n > 0 {
                    edge.evidence().stats().mean_m
                } else {
                    f64::from(edge.driven_z)
                };
                // Walk outwards: the first observed cell beyond tells whether the surface continues.
                let mut drop = true;
                for k in 1..=beyond_cells {
                    let (qx, qy) = self
                        .lattice
                        .cell_of(px + ux * l * k as f64, py + uy * l * k as f64);
                    if let Some(q) = self
                        .data(qx, qy)
                        .filter(|q| q.evidence().n >= self.rules.min_points())
                    {
                        let h_q = q.evidence().stats().mean_m;
                        // Lower than a step plus half the steepest drivable slope over the
                        // unseen gap: a slope that steep would have been seen from here.
                        drop = h_q < h_edge - drop_m - l * (k + 1) as f64 * 0.5 * tan_phi;
                        break;
                    }
                }
                // A drop seen from close by is not undone by a look from farther away (the
                // shadow behind an edge grows with distance and blurs into a slope).
                let marked_at = self.data(cx, cy).map_or(f32::INFINITY, |d| d.neg_range_m);
                if !drop && old == Class::NegativeObstacle && dist as f32 > marked_at + 1.0 {
                    continue;
                }
                let new = if drop {
                    Class::NegativeObstacle
                } else {
                    Class::Unknown
                };
                if drop {
                    let d = self.data_mut(cx, cy);
                    d.neg_range_m = d.neg_range_m.min(dist as f32);
                } else if old == Class::NegativeObstacle {
                    self.data_mut(cx, cy).neg_range_m = f32::INFINITY;
                }
                if new != old {
                    self.data_mut(cx, cy).class = new;
                    changed.push((cx, cy));
                }
                // The edge cell holds the lip of the drop: a wheel there is over it. A lip whose
                // drop turned out to be a ring gap goes back to what its own evidence says.
                if drop {
                    let e = self.data_mut(bx, by);
                    if e.class == Class::Traversable && !e.driven {
                        e.class = Class::NegativeObstacle;
                        changed.push((bx, by));
                    }
                } else if edge_was_lip && !self.beside_drop(bx, by) {
                    let mut v = self.rules.classify(&self.neighbourhood(bx, by)).class();
                    let e = self.data_mut(bx, by);
                    if e.driven {
                        v = Class::Traversable;
                    } else if v == Class::Traversable && !e.headroom {
                        v = Class::Overhung;
                    }
                    e.class = v;
                    changed.push((bx, by));
                }
            }
        }
        changed
    }

    /// True when an 8-neighbour is a drop-off without evidence enough to be observed.
    pub(super) fn beside_drop(&self, cx: i64, cy: i64) -> bool {
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                (dx != 0 || dy != 0)
                    && self.data(cx + dx, cy + dy).is_some_and(|n| {
                        n.class == Class::NegativeObstacle
                            && n.evidence().n < self.rules.min_points()
                            && !n.driven
                    })
            })
        })
    }
}
