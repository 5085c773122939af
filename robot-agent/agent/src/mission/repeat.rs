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
use planning::{CellXY, PlanGrid, Planner, SearchLimits};
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
            if point_segment_distance(r, a, b) <= self.cfg.reached_radius_m {
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
            let d = point_segment_distance(r, a, b);
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
                point_segment_distance(r, self.wps[self.next - 1].p, self.wps[self.next].p)
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

    /// Index of the first waypoint whose segment from its predecessor (or from the robot) is blocked.
    fn first_blocked(&self, r: (f64, f64), grid: &PlanGrid) -> Option<usize> {
        let mut prev = r;
        let mut along = 0.0;
        for i in self.next..self.wps.len() {
            let p = self.wps[i].p;
            if !segment_free(grid, prev, p) {
                return Some(i);
            }
            along += dist(prev, p);
            if along > self.cfg.check_ahead_m {
                break;
            }
            prev = p;
        }
        None
    }

    /// Distance from the robot along the route ahead to waypoint `j`, metres.
    fn along_to(&self, r: (f64, f64), j: usize) -> f64 {
        let mut prev = r;
        let mut along = 0.0;
        for w in &self.wps[self.next..=j.min(self.wps.len() - 1)] {
            along += dist(prev, w.p);
            prev = w.p;
        }
        along
    }

    /// The first blocked sample along the route ahead of the robot: (segment of the polyline
    /// robot-then-waypoints, distance along it, the point).
    fn first_blocked_sample(
        &self,
        r: (f64, f64),
        grid: &PlanGrid,
    ) -> Option<(usize, f64, (f64, f64))> {
        let step = grid.cell_size_m() / 8.0;
        let mut along = 0.0;
        let mut prev = r;
        for (m, w) in self.wps[self.next..].iter().enumerate() {
            let len = dist(prev, w.p);
            let n = (len / step).ceil().max(1.0) as usize;
            for k in 0..=n {
                let t = k as f64 / n as f64;
                let q = (prev.0 + t * (w.p.0 - prev.0), prev.1 + t * (w.p.1 - prev.1));
                if !point_free(grid, q) {
                    return Some((m, along + t * len, q));
                }
            }
            along += len;
            if along > self.cfg.check_ahead_m + self.cfg.detour_lead_m {
                break;
            }
            prev = w.p;
        }
        None
    }

    /// Where a detour should leave the route ahead: the route from the robot to its first
    /// blocked sample, backed off `detour_lead_m` along it. Returns (how many of the waypoints
    /// ahead are kept before the departure point, or None to depart from the robot; the
    /// departure point; the first blocked point).
    fn departure(&self, r: (f64, f64), grid: &PlanGrid) -> Departure {
        let ahead: Vec<(f64, f64)> = std::iter::once(r)
            .chain(self.wps[self.next..].iter().map(|w| w.p))
            .collect();
        let Some((hit_seg, s_hit, q_hit)) = self.first_blocked_sample(r, grid) else {
            return (None, r, None);
        };
        let s_dep = s_hit - self.cfg.detour_lead_m;
        if s_dep <= grid.cell_size_m() {
            return (None, r, Some(q_hit));
        }
        let mut along = 0.0;
        for (m, w) in ahead.windows(2).enumerate().take(hit_seg + 1) {
            let len = dist(w[0], w[1]);
            if along + len >= s_dep {
                let t = if len > 1e-9 {
                    (s_dep - along) / len
                } else {
                    0.0
                };
                let p = (
                    w[0].0 + t * (w[1].0 - w[0].0),
                    w[0].1 + t * (w[1].1 - w[0].1),
                );
                // ahead[1..=m] are waypoints next..next+m, all before the departure point.
                return (Some(m), p, Some(q_hit));
            }
            along += len;
        }
        (None, r, Some(q_hit))
    }

    fn splice_detour(
        &mut self,
        r: (f64, f64),
        blocked: usize,
        grid: &PlanGrid,
        corridor: &PlanGrid,
    ) -> Result<(), String> {
        // Where the detour leaves the route: `detour_lead_m` before the first blocked point,
        // or at the robot when it is already that close.
        let (keep, from, blocked_at) = self.departure(r, corridor);
        let start = grid
            .world_to_cell(from.0, from.1)
            .ok_or_else(|| "detour start is off the planning grid".to_string())?;
        // The departure point is on the driven line: free of obstacles, perhaps inside the
        // planner's inflation margin, which must not stop the detour from starting there.
        let own;
        let grid = if grid.is_free(i64::from(start.x), i64::from(start.y)) {
            grid
        } else if corridor.is_free(i64::from(start.x), i64::from(start.y)) {
            let mut g = grid.clone();
            g.set(i64::from(start.x), i64::from(start.y), 0.0, false);
            own = g;
            &own
        } else {
            return Err("robot is in a non-traversable cell".to_string());
        };
        let blocked_m = blocked_at.unwrap_or(self.wps[blocked].p);
        // Candidate rejoin points: past the blockage, in route order, free, with room past it.
        let mut along = 0.0;
        let mut first_clear_seen = false;
        for j in blocked..self.wps.len() {
            if j > blocked {
                along += dist(self.wps[j - 1].p, self.wps[j].p);
            }
            if along > self.cfg.rejoin_search_m {
                break;
            }
            let p = self.wps[j].p;
            // Only the taught route is rejoined: a point of an earlier detour is where the
            // robot went around something, and rejoining there chains detours off the route.
            if self.wps[j].taught.is_none() {
                continue;
            }
            if !point_free(grid, p) {
                first_clear_seen = false;
                continue;
            }
            // Skip the first free point right at the blockage's edge: rejoining there would
            // graze the obstacle; the next one leaves room.
            if !first_clear_seen && dist(p, blocked_m) < self.cfg.rejoin_min_past_m {
                first_clear_seen = true;
                continue;
            }
            // The rest of the route right after j must be free too, or the detour ends in a trap.
            if j + 1 < self.wps.len() && !segment_free(corridor, p, self.wps[j + 1].p) {
                continue;
            }
            let Some(goal) = grid.world_to_cell(p.0, p.1) else {
                continue;
            };
            let limits = SearchLimits {
                max_expansions: Some(200_000),
            };
            let Ok(path) = self
                .planner
                .plan_with(grid, start, goal, limits, &mut || false)
            else {
                continue;
            };
            let detour = resample(grid, &path.cells, self.cfg.waypoint_spacing_m, from, p);
            let length_m = detour.windows(2).map(|w| dist(w[0], w[1])).sum::<f64>();
            // From the robot the detour starts where it stands; from a departure point on the
            // route that point is a waypoint of its own.
            let first = if keep.is_some() { 0 } else { 1 };
            let spliced: Vec<Waypoint> = detour[first..detour.len() - 1]
                .iter()
                .map(|&p| Waypoint {
                    p,
                    home: p,
                    taught: None,
                })
                .collect();
            let d = Detour {
                blocked_taught: self.wps[blocked].taught.unwrap_or(blocked),
                rejoin_taught: self.wps[j].taught.unwrap_or(j),
                rejoin_m: p,
                blocked_m,
                length_m,
                replans: 0,
            };
            match self.detours.last_mut() {
                Some(last) if self.on_detour => {
                    *last = Detour {
                        blocked_taught: last.blocked_taught,
                        blocked_m: last.blocked_m,
                        replans: last.replans + 1,
                        ..d
                    };
                }
                _ => self.detours.push(d),
            }
            self.on_detour = true;
            let from_index = self.next + keep.unwrap_or(0);
            if j < from_index {
                continue;
            }
            self.wps.splice(from_index..j, spliced);
            return Ok(());
        }
        Err(format!(
            "route blocked at ({:.1}, {:.1}) and no detour rejoins it within {:.0} m",
            blocked_m.0, blocked_m.1, self.cfg.rejoin_search_m
        ))
    }
}

/// Where a detour leaves the route: (waypoints ahead kept before the departure point, or None
/// to depart from the robot; the departure point; the first blocked point on the route).
type Departure = (Option<usize>, (f64, f64), Option<(f64, f64)>);

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

fn point_segment_distance(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 1e-12 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, (a.0 + t * dx, a.1 + t * dy))
}

fn nearest(wps: &[Waypoint], p: (f64, f64)) -> usize {
    wps.iter()
        .enumerate()
        .min_by(|a, b| dist(a.1.p, p).total_cmp(&dist(b.1.p, p)))
        .map(|(i, _)| i)
        .unwrap_or(0)
}

/// Moves `p` out of non-traversable cells by a local search on a ring of growing radius, towards
/// the free cell that is nearest (the steepest direction of the clearance field); None when
/// nothing is free within `max_m`.
fn push_free(grid: &PlanGrid, p: (f64, f64), max_m: f64) -> Option<(f64, f64)> {
    let step = grid.cell_size_m();
    let rings = (max_m / step).ceil() as i32;
    for k in 1..=rings {
        let r = f64::from(k) * step;
        let n = (8 * k) as usize;
        let best = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                (p.0 + r * a.cos(), p.1 + r * a.sin())
            })
            .find(|q| point_free(grid, *q));
        if best.is_some() {
            return best;
        }
    }
    None
}

/// Cell path -> waypoints every `spacing_m`, starting at `from` and ending at `to` exactly; the
/// corners of the A* path are kept so the detour never cuts through a blocked cell.
fn resample(
    grid: &PlanGrid,
    cells: &[CellXY],
    spacing_m: f64,
    from: (f64, f64),
    to: (f64, f64),
) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = cells.iter().map(|c| grid.cell_center_m(*c)).collect();
    if let Some(f) = pts.first_mut() {
        *f = from;
    }
    if let Some(l) = pts.last_mut() {
        *l = to;
    }
    // Keep direction changes, then thin straight runs to the spacing.
    let mut out = vec![pts[0]];
    let mut since = 0.0;
    for i in 1..pts.len() {
        since += dist(pts[i - 1], pts[i]);
        let corner = i + 1 < pts.len() && {
            let (a, b, c) = (pts[i - 1], pts[i], pts[i + 1]);
            ((b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0)).abs() > 1e-9
        };
        if since >= spacing_m || corner || i + 1 == pts.len() {
            out.push(pts[i]);
            since = 0.0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight 30 m route along y = 10 on a 40 x 20 m grid.
    fn straight_route() -> Vec<(f64, f64)> {
        (0..=30).map(|i| (5.0 + f64::from(i), 10.0)).collect()
    }

    fn empty_grid() -> PlanGrid {
        PlanGrid::new(200, 100, 0.2, (0.0, 0.0))
    }

    fn assert_path_ahead_free(f: &RouteFollower, robot: &Pose2, g: &PlanGrid) {
        let ahead = f.path_ahead(robot);
        assert!(
            ahead.windows(2).all(|w| segment_free(g, w[0], w[1])),
            "{ahead:?}"
        );
    }

    fn block_rect(g: &mut PlanGrid, x0: f64, y0: f64, x1: f64, y1: f64) {
        let (cx0, cy0) = g.world_to_cell_unbounded(x0, y0);
        let (cx1, cy1) = g.world_to_cell_unbounded(x1, y1);
        for y in cy0..=cy1 {
            for x in cx0..=cx1 {
                g.set_blocked(x, y);
            }
        }
    }

    #[test]
    fn free_route_is_followed_exactly() {
        let route = straight_route();
        let robot = Pose2::new(5.0, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        assert_eq!(f.update(&robot, &empty_grid(), 0.0), RepeatState::Following);
        let ahead = f.path_ahead(&robot);
        assert!(
            ahead[1..].iter().all(|p| (p.1 - 10.0).abs() < 1e-12),
            "no point moved"
        );
        assert!(f.detours.is_empty());
        let (_, n, left) = f.progress(&robot);
        assert_eq!(n, 31);
        assert!((left - 30.0).abs() < 1e-9);
    }

    #[test]
    fn blocked_route_gets_a_detour_that_rejoins_right_after_the_obstacle() {
        let route = straight_route();
        let mut g = empty_grid();
        // A parked car (inflated) across the route from x = 14 to 18.
        block_rect(&mut g, 14.0, 8.5, 18.0, 11.5);
        let robot = Pose2::new(10.0, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        // Seen, not yet acted on: the robot drives on (the car is 4 m ahead, within
        // detour_plan_within_m), then detours once the blockage has stayed put for
        // blockage_confirm_s.
        assert!(matches!(
            f.update(&robot, &g, 0.0),
            RepeatState::Waiting { holding: false, .. }
        ));
        assert!(f.detours.is_empty() && !f.holding());
        assert_eq!(f.update(&robot, &g, 2.0), RepeatState::Following);
        assert_eq!(f.detours.len(), 1);
        let d = &f.detours[0];
        assert!(
            d.rejoin_m.0 > 18.0 && d.rejoin_m.0 <= 20.0,
            "rejoins within 2 m past the obstacle: {:?}",
            d.rejoin_m
        );
        let ahead = f.path_ahead(&robot);
        assert!(
            ahead.windows(2).all(|w| segment_free(&g, w[0], w[1])),
            "detour is free: {ahead:?}"
        );
        // After the rejoin point the taught route continues unchanged.
        let k = ahead.iter().position(|p| *p == d.rejoin_m).unwrap();
        assert!(ahead[k..].iter().all(|p| (p.1 - 10.0).abs() < 1e-12));
        // The detour is not replanned while it stays free.
        assert_eq!(f.update(&robot, &g, 3.0), RepeatState::Following);
        assert_eq!(f.detours.len(), 1);
    }

    #[test]
    fn a_wall_across_everything_blocks() {
        let route = straight_route();
        let mut g = empty_grid();
        block_rect(&mut g, 14.0, 0.0, 15.0, 19.99);
        let robot = Pose2::new(10.0, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        f.update(&robot, &g, 0.0);
        assert!(matches!(f.update(&robot, &g, 2.5), RepeatState::Blocked(_)));
        assert!(f.holding(), "a robot that cannot get round holds");
    }

    #[test]
    fn a_walker_on_the_route_is_waited_for_not_driven_around() {
        let route = straight_route();
        let robot = Pose2::new(9.0, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        // A person walks along the route ahead, away from the robot, at 1.3 m/s (a 0.6 m
        // blob, inflated), for 10 s: never a detour; the robot holds while it is close.
        let mut held = false;
        for k in 0..=20 {
            let t = f64::from(k) * 0.5;
            let x = 10.8 + 1.3 * t;
            let mut g = empty_grid();
            block_rect(&mut g, x - 0.3, 9.7, x + 0.3, 10.3);
            let st = f.update(&robot, &g, t);
            assert!(!matches!(st, RepeatState::Blocked(_)), "{t}: {st:?}");
            held |= f.holding();
        }
        assert!(held, "held while the walker was within detour_lead_m");
        assert!(f.detours.is_empty());
        assert!(!f.holding(), "drives on once it is far");
        // A group stops and stands on the route: after blockage_confirm_s the robot goes round.
        let mut g = empty_grid();
        block_rect(&mut g, 12.0, 9.0, 13.0, 11.0);
        assert!(matches!(
            f.update(&robot, &g, 20.0),
            RepeatState::Waiting { .. }
        ));
        assert_eq!(f.update(&robot, &g, 22.0), RepeatState::Following);
        assert_eq!(f.detours.len(), 1);
        assert!(f.detours[0].rejoin_m.0 > 13.0);
        assert_path_ahead_free(&f, &robot, &g);
    }

    #[test]
    fn a_detour_never_rejoins_an_earlier_detour() {
        let route = straight_route();
        let mut g = empty_grid();
        block_rect(&mut g, 14.0, 8.5, 18.0, 11.5);
        let robot = Pose2::new(10.0, 10.0, 0.0);
        let cfg = RepeatConfig {
            check_ahead_m: 20.0,
            // The re-plan below is for a blockage 8 m along the detour: decide it from here.
            detour_plan_within_m: 20.0,
            ..RepeatConfig::default()
        };
        let mut f = RouteFollower::new(cfg, &route, &robot);
        f.update(&robot, &g, 0.0);
        f.update(&robot, &g, 2.0);
        assert_eq!(f.detours.len(), 1);
        // The far side turns out longer: the detour is re-planned, to a taught point.
        block_rect(&mut g, 14.0, 8.5, 21.0, 11.5);
        f.update(&robot, &g, 3.0);
        f.update(&robot, &g, 5.0);
        let d = f.detours.last().unwrap();
        assert_eq!(
            f.detours.len(),
            1,
            "a re-plan updates the detour being driven"
        );
        assert!(
            d.replans >= 1 && d.rejoin_m.0 > 21.0 && d.rejoin_m.0 <= 23.0,
            "{d:?}"
        );
        assert!(
            (d.rejoin_m.1 - 10.0).abs() < 1e-9,
            "on the taught line: {d:?}"
        );
        assert_path_ahead_free(&f, &robot, &g);
    }

    #[test]
    fn points_near_obstacles_are_pushed_out() {
        let route = straight_route();
        let mut g = empty_grid();
        // A bush whose inflation just covers the route at x = 12.
        block_rect(&mut g, 11.8, 10.0, 12.2, 11.0);
        let robot = Pose2::new(9.0, 10.0, 0.0);
        let mut f = RouteFollower::new(
            RepeatConfig {
                check_ahead_m: 2.0,
                ..RepeatConfig::default()
            },
            &route,
            &robot,
        );
        f.update(&robot, &g, 0.0);
        let p = f
            .waypoints()
            .iter()
            .find(|w| w.taught == Some(7))
            .unwrap()
            .p;
        assert!(
            point_free(&g, p) && p.1 < 10.0 && p.1 > 9.5,
            "pushed just below the bush: {p:?}"
        );
        // What pushed it goes (a person walking on): the point is where it was taught again.
        f.update(&robot, &empty_grid(), 1.0);
        let w = f.waypoints().iter().find(|w| w.taught == Some(7)).unwrap();
        assert_eq!(w.p, w.home);
        assert!((w.p.1 - 10.0).abs() < 1e-12, "{w:?}");
    }

    #[test]
    fn loops_are_skipped_only_when_close() {
        // Out 10 m, a 4 m loop, back through the same place, then on.
        let mut route: Vec<(f64, f64)> = (0..=10).map(|i| (5.0 + f64::from(i), 10.0)).collect();
        route.extend([(15.0, 12.0), (13.0, 12.0), (13.0, 10.2), (15.2, 10.1)]);
        route.extend((1..=10).map(|i| (15.2 + f64::from(i), 10.0)));
        let robot = Pose2::new(15.0, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        f.update(&robot, &empty_grid(), 0.0);
        let ahead = f.path_ahead(&robot);
        assert!(
            ahead[1].0 > 15.0 && (ahead[1].1 - 10.0).abs() < 0.2,
            "loop skipped: {:?}",
            &ahead[..3]
        );
    }

    #[test]
    fn a_robot_past_a_zig_zag_goes_on_instead_of_turning_back() {
        // A detour's tail that doubles back to its rejoin point: 13.4 -> 13.0 -> 13.3 on the
        // line, and the robot already stands at 14.1 on the route.
        let mut route: Vec<(f64, f64)> = (0..=13).map(|i| (f64::from(i), 10.0)).collect();
        route.extend([(13.4, 10.1), (13.0, 10.0), (13.3, 10.05)]);
        route.extend((14..=30).map(|i| (f64::from(i), 10.0)));
        let robot = Pose2::new(12.5, 10.0, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        f.update(&robot, &empty_grid(), 0.0);
        let robot = Pose2::new(14.1, 10.0, 0.0);
        f.update(&robot, &empty_grid(), 0.1);
        let ahead = f.path_ahead(&robot);
        assert!(ahead[1].0 > 14.1, "heads on, not back: {:?}", &ahead[..3]);
    }

    #[test]
    fn finishes_at_the_last_point() {
        let route = straight_route();
        let robot = Pose2::new(35.0, 10.1, 0.0);
        let mut f = RouteFollower::new(RepeatConfig::default(), &route, &robot);
        assert_eq!(f.update(&robot, &empty_grid(), 0.0), RepeatState::Finished);
    }
}
