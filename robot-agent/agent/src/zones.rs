//! Keep-out and slow zones in the agent's map frame, and what they do, as pure functions:
//!
//! - [`ZoneMap::stamp_keep_out`]: the planning-grid layer. Cells within `margin_m` of a keep-out
//!   polygon are blocked, so no plan passes through (the margin keeps the body, not only its
//!   centre, out, and leaves room for the follower cutting a corner). When the robot itself
//!   stands in such a zone (a zone drawn around it), that zone's cells are not blocked but made
//!   very expensive instead: the cheapest plan then leaves by the shortest way out, and stays
//!   out.
//! - [`ZoneMap::check_goal`]: a goal inside a keep-out zone is refused with the zone's name.
//! - [`ZoneMap::speed_cap`]: the lowest slow-zone speed among the zones the robot is in or is
//!   about to enter (within `lead_m`, the distance it needs to slow down).

use common::command::{Refusal, RefusalCode};
use common::zone;
use planning::{CellXY, PlanGrid};

/// Step penalty added to a keep-out cell the robot has to cross to leave the zone it stands in,
/// metres per cell: far more than any detour, so the plan crosses as few of them as it can.
pub const EXIT_PENALTY_M: f32 = 50.0;

/// What a zone does.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ZoneRule {
    /// Never planned through; goals inside are refused.
    KeepOut,
    /// Speed capped at this many m/s.
    Slow(f64),
}

/// One zone in the map frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ZoneShape {
    /// Id chosen by the station.
    pub id: String,
    /// Name given by the operator.
    pub name: String,
    /// What it does.
    pub rule: ZoneRule,
    /// Corners (x, y), metres, not closed.
    pub polygon_m: Vec<(f64, f64)>,
}

/// The zones in force.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ZoneMap {
    /// The station's version of the set (0: none received).
    pub version: u64,
    /// The zones.
    pub zones: Vec<ZoneShape>,
}

impl ZoneMap {
    /// The keep-out zone `p` lies in, if any.
    pub fn keep_out_at(&self, p: (f64, f64)) -> Option<&ZoneShape> {
        self.zones
            .iter()
            .find(|z| z.rule == ZoneRule::KeepOut && zone::contains(&z.polygon_m, p))
    }

    /// Refuses a goal inside a keep-out zone.
    pub fn check_goal(&self, goal_m: (f64, f64)) -> Result<(), Refusal> {
        match self.keep_out_at(goal_m) {
            Some(z) => Err(Refusal::new(
                RefusalCode::GoalInKeepOut,
                format!(
                    "goal: ({:.1}, {:.1}) is inside keep-out zone {:?}",
                    goal_m.0, goal_m.1, z.name
                ),
            )),
            None => Ok(()),
        }
    }

    /// The lowest slow-zone speed of the zones within `lead_m` of `p` (inside counts), with
    /// that zone's name.
    pub fn speed_cap(&self, p: (f64, f64), lead_m: f64) -> Option<(f64, &str)> {
        self.zones
            .iter()
            .filter_map(|z| match z.rule {
                ZoneRule::Slow(v) if zone::signed_distance_m(&z.polygon_m, p) <= lead_m => {
                    Some((v, z.name.as_str()))
                }
                _ => None,
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// Blocks the cells of `grid` within `margin_m` of a keep-out polygon; the zone the robot
    /// (at `robot_m`) stands in, or within the margin of, is made expensive instead (see the
    /// module docs). Returns the name of that zone, if any.
    pub fn stamp_keep_out(
        &self,
        grid: &mut PlanGrid,
        margin_m: f64,
        robot_m: (f64, f64),
    ) -> Option<String> {
        let mut inside = None;
        let s = grid.cell_size_m();
        for z in self.zones.iter().filter(|z| z.rule == ZoneRule::KeepOut) {
            let escape = zone::signed_distance_m(&z.polygon_m, robot_m) <= margin_m;
            if escape {
                inside = Some(z.name.clone());
            }
            let ((x0, y0), (x1, y1)) = zone::bounds(&z.polygon_m);
            let (gx0, gy0) = grid.world_to_cell_unbounded(x0 - margin_m - s, y0 - margin_m - s);
            let (gx1, gy1) = grid.world_to_cell_unbounded(x1 + margin_m + s, y1 + margin_m + s);
            let gx0 = gx0.max(0);
            let gy0 = gy0.max(0);
            let gx1 = gx1.min(i64::from(grid.width()) - 1);
            let gy1 = gy1.min(i64::from(grid.height()) - 1);
            for gy in gy0..=gy1 {
                for gx in gx0..=gx1 {
                    let c = grid.cell_center_m(CellXY::new(gx as u32, gy as u32));
                    if zone::signed_distance_m(&z.polygon_m, c) > margin_m {
                        continue;
                    }
                    if escape {
                        let p = grid.penalty_m(gx, gy);
                        if p.is_finite() {
                            grid.set(gx, gy, p + EXIT_PENALTY_M, grid.is_unknown(gx, gy));
                        }
                    } else {
                        grid.set_blocked(gx, gy);
                    }
                }
            }
        }
        inside
    }

    /// A line for the operator about the zone acting on the robot at `p`, if any.
    pub fn note(&self, p: (f64, f64), margin_m: f64, cap: Option<(f64, &str)>) -> Option<String> {
        if let Some(z) = self.zones.iter().find(|z| {
            z.rule == ZoneRule::KeepOut && zone::signed_distance_m(&z.polygon_m, p) <= margin_m
        }) {
            return Some(format!("inside keep-out zone {}: leaving it", z.name));
        }
        cap.map(|(v, name)| format!("slow zone {name}: {v:.2} m/s"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use planning::astar::Planner;

    fn map_with(rule: ZoneRule, poly: Vec<(f64, f64)>) -> ZoneMap {
        ZoneMap {
            version: 1,
            zones: vec![ZoneShape {
                id: "z".into(),
                name: "pond".into(),
                rule,
                polygon_m: poly,
            }],
        }
    }

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<(f64, f64)> {
        vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    }

    fn plan(grid: &PlanGrid, a: (f64, f64), b: (f64, f64)) -> Vec<(f64, f64)> {
        let s = grid.world_to_cell(a.0, a.1).unwrap();
        let g = grid.world_to_cell(b.0, b.1).unwrap();
        let p = Planner::new().plan(grid, s, g).expect("a path");
        p.cells.iter().map(|c| grid.cell_center_m(*c)).collect()
    }

    #[test]
    fn a_keep_out_zone_across_the_line_is_planned_around() {
        // 20 x 20 m, a wall of keep-out across the straight line from (2, 10) to (18, 10).
        let zones = map_with(ZoneRule::KeepOut, rect(8.0, 4.0, 12.0, 16.0));
        let mut g = PlanGrid::new(100, 100, 0.2, (0.0, 0.0));
        assert_eq!(zones.stamp_keep_out(&mut g, 0.5, (2.0, 10.0)), None);
        let path = plan(&g, (2.0, 10.0), (18.0, 10.0));
        for p in &path {
            assert!(
                zone::signed_distance_m(&zones.zones[0].polygon_m, *p) > 0.5,
                "{p:?} within the margin"
            );
        }
        assert!(zones.check_goal((10.0, 10.0)).is_err());
        assert_eq!(
            zones.check_goal((10.0, 10.0)).unwrap_err().code,
            RefusalCode::GoalInKeepOut
        );
        assert!(zones.check_goal((18.0, 10.0)).is_ok());
    }

    #[test]
    fn a_robot_inside_leaves_by_the_shortest_way_out() {
        // The robot stands 1 m inside the zone's west edge; the goal lies east beyond it. The
        // plan must cross the west edge (1 m of zone), not the 9 m to the east edge.
        let zones = map_with(ZoneRule::KeepOut, rect(5.0, 2.0, 15.0, 18.0));
        let mut g = PlanGrid::new(100, 100, 0.2, (0.0, 0.0));
        assert_eq!(
            zones.stamp_keep_out(&mut g, 0.5, (6.0, 10.0)).as_deref(),
            Some("pond")
        );
        let path = plan(&g, (6.0, 10.0), (18.0, 10.0));
        let poly = &zones.zones[0].polygon_m;
        let first_out = path
            .iter()
            .position(|p| zone::signed_distance_m(poly, *p) > 0.5)
            .expect("leaves the zone");
        assert!(
            path[first_out].0 < 5.0,
            "left westwards at {:?}",
            path[first_out]
        );
        // ...and never comes back in once out.
        assert!(path[first_out..]
            .iter()
            .all(|p| zone::signed_distance_m(poly, *p) > 0.0));
    }

    #[test]
    fn slow_zones_cap_speed_ahead_of_the_robot() {
        let zones = map_with(ZoneRule::Slow(0.2), rect(5.0, -2.0, 9.0, 2.0));
        assert_eq!(zones.speed_cap((0.0, 0.0), 1.0), None);
        assert_eq!(zones.speed_cap((4.2, 0.0), 1.0), Some((0.2, "pond")));
        assert_eq!(zones.speed_cap((7.0, 0.0), 1.0), Some((0.2, "pond")));
        assert_eq!(zones.speed_cap((10.5, 0.0), 1.0), None);
        let cap = zones.speed_cap((7.0, 0.0), 1.0);
        assert_eq!(
            zones.note((7.0, 0.0), 0.5, cap).as_deref(),
            Some("slow zone pond: 0.20 m/s")
        );
        assert!(
            zones.check_goal((7.0, 0.0)).is_ok(),
            "slow zones take goals"
        );
    }
}
