//! Repeat: follow a taught route, forward or in reverse, around obstacles that appeared since
//! (docs/algorithms.md §7.2, the Orpheus use case).
//!
//! Per cycle, on the current planning grid:
//! 1. advance past waypoints the robot has reached;
//! 2. skip redundant points: when a later route point within `skip_radius_m` of the robot is
//!    visible in a straight line, the points in between are dropped (loops left by the teach drive);
//! 3. push points that lie in non-traversable cells away along the clearance gradient, up to
//!    `push_max_m`;
//! 4. check the corridor ahead (`check_ahead_m`) against the grid, which the mapper inflated by the
//!    robot's half width; if blocked, plan the shortest detour with A* (unknown cells assumed
//!    traversable) to the first reachable taught point past the blockage, resample it at the
//!    waypoint spacing and splice it in. Only a blocked route is replanned: where the route is
//!    free it is followed exactly as taught, even where it looks suboptimal.
//!
//! A blockage is acted on only once it has stayed put for `blockage_confirm_s`: a person
//! crossing or walking along the route is waited for (the robot holds `detour_lead_m` before
//! it), not driven around, and a detour never chases something that moves. After
//! `blockage_wait_max_s` of holding, the robot detours around whatever is there.

use common::geom::Pose2;
use planning::smooth::{point_free, segment_free};
use planning::{PlanGrid, Planner, SearchLimits};
use serde::Deserialize;

/// Repeat parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RepeatConfig {
    /// A waypoint counts as reached within this distance, metres.
    pub reached_radius_m: f64,
    /// Later route points this close to the robot may be jumped to when visible, metres.
    pub skip_radius_m: f64,
    /// Length of route ahead checked against the grid each cycle, metres.
    pub check_ahead_m: f64,
    /// The corridor checked along the route is the robot's half width plus this, metres.
    pub corridor_margin_m: f64,
    /// How far a point in a non-traversable cell may be pushed, metres.
    pub push_max_m: f64,
    /// Spacing of detour waypoints, metres.
    pub waypoint_spacing_m: f64,
    /// How far past a blockage rejoin points are searched, metres.
    pub rejoin_search_m: f64,
    /// Rejoin points closer than this to the blockage are not used (the robot body needs room
    /// to turn back onto the route), metres.
    pub rejoin_min_past_m: f64,
    /// A detour leaves the route this far (along it) before the first blocked point, so the
    /// route is followed exactly up to the obstacle even when the blockage is seen from afar,
    /// metres.
    pub detour_lead_m: f64,
    /// Distance at which the final waypoint counts as reached, metres.
    pub goal_tolerance_m: f64,
    /// Pure-pursuit look-ahead while repeating, metres: shorter than for goals, because a
    /// taught route is to be followed to the centimetre, corners included.
    pub lookahead_m: f64,
    /// Heading error beyond which the robot turns in place while repeating, radians: a robot
    /// that sets off with a large heading error swings off the route.
    pub rotate_in_place_rad: f64,
    /// A blockage must stay within `blockage_still_m` of where it was first seen this long
    /// before a detour is planned around it, seconds.
    pub blockage_confirm_s: f64,
    /// How far the first blocked point may move and still count as the same, still blockage,
    /// metres.
    pub blockage_still_m: f64,
    /// After holding this long in front of a blockage that keeps moving, detour anyway, seconds.
    pub blockage_wait_max_s: f64,
    /// With the teach-time view of the route: an obstacle cell on the corridor blocks only when
    /// something stands this much higher than what stood there at teach time, metres.
    pub new_obstacle_rise_m: f64,
    /// ...judged on the cell's newest evidence epoch alone once that holds this many returns
    /// (older epochs can hold a person who has walked on).
    pub newest_evidence_min_points: u32,
    /// A safety stop that holds this long blocks the route where its nearest point stands, so
    /// the repeat waits and then detours as for a blockage on the map (a person standing at the
    /// robot's shoulder, waiting for it to pass, would otherwise wait forever with it), seconds.
    pub safety_stop_block_s: f64,
    /// A detour is planned only once the blockage is this close along the route (until then the
    /// robot drives on towards it), metres.
    pub detour_plan_within_m: f64,
}

impl Default for RepeatConfig {
    fn default() -> Self {
        Self {
            reached_radius_m: 0.6,
            skip_radius_m: 1.0,
            check_ahead_m: 8.0,
            corridor_margin_m: 0.0,
            push_max_m: 0.6,
            waypoint_spacing_m: 1.0,
            rejoin_search_m: 20.0,
            rejoin_min_past_m: 0.5,
            detour_lead_m: 1.5,
            goal_tolerance_m: 0.3,
            lookahead_m: 0.6,
            rotate_in_place_rad: 0.35,
            blockage_confirm_s: 2.0,
            blockage_still_m: 0.6,
            blockage_wait_max_s: 20.0,
            new_obstacle_rise_m: 0.15,
            newest_evidence_min_points: 10,
            safety_stop_block_s: 3.0,
            detour_plan_within_m: 5.0,
        }
    }
}

/// One waypoint of the route being repeated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Waypoint {
    /// Map position, metres (pushed off an obstacle, or where it was taught or planned).
    pub p: (f64, f64),
    /// Where it was taught or planned: a push is undone when the obstacle goes (a person who
    /// walked along the route pushed a run of points 16 cm aside for the rest of the return).
    pub home: (f64, f64),
    /// Index in the taught route (driving order), None for detour points.
    pub taught: Option<usize>,
}

/// A detour spliced into the route.
#[derive(Clone, Debug, PartialEq)]
pub struct Detour {
    /// Taught index of the first blocked route point.
    pub blocked_taught: usize,
    /// Taught index where the detour rejoins the route.
    pub rejoin_taught: usize,
    /// Where it rejoins, map frame.
    pub rejoin_m: (f64, f64),
    /// Where the route was first blocked, map frame.
    pub blocked_m: (f64, f64),
    /// Detour length, metres.
    pub length_m: f64,
    /// Times this detour was re-planned before the robot rejoined (the obstacle's far side
    /// coming into view moves the rejoin point).
    pub replans: u32,
}

/// State of a repeat after a cycle.
#[derive(Clone, Debug, PartialEq)]
pub enum RepeatState {
    /// Following the route.
    Following,
    /// The route ahead is blocked by something that has not stayed put yet; the robot holds
    /// `detour_lead_m` before it (or drives on while farther).
    Waiting {
        /// The first blocked point, map frame.
        at_m: (f64, f64),
        /// Whether the robot is holding (stopped) for it.
        holding: bool,
    },
    /// The route ahead is blocked and no detour exists (yet); the robot holds.
    Blocked(String),
    /// The last waypoint is reached.
    Finished,
}

/// Follows a taught route.
#[derive(Debug)]
pub struct RouteFollower {
    cfg: RepeatConfig,
    wps: Vec<Waypoint>,
    next: usize,
    taught_len: usize,
    /// Detours spliced so far (one per blockage; re-plans of a detour still being driven
    /// update it).
    pub detours: Vec<Detour>,
    /// Whether the robot is on the last detour, not yet back on the route.
    on_detour: bool,
    /// A blockage seen and not yet detoured.
    pending: Option<Pending>,
    /// Whether the robot must stand still (in front of a blockage).
    holding: bool,
    planner: Planner,
}

/// A blockage being watched: where, since when it has been still there, since when the robot
/// holds for it.
#[derive(Clone, Copy, Debug)]
struct Pending {
    at_m: (f64, f64),
    still_since_s: f64,
    holding_since_s: Option<f64>,
}

impl RouteFollower {
    /// Starts following `route_m` (already in driving order: reversed for a return home) from
    /// the route point nearest to the robot.
    pub fn new(cfg: RepeatConfig, route_m: &[(f64, f64)], robot: &Pose2) -> Self {
        let wps: Vec<Waypoint> = route_m
            .iter()
            .enumerate()
            .map(|(i, p)| Waypoint {
                p: *p,
                home: *p,
                taught: Some(i),
            })
            .collect();
        let next = nearest(&wps, (robot.x_m, robot.y_m));
        Self {
            cfg,
            taught_len: wps.len(),
            wps,
            next,
            detours: Vec::new(),
            on_detour: false,
            pending: None,
            holding: false,
            planner: Planner::new(),
        }
    }

    /// The remaining waypoints, robot first: what the path follower tracks.
    pub fn path_ahead(&self, robot: &Pose2) -> Vec<(f64, f64)> {
        std::iter::once((robot.x_m, robot.y_m))
            .chain(
                self.wps[self.next.min(self.wps.len())..]
                    .iter()
                    .map(|w| w.p),
            )
            .collect()
    }

    /// The path the controller tracks: the route line itself from the waypoint just passed
    /// (so cross-track feedback pulls the robot onto the taught line, not onto the chord from
    /// wherever it is), or from the robot when it is off the route.
    pub fn follow_path(&self, robot: &Pose2) -> Vec<(f64, f64)> {
        let r = (robot.x_m, robot.y_m);
        let next = self.next.min(self.wps.len());
        if next > 0 && next < self.wps.len() {
            let (a, b) = (self.wps[next - 1].p, self.wps[next].p);
            if segment_distance_m(a, b, r) <= self.cfg.reached_radius_m {
                return self.wps[next - 1..].iter().map(|w| w.p).collect();
            }
        }
        self.path_ahead(robot)
    }

    /// All waypoints (taught and spliced).
    pub fn waypoints(&self) -> &[Waypoint] {
        &self.wps
    }

    /// The first blocked point of the route ahead being watched, if any (diagnostics).
    pub fn blockage_m(&self) -> Option<(f64, f64)> {
        self.pending.as_ref().map(|p| p.at_m)
    }

    /// True while the robot follows a spliced-in detour (until it is back on the route).
    pub fn on_detour(&self) -> bool {
        self.on_detour
    }

    /// (next waypoint index, waypoint count, distance left along the route in metres).
    pub fn progress(&self, robot: &Pose2) -> (usize, usize, f64) {
        let ahead = self.path_ahead(robot);
        let left = ahead.windows(2).map(|w| dist(w[0], w[1])).sum();
        (self.next, self.wps.len(), left)
    }

    /// Number of taught waypoints.
    pub fn taught_len(&self) -> usize {
        self.taught_len
    }

    /// Whether the robot must stand still: in front of a blockage it waits for, or one it
    /// cannot get around.
    pub fn holding(&self) -> bool {
        self.holding
    }

    /// One repeat cycle on the current grid at time `t_s` (seconds, any epoch).
    pub fn update(&mut self, robot: &Pose2, grid: &PlanGrid, t_s: f64) -> RepeatState {
        self.update_with_corridor(robot, grid, grid, t_s)
    }

    /// One repeat cycle: `corridor` decides whether the route ahead is blocked (obstacles
    /// within the robot's half width of the taught line; the robot drove there, so the planner's
    /// wider inflation margins must not call a free route blocked), `grid` is what detours are
    /// planned on.
    pub fn update_with_corridor(
        &mut self,
        robot: &Pose2,
        grid: &PlanGrid,
        corridor: &PlanGrid,
        t_s: f64,
    ) -> RepeatState {
        let r = (robot.x_m, robot.y_m);
        self.advance(r);
        self.holding = false;
        if self.next >= self.wps.len() {
            return RepeatState::Finished;
        }
        if self.next == self.wps.len() - 1
            && dist(r, self.wps[self.next].p) <= self.cfg.goal_tolerance_m
        {
            self.next = self.wps.len();
            return RepeatState::Finished;
        }
        self.skip_redundant(r, grid);
        // Back on the route once the next waypoint is the rejoin point or past it.
        if let (Some(d), Some(w)) = (self.detours.last(), self.wps.get(self.next)) {
            if w.taught.is_some_and(|t| t > d.rejoin_taught) {
                self.on_detour = false;
            }
        }
        self.push_points(corridor);
        let Some(b) = self.first_blocked(r, corridor) else {
            self.pending = None;
            return RepeatState::Following;
        };
        let (s_hit, at_m) = self
            .first_blocked_sample(r, corridor)
            .map_or_else(|| (self.along_to(r, b), self.wps[b].p), |(_, s, q)| (s, q));
        let cfg = &self.cfg;
        let p = self.pending.get_or_insert(Pending {
            at_m,
            still_since_s: t_s,
            holding_since_s: None,
        });
        if dist(p.at_m, at_m) > cfg.blockage_still_m {
            p.at_m = at_m;
            p.still_since_s = t_s;
        }
        let close = s_hit <= cfg.detour_lead_m;
        if close {
            p.holding_since_s.get_or_insert(t_s);
        }
        let still = t_s - p.still_since_s >= cfg.blockage_confirm_s;
        let waited_out = p
            .holding_since_s
            .is_some_and(|h| t_s - h >= cfg.blockage_wait_max_s);
        // A blockage seen from afar is judged on sparse returns (and may be what a person left
        // in the map a moment ago): drive on and decide from close by.
        let near_enough = s_hit <= cfg.detour_plan_within_m;
        if !(still || waited_out) || !near_enough {
            self.holding = close;
            return RepeatState::Waiting {
                at_m,
                holding: close,
            };
        }
        match self.splice_detour(r, b, grid, corridor) {
            Ok(()) => {
                self.pending = None;
                RepeatState::Following
            }
            Err(why) => {
                self.holding = true;
                RepeatState::Blocked(why)
            }
        }
    }

    fn advance(&mut self, r: (f64, f64)) {
        while self.next < self.wps.len() {
            let p = self.wps[self.next].p;
            let reached = dist(r, p) <= self.cfg.reached_radius_m && self.next + 1 < self.wps.len();
            // Passed: the robot is beyond the point along the segment to the following one.
            let passed = self.next + 1 < self.wps.len() && {
                let q = self.wps[self.next + 1].p;
                let (dx, dy) = (q.0 - p.0, q.1 - p.1);
                let len2 = dx * dx + dy * dy;
                len2 > 1e-9
                    && ((r.0 - p.0) * dx + (r.1 - p.1) * dy) / len2 > 0.0
                    && dist(r, p) < 2.0 * self.cfg.reached_radius_m.max(1.0)
            };
            if reached || passed {
                self.next += 1;
            } else {
                break;
            }
        }
        // A robot that cut a corner or overshot a zig-zag (a detour's tail doubling back to its
        // rejoin point) is nearer to a later stretch of the route than to the waypoint it
        // heads for: it goes on from there instead of turning back. Only the next few metres
        // are searched, so a route passing near itself is not short-cut.
        let window = 3.0 * self.cfg.reached_radius_m.max(1.0);
        let (mut along, mut best) = (0.0, None::<(usize, f64)>);
        for i in self.next.max(1)..self.wps.len() {
            let (a, b) = (self.wps[i - 1].p, self.wps[i].p);
            let d = segment_distance_m(a, b, r);
            if best.is_none_or(|(_, bd)| d < bd - 1e-9) {
                best = Some((i, d));
            }
            along += dist(a, b);
            if along > window {
                break;
            }
        }
        if let Some((i, d)) = best {
            let current = if self.next >= 1 && self.next < self.wps.len() {
                segment_distance_m(self.wps[self.next - 1].p, self.wps[self.next].p, r)
            } else {
                f64::INFINITY
            };
            if i > self.next && d <= self.cfg.reached_radius_m && d < current - 0.05 {
                self.next = i;
            }
        }
    }

    fn skip_redundant(&mut self, r: (f64, f64), grid: &PlanGrid) {
        let mut along = 0.0;
        let mut best = None;
        for j in self.next + 1..self.wps.len() {
            along += dist(self.wps[j - 1].p, self.wps[j].p);
            let d = dist(r, self.wps[j].p);
            // Only a point that is near in space but far along the route is redundant.
            if d <= self.cfg.skip_radius_m
                && along > d + 2.0 * self.cfg.skip_radius_m
                && segment_free(grid, r, self.wps[j].p)
            {
                best = Some(j);
            }
            if along > self.cfg.rejoin_search_m * 3.0 {
                break;
            }
        }
        if let Some(j) = best {
            self.next = j;
        }
    }

    fn push_points(&mut self, grid: &PlanGrid) {
        let mut along = 0.0;
        for i in self.next..self.wps.len() {
            if i > self.next {
                along += dist(self.wps[i - 1].p, self.wps[i].p);
            }
            if along > self.cfg.check_ahead_m {
                break;
            }
            let home = self.wps[i].home;
            if point_free(grid, home) {
                self.wps[i].p = home;
                continue;
            }
            if let Some(q) = push_free(grid, home, self.cfg.push_max_m) {
                self.wps[i].p = q;
            }
        }
    }
}

mod detour;
mod geometry;
#[cfg(test)]
mod tests;

use common::zone::segment_distance_m;
use geometry::{dist, nearest, push_free};
