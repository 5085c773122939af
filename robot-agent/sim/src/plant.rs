//! Differential-drive plant: velocity, wheel and acceleration limits, terrain following (height,
//! pitch and roll from the four wheel contacts), and collision detection.
//!
//! A move is refused (the robot stops where it is) when, at the candidate pose, the footprint
//! overlaps a solid below the robot's height plus clearance or a walker, the leading edge faces a
//! step up of `max_step_m` or more (`Step`) or a drop of as much (`DropOff`) within 0.1 m ahead,
//! the tilt exceeds `max_slope_deg` + 2 deg (`TooSteep`), or the footprint leaves the world.
//! Every contact is reported once when it begins (edge-triggered per kind and object) and counted.

use crate::world::{Obb, WalkerState, World};
use common::geom::Pose2;
use common::robot::RobotProfile;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// What the robot ran into.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[non_exhaustive]
pub enum CollisionKind {
    /// A static solid (wall, pole, trunk, box, car).
    Obstacle,
    /// A walker.
    Walker,
    /// A step up too high to climb.
    Step,
    /// A drop-off or hole edge.
    DropOff,
    /// Terrain steeper than the robot can hold.
    TooSteep,
    /// The edge of the simulated world.
    OutOfWorld,
}

/// One collision event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collision {
    /// Simulation time, seconds.
    pub t_s: f64,
    /// What kind.
    pub kind: CollisionKind,
    /// Solid index (`Obstacle`), walker id (`Walker`), else 0.
    pub object: usize,
    /// Robot x when it happened, metres (map frame).
    pub x_m: f64,
    /// Robot y, metres.
    pub y_m: f64,
    /// Step height, drop depth (metres) or tilt (degrees) where meaningful, else 0.
    pub detail: f64,
}

#[derive(Clone, Copy, Debug)]
struct Contact {
    kind: CollisionKind,
    object: usize,
    x_m: f64,
    y_m: f64,
}

/// The plant's state.
#[derive(Clone, Debug)]
pub struct Plant {
    profile: RobotProfile,
    pose: Pose2,
    v_mps: f64,
    omega_rps: f64,
    z_m: f64,
    pitch_rad: f64,
    roll_rad: f64,
    active: Vec<Contact>,
    collisions_total: u64,
}

impl Plant {
    /// A robot standing still at `start` on the world's ground.
    pub fn new(profile: &RobotProfile, start: Pose2, world: &World) -> Self {
        let mut p = Self {
            profile: profile.clone(),
            pose: start,
            v_mps: 0.0,
            omega_rps: 0.0,
            z_m: 0.0,
            pitch_rad: 0.0,
            roll_rad: 0.0,
            active: Vec::new(),
            collisions_total: 0,
        };
        if let Some((z, pitch, roll)) = p.attitude(world, &start) {
            p.z_m = z;
            p.pitch_rad = pitch;
            p.roll_rad = roll;
        }
        p
    }

    /// Planar pose of `base_link` in the map frame.
    pub fn pose2(&self) -> Pose2 {
        self.pose
    }

    /// Current forward speed, m/s.
    pub fn v_mps(&self) -> f64 {
        self.v_mps
    }

    /// Current turn rate, rad/s.
    pub fn omega_rps(&self) -> f64 {
        self.omega_rps
    }

    /// Pitch (positive nose down) and roll (positive left side up), radians.
    pub fn pitch_roll_rad(&self) -> (f64, f64) {
        (self.pitch_rad, self.roll_rad)
    }

    /// Collisions reported so far.
    pub fn collisions_total(&self) -> u64 {
        self.collisions_total
    }

    /// `map <- base_link`.
    pub fn pose3(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.pose.x_m, self.pose.y_m, self.z_m),
            UnitQuaternion::from_euler_angles(self.roll_rad, self.pitch_rad, self.pose.yaw_rad),
        )
    }

    /// Height, pitch and roll at a planar pose from the four wheel contacts.
    fn attitude(&self, world: &World, p: &Pose2) -> Option<(f64, f64, f64)> {
        let a = 0.5 * self.profile.wheelbase_m;
        let b = 0.5 * self.profile.track_width_m;
        let h = |x: f64, y: f64| {
            let (wx, wy) = p.transform_point(x, y);
            world.ground_height(wx, wy)
        };
        let (fl, fr, rl, rr) = (h(a, b)?, h(a, -b)?, h(-a, b)?, h(-a, -b)?);
        let z = 0.25 * (fl + fr + rl + rr);
        let pitch = -((0.5 * (fl + fr) - 0.5 * (rl + rr)) / (2.0 * a)).atan();
        let roll = ((0.5 * (fl + rl) - 0.5 * (fr + rr)) / (2.0 * b)).atan();
        Some((z, pitch, roll))
    }

    fn footprint(&self, p: &Pose2) -> Obb {
        Obb {
            cx: p.x_m,
            cy: p.y_m,
            hx: 0.5 * self.profile.length_m,
            hy: 0.5 * self.profile.width_m,
            yaw: p.yaw_rad,
        }
    }

    /// Advances by `dt_s` (ending at time `t_end_s`) under the command; returns new collisions.
    pub fn step(
        &mut self,
        world: &World,
        walkers: &[WalkerState],
        t_end_s: f64,
        dt_s: f64,
        cmd_v_mps: f64,
        cmd_omega_rps: f64,
    ) -> Vec<Collision> {
        let pr = &self.profile;
        let cmd_v = if cmd_v_mps.is_finite() {
            cmd_v_mps
        } else {
            0.0
        };
        let cmd_w = if cmd_omega_rps.is_finite() {
            cmd_omega_rps
        } else {
            0.0
        };
        let mut v_t = cmd_v.clamp(-pr.max_speed_mps, pr.max_speed_mps);
        let mut w_t = cmd_w.clamp(-pr.max_omega_rps, pr.max_omega_rps);
        // Wheel-speed saturation keeps the turning radius: scale both together.
        let half_track = 0.5 * pr.track_width_m;
        let wheel = v_t.abs() + w_t.abs() * half_track;
        if wheel > pr.max_wheel_speed_mps {
            let k = pr.max_wheel_speed_mps / wheel;
            v_t *= k;
            w_t *= k;
        }
        let dv = (v_t - self.v_mps).clamp(-pr.max_accel_mps2 * dt_s, pr.max_accel_mps2 * dt_s);
        let dw = (w_t - self.omega_rps).clamp(-pr.max_alpha_rps2 * dt_s, pr.max_alpha_rps2 * dt_s);
        let v = self.v_mps + dv;
        let w = self.omega_rps + dw;
        let cand = self
            .pose
            .integrate(0.5 * (self.v_mps + v), 0.5 * (self.omega_rps + w), dt_s);

        let mut hits: Vec<(CollisionKind, usize, f64)> = Vec::new();
        let moving = v.abs() > 1e-9 || w.abs() > 1e-9;
        let fp = self.footprint(&cand);
        let att = self.attitude(world, &cand);
        let corners_in = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .all(|&(a, b)| {
                let (x, y) = cand.transform_point(a * fp.hx, b * fp.hy);
                world.ground_height(x, y).is_some()
            });
        if moving {
            match att {
                Some((_, pitch, roll)) if corners_in => {
                    let tilt = pitch.abs().max(roll.abs()).to_degrees();
                    if tilt > pr.max_slope_deg + 2.0 {
                        hits.push((CollisionKind::TooSteep, 0, tilt));
                    }
                }
                _ => hits.push((CollisionKind::OutOfWorld, 0, 0.0)),
            }
            let (lo, hi) = ground_span(world, &cand, &fp);
            for (i, s) in world.solids().iter().enumerate() {
                let (bx, by, br) = s.bounds();
                if (bx - cand.x_m).hypot(by - cand.y_m) > br + 0.7 {
                    continue;
                }
                if s.z0_m <= hi + pr.height_m + pr.clearance_m
                    && s.z1_m >= lo - 0.05
                    && s.overlaps(&fp)
                {
                    hits.push((CollisionKind::Obstacle, i, 0.0));
                }
            }
            // Leading edge: probe 0.1 m ahead of five points across it.
            if v.abs() > 1e-9 {
                let dir = v.signum();
                let thr = pr.max_step_m - 0.01;
                let mut worst: (f64, Option<CollisionKind>) = (0.0, None);
                for k in 0..5 {
                    let ly = (k as f64 / 4.0 - 0.5) * 2.0 * fp.hy;
                    let lx = dir * fp.hx;
                    let (x0, y0) = cand.transform_point(lx, ly);
                    let (x1, y1) = cand.transform_point(lx + dir * 0.1, ly);
                    if let (Some(h0), Some(h1)) =
                        (world.ground_height(x0, y0), world.ground_height(x1, y1))
                    {
                        let j = h1 - h0;
                        if j.abs() >= thr && j.abs() > worst.0 {
                            worst = (
                                j.abs(),
                                Some(if j > 0.0 {
                                    CollisionKind::Step
                                } else {
                                    CollisionKind::DropOff
                                }),
                            );
                        }
                    }
                }
                if let (d, Some(kind)) = worst {
                    hits.push((kind, 0, d));
                }
            }
        }
        let blocked = !hits.is_empty();
        if blocked {
            self.v_mps = 0.0;
            self.omega_rps = 0.0;
        } else {
            self.pose = cand;
            self.v_mps = v;
            self.omega_rps = w;
            if let Some((z, pitch, roll)) = att {
                self.z_m = z;
                self.pitch_rad = pitch;
                self.roll_rad = roll;
            }
        }
        // Walkers touching the robot where it now stands (they walk into it too).
        let fp_now = self.footprint(&self.pose);
        for wk in walkers {
            if fp_now.distance_to(wk.x_m, wk.y_m) <= wk.radius_m {
                hits.push((CollisionKind::Walker, wk.id, 0.0));
            }
        }
        // Edge-triggered: a contact stays active while it persists, or (static kinds) while the
        // robot is within 0.15 m of where it began, so creeping against a wall is one event.
        let mut events = Vec::new();
        let (x_now, y_now) = (self.pose.x_m, self.pose.y_m);
        let mut still: Vec<Contact> = Vec::new();
        for c in &self.active {
            let persists = hits.iter().any(|h| h.0 == c.kind && h.1 == c.object);
            let near =
                c.kind != CollisionKind::Walker && (c.x_m - x_now).hypot(c.y_m - y_now) < 0.15;
            let walker_near = c.kind == CollisionKind::Walker
                && walkers.iter().any(|w| {
                    w.id == c.object && fp_now.distance_to(w.x_m, w.y_m) <= w.radius_m + 0.1
                });
            if persists || near || walker_near {
                still.push(*c);
            }
        }
        for &(kind, object, detail) in &hits {
            if still.iter().any(|c| c.kind == kind && c.object == object) {
                continue;
            }
            still.push(Contact {
                kind,
                object,
                x_m: x_now,
                y_m: y_now,
            });
            events.push(Collision {
                t_s: t_end_s,
                kind,
                object,
                x_m: x_now,
                y_m: y_now,
                detail,
            });
        }
        self.active = still;
        self.collisions_total += events.len() as u64;
        events
    }
}

fn ground_span(world: &World, p: &Pose2, fp: &Obb) -> (f64, f64) {
    let mut r = (f64::INFINITY, f64::NEG_INFINITY);
    for a in [-1.0, 0.0, 1.0] {
        for b in [-1.0, 0.0, 1.0] {
            let (x, y) = p.transform_point(a * fp.hx, b * fp.hy);
            if let Some(h) = world.ground_height(x, y) {
                r = (r.0.min(h), r.1.max(h));
            }
        }
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;

    fn world(extra: &str) -> World {
        World::new(
            &Scenario::from_toml_str(
                &format!(
                    r#"
name = "plant"
[datum]
lat_deg = 48.0
lon_deg = 16.0
h_m = 200.0
[extent]
x_min_m = -20.0
x_max_m = 20.0
y_min_m = -20.0
y_max_m = 20.0
[terrain]
undulation_amplitude_m = 0.0
{extra}
"#
                ),
                "t",
            )
            .unwrap(),
        )
    }

    #[test]
    fn limits_are_respected() {
        let w = world("");
        let prof = RobotProfile::default();
        let mut p = Plant::new(&prof, Pose2::default(), &w);
        let dt = 0.02;
        let mut prev_v = 0.0;
        let mut prev_w = 0.0;
        for k in 0..300 {
            let cmd = if k < 150 { (5.0, 4.0) } else { (-5.0, -4.0) };
            assert!(p.step(&w, &[], k as f64 * dt, dt, cmd.0, cmd.1).is_empty());
            let (v, om) = (p.v_mps(), p.omega_rps());
            assert!(v.abs() <= prof.max_speed_mps + 1e-9);
            assert!(om.abs() <= prof.max_omega_rps + 1e-9);
            assert!(
                v.abs() + om.abs() * 0.5 * prof.track_width_m <= prof.max_wheel_speed_mps + 1e-9
            );
            assert!((v - prev_v).abs() <= prof.max_accel_mps2 * dt + 1e-9);
            assert!((om - prev_w).abs() <= prof.max_alpha_rps2 * dt + 1e-9);
            prev_v = v;
            prev_w = om;
        }
        // It did reach the saturated command at some point.
        assert!(prev_v < -0.2);
    }

    #[test]
    fn driving_into_a_wall_is_a_collision() {
        let w = world("[[wall]]\npoints = [[3.0, -5.0], [3.0, 5.0]]\nheight_m = 2.0\n");
        let mut p = Plant::new(&RobotProfile::default(), Pose2::default(), &w);
        let mut events = Vec::new();
        for k in 0..500 {
            events.extend(p.step(&w, &[], k as f64 * 0.02, 0.02, 0.8, 0.0));
        }
        assert_eq!(events.len(), 1, "{events:?}");
        assert_eq!(events[0].kind, CollisionKind::Obstacle);
        // Stopped at the wall face (2.875) minus half the length, not through it.
        let x = p.pose2().x_m;
        assert!(x < 2.875 - 0.5 + 1e-6 && x > 2.2, "{x}");
        assert_eq!(p.collisions_total(), 1);
    }

    #[test]
    fn curbs_and_drop_offs() {
        let w = world(
            "[[step]]\nrect = { center_m = [5.0, 0.0], size_m = [4.0, 20.0] }\nheight_m = 0.05\n\
             [[step]]\nrect = { center_m = [5.0, 10.0], size_m = [4.0, 4.0] }\nheight_m = 0.15\n\
             [[platform]]\nrect = { center_m = [-8.0, 0.0], size_m = [6.0, 6.0] }\nheight_m = 0.8\n",
        );
        let prof = RobotProfile::default();
        // 5 cm: climbs it and follows the terrain.
        let mut p = Plant::new(&prof, Pose2::new(0.0, -3.0, 0.0), &w);
        for k in 0..400 {
            assert!(p.step(&w, &[], k as f64 * 0.02, 0.02, 0.5, 0.0).is_empty());
        }
        assert!(p.pose2().x_m > 3.5);
        // 15 cm: refused.
        let mut p = Plant::new(&prof, Pose2::new(0.0, 10.0, 0.0), &w);
        let mut ev = Vec::new();
        for k in 0..400 {
            ev.extend(p.step(&w, &[], k as f64 * 0.02, 0.02, 0.5, 0.0));
        }
        assert!(ev.iter().any(|e| e.kind == CollisionKind::Step), "{ev:?}");
        assert!(p.pose2().x_m < 3.0);
        // Off the platform edge: a drop-off.
        let mut p = Plant::new(&prof, Pose2::new(-8.0, 0.0, 0.0), &w);
        let mut ev = Vec::new();
        for k in 0..400 {
            ev.extend(p.step(&w, &[], k as f64 * 0.02, 0.02, 0.5, 0.0));
        }
        assert!(
            ev.iter().any(|e| e.kind == CollisionKind::DropOff),
            "{ev:?}"
        );
        assert!(p.pose2().x_m < -5.0);
        assert!((p.pose3().translation.vector.z - 0.8).abs() < 0.01);
    }
}
