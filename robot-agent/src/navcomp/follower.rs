//! A navigation computer that drives its robot along a waypoint list by itself (methods.md §7),
//! as the Orpheus robot's did: it takes a route list (`$NALST` ... `$NALST,END`) and edits
//! (`$CAREM`/`$CAINS`, the speed limit `$CASPD`) from the control application, steers by pure
//! pursuit along the list, and reports each waypoint it reaches (`$NAWPT`). `robot-agent sim
//! --serve-ros2 --nav-computer-listen` runs one on the simulated robot. No socket, no clock: the
//! caller feeds lines and poses.
//!
//! The waypoint it heads for keeps pointing at the same point through edits: a removal before it
//! shifts it down, an insertion before it shifts it up, and points inserted at its id come first
//! (a detour spliced in where the robot is heading is driven before the route it rejoins).

use common::geo::orpheus::{format_orpheus, parse_orpheus, OrpheusMessage, RoutePoint};
use common::geo::LocalFrame;
use common::geom::{wrap_angle, Pose2};
use common::msg::Datum;
use nalgebra::Vector3;

/// How the navigation computer drives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FollowerConfig {
    /// Speed at 100 %, m/s.
    pub v_max_mps: f64,
    /// Largest turn rate, rad/s.
    pub omega_max_rps: f64,
    /// Pure-pursuit look-ahead along the list, metres.
    pub lookahead_m: f64,
    /// A waypoint counts as reached this close, metres (or once passed).
    pub reach_radius_m: f64,
    /// The last waypoint counts as reached this close, metres.
    pub goal_tolerance_m: f64,
    /// Beyond this heading error the robot turns in place, radians.
    pub rotate_in_place_rad: f64,
}

impl Default for FollowerConfig {
    fn default() -> Self {
        Self {
            v_max_mps: 0.5,
            omega_max_rps: 0.5,
            lookahead_m: 0.8,
            reach_radius_m: 0.5,
            goal_tolerance_m: 0.25,
            rotate_in_place_rad: 0.8,
        }
    }
}

/// What the navigation computer received and did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct FollowerCounts {
    /// Complete lists taken.
    pub lists: u64,
    /// Waypoints removed by `$CAREM`.
    pub removed: u64,
    /// Waypoints inserted by `$CAINS`.
    pub inserted: u64,
    /// Speed limits taken.
    pub speeds: u64,
    /// Waypoints reached (`$NAWPT` sent).
    pub reached: u64,
    /// Lines refused.
    pub refused: u64,
}

/// See the module docs.
#[derive(Clone, Debug)]
pub struct WaypointFollower {
    cfg: FollowerConfig,
    frame: LocalFrame,
    route: Vec<RoutePoint>,
    /// The route in the local frame (east, north), metres.
    xy: Vec<(f64, f64)>,
    incoming: Vec<RoutePoint>,
    target: usize,
    speed_pct: u8,
    finished: bool,
    /// What it received and did.
    pub counts: FollowerCounts,
    /// Why the last refused line was refused.
    pub last_error: Option<String>,
}

impl WaypointFollower {
    /// A navigation computer working in the ENU frame at `datum` (where its robot's poses are),
    /// with no route and speed 0.
    pub fn new(cfg: FollowerConfig, datum: Datum) -> Self {
        Self {
            cfg,
            frame: LocalFrame::new(datum),
            route: Vec::new(),
            xy: Vec::new(),
            incoming: Vec::new(),
            target: 0,
            speed_pct: 0,
            finished: false,
            counts: FollowerCounts::default(),
            last_error: None,
        }
    }

    /// Takes one line from the control application; a refused one is counted with its reason.
    pub fn on_line(&mut self, line: &str) -> Result<(), String> {
        let r = self.handle(line);
        if let Err(e) = &r {
            self.counts.refused += 1;
            self.last_error = Some(e.clone());
        }
        r
    }

    fn handle(&mut self, line: &str) -> Result<(), String> {
        match parse_orpheus(line).map_err(|e| e.to_string())? {
            OrpheusMessage::RoutePoint(p) => {
                if p.id == 0 {
                    self.incoming.clear();
                } else if p.id as usize != self.incoming.len() {
                    return Err(format!(
                        "route point {} out of sequence (expected {})",
                        p.id,
                        self.incoming.len()
                    ));
                }
                self.incoming.push(p);
            }
            OrpheusMessage::RouteEnd => {
                self.route = std::mem::take(&mut self.incoming);
                self.target = 0;
                self.finished = false;
                self.counts.lists += 1;
                self.relocate();
            }
            OrpheusMessage::Remove(id) if (id as usize) < self.route.len() => {
                self.route.remove(id as usize);
                if (id as usize) < self.target {
                    self.target -= 1;
                }
                self.counts.removed += 1;
                self.relocate();
            }
            OrpheusMessage::Insert(p) if (p.id as usize) <= self.route.len() => {
                if (p.id as usize) < self.target {
                    self.target += 1;
                }
                self.route.insert(p.id as usize, p);
                self.finished = false;
                self.counts.inserted += 1;
                self.relocate();
            }
            OrpheusMessage::Remove(id) | OrpheusMessage::Insert(RoutePoint { id, .. }) => {
                return Err(format!(
                    "edit of waypoint {id}: the list has {}",
                    self.route.len()
                ))
            }
            OrpheusMessage::RemoveEnd | OrpheusMessage::InsertEnd => {}
            OrpheusMessage::SpeedLimit(p) => {
                self.speed_pct = p;
                self.counts.speeds += 1;
            }
            other => return Err(format!("unexpected {other:?} from the control application")),
        }
        Ok(())
    }

    fn relocate(&mut self) {
        for (i, p) in self.route.iter_mut().enumerate() {
            p.id = i as u32;
        }
        let frame = self.frame;
        self.xy = self
            .route
            .iter()
            .map(|p| {
                let e = frame.lla_to_enu(&Datum {
                    lat_deg: p.lat_deg,
                    lon_deg: p.lon_deg,
                    h_m: frame.datum().h_m,
                });
                (e.x, e.y)
            })
            .collect();
        self.target = self.target.min(self.xy.len());
    }

    /// Whether it drives the robot now: a route not yet finished, and a speed above 0.
    pub fn active(&self) -> bool {
        !self.finished && self.target < self.xy.len() && self.speed_pct > 0
    }

    /// The route, the waypoint it heads for, and the speed limit in percent.
    pub fn state(&self) -> (&[RoutePoint], usize, u8) {
        (&self.route, self.target, self.speed_pct)
    }

    /// The command `(v m/s, omega rad/s)` for the robot at `pose` (local frame), and the
    /// `$NAWPT` sentences of the waypoints it reached.
    pub fn step(&mut self, pose: &Pose2) -> ((f64, f64), Vec<String>) {
        let r = (pose.x_m, pose.y_m);
        let mut reports = Vec::new();
        let n = self.xy.len();
        while !self.finished && self.target < n {
            let k = self.target;
            let d = dist(r, self.xy[k]);
            let reached = if k + 1 == n {
                d <= self.cfg.goal_tolerance_m
            } else {
                d <= self.cfg.reach_radius_m || self.passed(r, k)
            };
            if !reached {
                break;
            }
            reports.push(format_orpheus(&OrpheusMessage::WaypointReached(k as u32)));
            self.counts.reached += 1;
            if k + 1 == n {
                self.finished = true;
            } else {
                self.target += 1;
            }
        }
        if !self.active() {
            return ((0.0, 0.0), reports);
        }
        (self.pursue(pose), reports)
    }

    /// The robot is beyond waypoint `k` along the segment to the next, and near it.
    fn passed(&self, r: (f64, f64), k: usize) -> bool {
        let (p, q) = (self.xy[k], self.xy[k + 1]);
        let (dx, dy) = (q.0 - p.0, q.1 - p.1);
        let len2 = dx * dx + dy * dy;
        len2 > 1e-9
            && ((r.0 - p.0) * dx + (r.1 - p.1) * dy) / len2 > 0.0
            && dist(r, p) < 2.0 * self.cfg.reach_radius_m
    }

    /// Pure pursuit on the list from the robot's projection on the segment it is on.
    fn pursue(&self, pose: &Pose2) -> (f64, f64) {
        let c = &self.cfg;
        let r = (pose.x_m, pose.y_m);
        let k = self.target;
        let start = if k > 0 {
            project(r, self.xy[k - 1], self.xy[k])
        } else {
            r
        };
        let mut left = c.lookahead_m;
        let mut at = start;
        let mut carrot = self.xy[self.xy.len() - 1];
        for &q in &self.xy[k..] {
            let d = dist(at, q);
            if d >= left {
                let f = left / d;
                carrot = (at.0 + f * (q.0 - at.0), at.1 + f * (q.1 - at.1));
                break;
            }
            left -= d;
            at = q;
        }
        let alpha = wrap_angle((carrot.1 - r.1).atan2(carrot.0 - r.0) - pose.yaw_rad);
        if alpha.abs() > c.rotate_in_place_rad {
            return (0.0, c.omega_max_rps.copysign(alpha));
        }
        let mut v = c.v_max_mps * f64::from(self.speed_pct) / 100.0;
        // Slow down into the last waypoint so it is reached, not overshot.
        let to_end = dist(r, self.xy[self.xy.len() - 1]);
        if k + 1 == self.xy.len() {
            v = v.min(0.6 * to_end + 0.05);
        }
        let ld = dist(r, carrot).max(0.1);
        let curvature = 2.0 * alpha.sin() / ld;
        let mut w = v * curvature;
        if w.abs() > c.omega_max_rps {
            v *= c.omega_max_rps / w.abs();
            w = c.omega_max_rps.copysign(w);
        }
        (v, w)
    }
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

/// The point of segment `a`-`b` nearest to `p`.
fn project(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    if len2 < 1e-12 {
        return a;
    }
    let t = (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0);
    (a.0 + t * dx, a.1 + t * dy)
}

/// `(east, north)` of a latitude/longitude in the frame at `datum` (for tests and tools).
pub fn to_local(datum: Datum, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
    let e = LocalFrame::new(datum).lla_to_enu(&Datum {
        lat_deg,
        lon_deg,
        h_m: datum.h_m,
    });
    (e.x, e.y)
}

/// The latitude/longitude of `(east, north)` in the frame at `datum` (for tests and tools).
pub fn to_lat_lon(datum: Datum, x_m: f64, y_m: f64) -> (f64, f64) {
    let d = LocalFrame::new(datum).enu_to_lla(&Vector3::new(x_m, y_m, 0.0));
    (d.lat_deg, d.lon_deg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::navcomp::OrpheusGateway;

    const DATUM: Datum = Datum {
        lat_deg: 47.3769,
        lon_deg: 8.5417,
        h_m: 408.0,
    };

    fn follower_with(points: &[(f64, f64)], pct: u8) -> WaypointFollower {
        let mut f = WaypointFollower::new(FollowerConfig::default(), DATUM);
        let ll: Vec<(f64, f64)> = points
            .iter()
            .map(|(x, y)| to_lat_lon(DATUM, *x, *y))
            .collect();
        let mut gw = OrpheusGateway::new();
        for l in gw.send_list(&ll, 0.05) {
            f.on_line(&l).unwrap();
        }
        f.on_line(&OrpheusGateway::speed_limit(pct)).unwrap();
        f
    }

    /// Drives a unicycle by the follower's commands; returns the track.
    fn drive(f: &mut WaypointFollower, mut p: Pose2, seconds: f64) -> (Pose2, Vec<(f64, f64)>) {
        let dt = 0.02;
        let mut track = Vec::new();
        for _ in 0..(seconds / dt) as usize {
            let ((v, w), _) = f.step(&p);
            p = Pose2::new(
                p.x_m + v * p.yaw_rad.cos() * dt,
                p.y_m + v * p.yaw_rad.sin() * dt,
                wrap_angle(p.yaw_rad + w * dt),
            );
            track.push((p.x_m, p.y_m));
        }
        (p, track)
    }

    #[test]
    fn follows_a_list_to_its_end_reporting_every_waypoint() {
        let pts: Vec<(f64, f64)> = (0..=8).map(|i| (f64::from(i), 0.0)).collect();
        let mut f = follower_with(&pts, 100);
        assert!(f.active());
        // Starting behind the line, turned away: it turns, joins and stops at the end.
        let (end, track) = drive(&mut f, Pose2::new(-0.5, 0.3, 3.0), 40.0);
        assert!(
            dist((end.x_m, end.y_m), (8.0, 0.0)) <= 0.25,
            "ends at the last point: {end:?}"
        );
        assert!(!f.active());
        assert_eq!(f.counts.reached, 9);
        let past_join: Vec<f64> = track
            .iter()
            .filter(|p| p.0 > 3.0)
            .map(|p| p.1.abs())
            .collect();
        assert!(
            past_join.iter().all(|d| *d < 0.05),
            "on the line: {:?}",
            past_join.iter().cloned().fold(0.0, f64::max)
        );
    }

    #[test]
    fn speed_zero_holds_and_edits_keep_the_target_on_the_same_point() {
        let pts: Vec<(f64, f64)> = (0..=6).map(|i| (f64::from(i), 0.0)).collect();
        let mut f = follower_with(&pts, 0);
        assert_eq!(f.step(&Pose2::new(0.0, 0.0, 0.0)).0, (0.0, 0.0));
        f.on_line(&OrpheusGateway::speed_limit(50)).unwrap();
        let (p, _) = drive(&mut f, Pose2::new(0.0, 0.0, 0.0), 5.0);
        assert!(p.x_m > 1.0 && p.x_m < 2.5, "{p:?}");
        let target_before = f.state().1;
        assert_eq!(target_before, 2);
        // A detour replaces points 3..5 by two points off the line: the target (2) stays on
        // its point; after it come the detour points.
        let mut gw = OrpheusGateway::new();
        let ll: Vec<(f64, f64)> = pts.iter().map(|(x, y)| to_lat_lon(DATUM, *x, *y)).collect();
        gw.send_list(&ll, 0.05);
        let detour = [to_lat_lon(DATUM, 3.5, 1.0), to_lat_lon(DATUM, 4.5, 1.0)];
        for l in gw.splice(3, 5, &detour, 0.05).unwrap() {
            f.on_line(&l).unwrap();
        }
        assert_eq!(f.state().1, 2);
        assert_eq!(f.state().0.len(), 7);
        let (end, track) = drive(&mut f, p, 30.0);
        assert!(track.iter().any(|q| q.1 > 0.8), "drove the detour");
        assert!(dist((end.x_m, end.y_m), (6.0, 0.0)) <= 0.25, "{end:?}");
        // Removing the point it heads for makes the next one the target.
        let mut f = follower_with(&pts, 100);
        drive(&mut f, Pose2::new(0.0, 0.0, 0.0), 2.5);
        let t = f.state().1;
        f.on_line(&common::geo::nmea::frame(&format!("CAREM,{t}")))
            .unwrap();
        assert_eq!(f.state().1, t);
        assert!(f.on_line("$CAREM,99*00").is_err());
        assert!(f
            .on_line(&common::geo::nmea::frame("CAREM,99"))
            .unwrap_err()
            .contains("the list has"));
        assert_eq!(f.counts.refused, 2);
    }
}
