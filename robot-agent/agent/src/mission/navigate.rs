//! The go-to-goal mission: goal in, path out, state reported (docs/algorithms.md §5).
//!
//! The navigator owns the goal, the mission state and the path. It plans when asked (the agent's
//! loop calls [`Navigator::wants_replan`] at its own rate and times [`Navigator::replan`]); it never
//! reads a clock: every call takes the session time.

use super::Phase;
use crate::localiser::gnss::GnssGoal;
use common::geom::Pose2;
use planning::goal::{goal_cell, start_cell, GoalError};
use planning::reach::{Floods, Reachability};
use planning::smooth::{cells_to_polyline, polyline_length_m, smooth_polyline};
use planning::{PlanError, PlanGrid, Planner, PlannerConfig, SearchLimits};
use serde::Deserialize;

/// Mission parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct NavConfig {
    /// Distance at which a goal counts as reached, metres (a goal may ask for another).
    pub goal_tolerance_m: f64,
    /// How long "no path" is re-checked before the mission gives up, seconds: a walker can close
    /// a passage for a moment, a drop-off cannot.
    pub no_path_give_up_s: f64,
}

impl Default for NavConfig {
    fn default() -> Self {
        Self {
            goal_tolerance_m: 0.3,
            no_path_give_up_s: 10.0,
        }
    }
}

/// An active goal.
#[derive(Clone, Debug, PartialEq)]
pub struct Goal {
    /// Id from the command.
    pub id: u32,
    /// Where, map frame, metres.
    pub goal_map: (f64, f64),
    /// Reached within this distance, metres.
    pub tolerance_m: f64,
    /// The GNSS form, when it was given as lat/lon (re-evaluated per fix).
    pub gnss: Option<GnssGoal>,
}

/// What one planning call did.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanReport {
    /// State after planning.
    pub state: Phase,
    /// Path length, metres (0 without a path).
    pub length_m: f64,
    /// Cells expanded by A*.
    pub expansions: usize,
}

/// The go-to-goal mission.
#[derive(Debug)]
pub struct Navigator {
    cfg: NavConfig,
    planner_cfg: PlannerConfig,
    planner: Planner,
    floods: Floods,
    goal: Option<Goal>,
    /// The last goal set, kept after it was reached or given up (status reports it).
    last_goal: Option<Goal>,
    state: Phase,
    reason: String,
    path: Vec<(f64, f64)>,
    last_plan_t_s: f64,
    path_invalid: bool,
    no_path_since_s: Option<f64>,
    /// Plans made since start.
    pub replans: u32,
}

impl Navigator {
    /// An idle navigator.
    pub fn new(cfg: NavConfig, planner_cfg: PlannerConfig) -> Self {
        Self {
            cfg,
            planner_cfg,
            planner: Planner::new(),
            floods: Floods::new(),
            goal: None,
            last_goal: None,
            state: Phase::Idle,
            reason: String::new(),
            path: Vec::new(),
            last_plan_t_s: f64::NEG_INFINITY,
            path_invalid: false,
            no_path_since_s: None,
            replans: 0,
        }
    }

    /// Starts a mission to `goal` (replaces any current one).
    pub fn set_goal(&mut self, mut goal: Goal) {
        if goal.tolerance_m <= 0.0 {
            goal.tolerance_m = self.cfg.goal_tolerance_m;
        }
        self.last_goal = Some(goal.clone());
        self.goal = Some(goal);
        self.state = Phase::Planning;
        self.reason = "new goal".into();
        self.path.clear();
        self.path_invalid = true;
        self.no_path_since_s = None;
    }

    /// Ends the mission and clears the path.
    pub fn stop(&mut self, reason: &str) {
        self.goal = None;
        self.path.clear();
        self.state = Phase::Stopped;
        self.reason = reason.to_string();
    }

    /// Ends a mission that completed (a route's last waypoint): reached, not stopped.
    pub fn finish(&mut self, reason: &str) {
        self.goal = None;
        self.last_goal = None;
        self.path.clear();
        self.state = Phase::Reached;
        self.reason = reason.to_string();
    }

    /// The last goal set, also after it was reached or given up.
    pub fn last_goal(&self) -> Option<&Goal> {
        self.last_goal.as_ref()
    }

    /// Current mission state.
    pub fn state(&self) -> Phase {
        self.state
    }

    /// Why the mission is in its state.
    pub fn reason(&self) -> &str {
        &self.reason
    }

    /// The active goal.
    pub fn goal(&self) -> Option<&Goal> {
        self.goal.as_ref()
    }

    /// Mutable access to the active goal (the agent refreshes GNSS goals per fix).
    pub fn goal_mut(&mut self) -> Option<&mut Goal> {
        self.goal.as_mut()
    }

    /// The smoothed path being followed, map frame.
    pub fn path(&self) -> &[(f64, f64)] {
        &self.path
    }

    /// True while the robot should be moving along the path.
    pub fn is_driving(&self) -> bool {
        self.state == Phase::Driving && !self.path.is_empty()
    }

    /// Marks the mission blocked by the safety stop (or clears that), without losing the path.
    pub fn set_blocked(&mut self, blocked: bool, reason: &str) {
        match (blocked, self.state) {
            (true, Phase::Driving) => {
                self.state = Phase::Blocked;
                self.reason = reason.to_string();
            }
            (false, Phase::Blocked) => {
                self.state = Phase::Driving;
                self.reason = "path clear again".into();
                self.path_invalid = true;
            }
            _ => {}
        }
    }

    /// Whether a plan is due at `t_s`: at the replanning rate while a goal is active, and at once
    /// when the grid changed on the path.
    pub fn wants_replan(&self, t_s: f64) -> bool {
        let active = matches!(
            self.state,
            Phase::Planning | Phase::Driving | Phase::Blocked | Phase::NoPath
        );
        active
            && self.goal.is_some()
            && (self.path_invalid
                || t_s - self.last_plan_t_s >= 1.0 / self.planner_cfg.replan_rate_hz)
    }

    /// The stretch of the path [`Navigator::check_path`] checks from `pose`: from the path point
    /// nearest the robot on (empty without a path of two points).
    pub fn path_ahead(&self, pose: &Pose2) -> &[(f64, f64)] {
        if self.path.len() < 2 {
            return &[];
        }
        &self.path[nearest_index(&self.path, (pose.x_m, pose.y_m))..]
    }

    /// Checks the path ahead of the robot against a new grid; a blocked stretch asks for a replan.
    pub fn check_path(&mut self, grid: &PlanGrid, pose: &Pose2) -> bool {
        let blocked = self
            .path_ahead(pose)
            .windows(2)
            .any(|w| !planning::smooth::segment_free(grid, w[0], w[1]));
        if blocked {
            self.path_invalid = true;
        }
        blocked
    }

    /// True (and the state becomes Reached) when the robot is within tolerance of the goal.
    pub fn check_reached(&mut self, pose: &Pose2) -> bool {
        let Some(goal) = &self.goal else { return false };
        let d = (goal.goal_map.0 - pose.x_m).hypot(goal.goal_map.1 - pose.y_m);
        if d <= goal.tolerance_m {
            self.state = Phase::Reached;
            self.reason = format!("within {d:.2} m of goal {}", goal.id);
            self.path.clear();
            self.goal = None;
            return true;
        }
        false
    }

    /// Plans from `pose` to the goal on `grid`: goal-cell rules, reachability floods, A*,
    /// smoothing. Sets the state and reason; keeps the old path when planning fails for a reason
    /// that may pass (budget) and clears it when there is no path.
    pub fn replan(&mut self, t_s: f64, pose: &Pose2, grid: &PlanGrid) -> PlanReport {
        self.last_plan_t_s = t_s;
        self.path_invalid = false;
        self.replans += 1;
        let Some(goal) = self.goal.clone() else {
            return self.report(0.0, 0);
        };
        if self.check_reached(pose) {
            return self.report(0.0, 0);
        }
        let robot = (pose.x_m, pose.y_m);
        let start = match start_cell(grid, robot) {
            Ok(c) => c,
            Err(e) => return self.fail_no_path(t_s, e.to_string(), true),
        };
        let goal_c = match goal_cell(
            grid,
            robot,
            goal.goal_map,
            self.planner_cfg.goal_search_radius_m,
        ) {
            Ok(g) => g,
            Err(e @ GoalError::NoFreeCellNearGoal { .. }) => {
                return self.fail_no_path(t_s, e.to_string(), false)
            }
            Err(e) => return self.fail_no_path(t_s, e.to_string(), false),
        };
        let reach = self.floods.check(grid, start, goal_c.cell);
        if reach.reachability == Reachability::NoPath {
            return self.fail_no_path(
                t_s,
                "goal is cut off from the robot (reachability floods)".into(),
                false,
            );
        }
        let limits = SearchLimits {
            max_expansions: Some(self.planner_cfg.max_expansions),
        };
        match self
            .planner
            .plan_with(grid, start, goal_c.cell, limits, &mut || false)
        {
            Ok(p) => {
                let poly = cells_to_polyline(grid, &p.cells);
                let mut smooth = smooth_polyline(
                    grid,
                    &poly,
                    self.planner_cfg.smoothing_window_points,
                    self.planner_cfg.smoothing_iterations,
                );
                // Start the path at the robot itself so the follower never aims back at a cell centre.
                if let Some(first) = smooth.first_mut() {
                    *first = robot;
                }
                // Finish at the goal itself when it lies in the goal cell, not at the cell centre.
                if goal_c.rule == planning::goal::GoalRule::Contains {
                    if let Some(last) = smooth.last_mut() {
                        *last = goal.goal_map;
                    }
                }
                self.path = smooth;
                self.no_path_since_s = None;
                self.state = Phase::Driving;
                self.reason = match reach.reachability {
                    Reachability::MayExistBeyondMap => {
                        "heading for the map edge towards the goal".into()
                    }
                    _ => format!("path {:.1} m", p.length_m),
                };
                self.report(polyline_length_m(&self.path), p.expansions)
            }
            Err(PlanError::BudgetExceeded { max_expansions }) => {
                self.reason = format!("planner budget exceeded after {max_expansions} expansions; keeping the old path");
                self.report(polyline_length_m(&self.path), max_expansions)
            }
            Err(e) => self.fail_no_path(t_s, e.to_string(), false),
        }
    }

    fn fail_no_path(&mut self, t_s: f64, reason: String, robot_blocked: bool) -> PlanReport {
        self.path.clear();
        let since = *self.no_path_since_s.get_or_insert(t_s);
        self.reason = reason;
        if robot_blocked {
            self.state = Phase::Blocked;
        } else if t_s - since >= self.cfg.no_path_give_up_s {
            self.state = Phase::NoPath;
            self.goal = None;
        } else {
            self.state = Phase::NoPath;
        }
        self.report(0.0, 0)
    }

    fn report(&self, length_m: f64, expansions: usize) -> PlanReport {
        PlanReport {
            state: self.state,
            length_m,
            expansions,
        }
    }
}

/// Index of the path point nearest to `p`.
pub fn nearest_index(path: &[(f64, f64)], p: (f64, f64)) -> usize {
    path.iter()
        .enumerate()
        .min_by(|a, b| {
            let da = (a.1 .0 - p.0).hypot(a.1 .1 - p.1);
            let db = (b.1 .0 - p.0).hypot(b.1 .1 - p.1);
            da.total_cmp(&db)
        })
        .map(|(i, _)| i)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_with_wall(gap: bool) -> PlanGrid {
        let mut g = PlanGrid::new(100, 100, 0.2, (0.0, 0.0));
        for y in 0..100 {
            if !(gap && (80..90).contains(&y)) {
                g.set_blocked(50, y);
            }
        }
        g
    }

    fn goal(x: f64, y: f64) -> Goal {
        Goal {
            id: 1,
            goal_map: (x, y),
            tolerance_m: 0.0,
            gnss: None,
        }
    }

    #[test]
    fn plans_around_a_wall_and_reaches() {
        let mut n = Navigator::new(NavConfig::default(), PlannerConfig::default());
        n.set_goal(goal(18.0, 2.0));
        assert!(n.wants_replan(0.0));
        let pose = Pose2::new(2.0, 2.0, 0.0);
        let r = n.replan(0.0, &pose, &grid_with_wall(true));
        assert_eq!(r.state, Phase::Driving);
        // Straight line 16 m; through the gap at (10, 16-18) at least 2 x 16.1 m.
        assert!(
            r.length_m > 32.0 && r.length_m < 37.0,
            "detour through the gap: {}",
            r.length_m
        );
        assert_eq!(n.path()[0], (2.0, 2.0));
        assert_eq!(*n.path().last().unwrap(), (18.0, 2.0));
        assert!(!n.wants_replan(0.1));
        assert!(n.wants_replan(0.6), "2 Hz replanning");
        assert!(n.check_reached(&Pose2::new(17.9, 2.1, 0.0)));
        assert_eq!(n.state(), Phase::Reached);
        assert!(!n.wants_replan(10.0));
    }

    #[test]
    fn cut_off_goal_is_no_path_after_the_grace_period() {
        let mut n = Navigator::new(NavConfig::default(), PlannerConfig::default());
        let mut g = grid_with_wall(false);
        // Close the robot's side completely so nothing can exist beyond the map either.
        for x in 0..50 {
            g.set_blocked(x, 0);
            g.set_blocked(x, 99);
        }
        for y in 0..100 {
            g.set_blocked(0, y);
        }
        n.set_goal(goal(18.0, 2.0));
        let pose = Pose2::new(2.0, 2.0, 0.0);
        assert_eq!(n.replan(0.0, &pose, &g).state, Phase::NoPath);
        assert!(n.goal().is_some(), "still re-checking");
        assert!(n.wants_replan(0.5));
        n.replan(11.0, &pose, &g);
        assert_eq!(n.state(), Phase::NoPath);
        assert!(n.goal().is_none(), "gave up");
        assert!(n.reason().contains("cut off"), "{}", n.reason());
    }

    #[test]
    fn a_new_obstacle_on_the_path_asks_for_a_replan() {
        let mut n = Navigator::new(NavConfig::default(), PlannerConfig::default());
        n.set_goal(goal(18.0, 2.0));
        let pose = Pose2::new(2.0, 2.0, 0.0);
        let mut g = PlanGrid::new(100, 100, 0.2, (0.0, 0.0));
        n.replan(0.0, &pose, &g);
        assert!(!n.check_path(&g, &pose));
        for y in 0..20 {
            g.set_blocked(60, y);
        }
        assert!(n.check_path(&g, &pose));
        assert!(n.wants_replan(0.01));
        n.replan(0.01, &pose, &g);
        assert!(n
            .path()
            .iter()
            .all(|p| planning::smooth::point_free(&g, *p)));
    }
}
