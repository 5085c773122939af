//! Detours: where the corridor ahead is first blocked, where a detour leaves the route, and
//! splicing the planned detour into the waypoints so it rejoins past the blockage.

use super::geometry::{dist, resample};
use super::*;

impl RouteFollower {
    /// Index of the first waypoint whose segment from its predecessor (or from the robot) is blocked.
    pub(super) fn first_blocked(&self, r: (f64, f64), grid: &PlanGrid) -> Option<usize> {
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
    pub(super) fn along_to(&self, r: (f64, f64), j: usize) -> f64 {
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
    pub(super) fn first_blocked_sample(
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
    pub(super) fn departure(&self, r: (f64, f64), grid: &PlanGrid) -> Departure {
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

    pub(super) fn splice_detour(
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
pub(super) type Departure = (Option<usize>, (f64, f64), Option<(f64, f64)>);
