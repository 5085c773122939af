//! Alerts for the operator: a robot that has not progressed toward its goal for
//! `stuck_after_s`, a mission that fails (no path, or a mission run that ends in failure), a
//! robot that goes offline, a GNSS fix that degrades. Each alert is raised once, stays in the
//! list until the operator acknowledges it, and says whether its cause is still there.
//!
//! Plain data: the station feeds what it knows of each robot with the time; nothing here reads
//! a clock or the network.

use std::collections::BTreeMap;

use common::msg::{FixState, MissionState, Mode, Pose, Status};
use serde::{Deserialize, Serialize};

/// What raises alerts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlertConfig {
    /// A robot on a mission that has not come this much closer to its goal for this long is
    /// stuck, seconds.
    pub stuck_after_s: f64,
    /// Progress that counts, metres.
    pub stuck_progress_m: f64,
    /// A fix worse than the best seen for this long is degraded, seconds.
    pub gnss_degraded_after_s: f64,
    /// "No path" that lasts this long fails the mission, seconds.
    pub no_path_after_s: f64,
}

impl Default for AlertConfig {
    fn default() -> Self {
        Self {
            stuck_after_s: 30.0,
            stuck_progress_m: 0.5,
            gnss_degraded_after_s: 2.0,
            no_path_after_s: 2.0,
        }
    }
}

/// Kinds of alert.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlertKind {
    /// No progress toward the goal.
    Stuck,
    /// A mission failed.
    MissionFailed,
    /// The robot went offline.
    Offline,
    /// The GNSS fix degraded.
    GnssDegraded,
}

/// One alert.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alert {
    /// Id, increasing.
    pub id: u64,
    /// The robot.
    pub robot: String,
    /// What.
    pub kind: AlertKind,
    /// For humans.
    pub message: String,
    /// When raised, Unix ms.
    pub raised_unix_ms: u64,
    /// Its cause is still there.
    pub active: bool,
    /// When acknowledged, Unix ms.
    pub acked_unix_ms: Option<u64>,
}

/// What the station knows of one robot at one instant.
#[derive(Clone, Copy, Debug)]
pub struct Observation<'a> {
    /// Liveliness.
    pub online: bool,
    /// Last status.
    pub status: Option<&'a Status>,
    /// Last pose.
    pub pose: Option<&'a Pose>,
}

#[derive(Clone, Debug, Default)]
struct Watch {
    online: Option<bool>,
    /// (what the robot is working toward, best remaining distance, since when, heading then)
    /// while on a mission.
    progress: Option<(String, f64, u64, f64)>,
    stuck_alert: Option<u64>,
    no_path_since: Option<(u64, u32)>,
    no_path_raised: Option<u32>,
    best_fix: u8,
    degraded_since: Option<u64>,
    gnss_alert: Option<u64>,
    offline_alert: Option<u64>,
}

fn fix_rank(f: FixState) -> u8 {
    match f {
        FixState::NoFix => 0,
        FixState::Single => 1,
        FixState::Dgps => 2,
        FixState::RtkFloat => 3,
        FixState::RtkFixed => 4,
    }
}

/// The alert list and the per-robot watches that raise it.
#[derive(Clone, Debug, Default)]
pub struct Alerts {
    cfg: AlertConfig,
    next_id: u64,
    list: Vec<Alert>,
    watch: BTreeMap<String, Watch>,
}

/// A turn on the spot this large counts as progress, radians.
pub const TURN_PROGRESS_RAD: f64 = 0.5;

/// Most alerts kept (the oldest acknowledged go first).
pub const MAX_ALERTS: usize = 500;

impl Alerts {
    /// An empty list.
    pub fn new(cfg: AlertConfig) -> Self {
        Self {
            cfg,
            next_id: 1,
            ..Self::default()
        }
    }

    /// An alert list that goes on from `stored` (alerts kept across a restart). Their causes
    /// are judged anew: they are no longer marked active.
    pub fn restore(cfg: AlertConfig, stored: Vec<Alert>) -> Self {
        let next_id = stored.iter().map(|a| a.id).max().unwrap_or(0) + 1;
        let list = stored
            .into_iter()
            .map(|a| Alert { active: false, ..a })
            .collect();
        Self {
            cfg,
            next_id,
            list,
            watch: BTreeMap::new(),
        }
    }

    /// Every alert, newest first.
    pub fn list(&self) -> Vec<Alert> {
        self.list.iter().rev().cloned().collect()
    }

    /// One alert.
    pub fn get(&self, id: u64) -> Option<&Alert> {
        self.list.iter().find(|a| a.id == id)
    }

    /// Acknowledges an alert; false when there is no such alert.
    pub fn ack(&mut self, id: u64, now_ms: u64) -> bool {
        match self.list.iter_mut().find(|a| a.id == id) {
            Some(a) => {
                a.acked_unix_ms.get_or_insert(now_ms);
                true
            }
            None => false,
        }
    }

    /// Raises an alert from outside the watches (a mission run that failed). Returns it.
    pub fn raise(&mut self, robot: &str, kind: AlertKind, message: String, now_ms: u64) -> Alert {
        let a = Alert {
            id: self.next_id.max(1),
            robot: robot.to_string(),
            kind,
            message,
            raised_unix_ms: now_ms,
            active: true,
            acked_unix_ms: None,
        };
        self.next_id = a.id + 1;
        self.list.push(a.clone());
        if self.list.len() > MAX_ALERTS {
            let drop = self
                .list
                .iter()
                .position(|a| a.acked_unix_ms.is_some())
                .unwrap_or(0);
            self.list.remove(drop);
        }
        a
    }

    fn set_active(&mut self, id: Option<u64>, active: bool) -> Option<Alert> {
        let a = self.list.iter_mut().find(|a| Some(a.id) == id)?;
        (a.active != active).then(|| {
            a.active = active;
            a.clone()
        })
    }

    /// Feeds what is known of `robot` at `now_ms`; returns the alerts raised or changed.
    pub fn observe(&mut self, robot: &str, o: Observation<'_>, now_ms: u64) -> Vec<Alert> {
        let cfg = self.cfg;
        let mut w = self.watch.remove(robot).unwrap_or_default();
        let mut out = Vec::new();

        // Offline: on the edge; resolved (not removed) when the robot is back.
        if w.online == Some(true) && !o.online {
            let a = self.raise(
                robot,
                AlertKind::Offline,
                format!("{robot} went offline"),
                now_ms,
            );
            w.offline_alert = Some(a.id);
            out.push(a);
        } else if o.online && w.online == Some(false) {
            out.extend(self.set_active(w.offline_alert.take(), false));
        }
        w.online = Some(o.online);

        if let Some(s) = o.status {
            out.extend(self.watch_progress(robot, &mut w, s, o.pose, now_ms, cfg));
            out.extend(self.watch_no_path(robot, &mut w, s, now_ms, cfg));
            out.extend(self.watch_gnss(robot, &mut w, s, o.pose, now_ms, cfg));
        }
        self.watch.insert(robot.to_string(), w);
        out
    }

    fn watch_progress(
        &mut self,
        robot: &str,
        w: &mut Watch,
        s: &Status,
        pose: Option<&Pose>,
        now_ms: u64,
        cfg: AlertConfig,
    ) -> Vec<Alert> {
        let moving = matches!(
            s.mission,
            MissionState::Planning | MissionState::Driving | MissionState::Blocked
        );
        // What the robot works toward (its key, for humans) and how far it still is.
        let target = match (s.mode, &s.route, s.goal_m, pose) {
            (Mode::Repeat, Some(r), _, _) => Some((
                format!("route {}", r.route_id),
                format!("route {:?}", r.name),
                f64::from(r.distance_left_m),
            )),
            (Mode::Goal, _, Some(g), Some(p)) => Some((
                format!("goal {}", s.goal_id),
                format!("goal ({:.1}, {:.1})", g.0, g.1),
                (g.0 - p.x_m).hypot(g.1 - p.y_m),
            )),
            _ => None,
        };
        let mut out = Vec::new();
        match target.filter(|_| moving) {
            None => {
                w.progress = None;
                out.extend(self.set_active(w.stuck_alert.take(), false));
            }
            Some((key, label, d)) => {
                let yaw = pose.map_or(0.0, |p| f64::from(p.yaw_rad));
                // Turning on the spot toward the path (a route repeated backwards starts with a
                // half turn) is progress too; standing or creeping is not.
                let fresh = match &w.progress {
                    Some((k, best, _, yaw0)) => {
                        let turned = (yaw - yaw0 + std::f64::consts::PI)
                            .rem_euclid(std::f64::consts::TAU)
                            - std::f64::consts::PI;
                        *k != key
                            || d < best - cfg.stuck_progress_m
                            || turned.abs() > TURN_PROGRESS_RAD
                    }
                    None => true,
                };
                if fresh {
                    w.progress = Some((key, d, now_ms, yaw));
                    out.extend(self.set_active(w.stuck_alert.take(), false));
                } else if let Some((_, best, since, _)) = &w.progress {
                    let idle_s = now_ms.saturating_sub(*since) as f64 / 1000.0;
                    if w.stuck_alert.is_none() && idle_s >= cfg.stuck_after_s {
                        let a = self.raise(
                            robot,
                            AlertKind::Stuck,
                            format!(
                                "{robot} is stuck: no progress toward its {label} for {idle_s:.0} s ({best:.1} m to go; {})",
                                s.reason
                            ),
                            now_ms,
                        );
                        w.stuck_alert = Some(a.id);
                        out.push(a);
                    }
                }
            }
        }
        out
    }

    fn watch_no_path(
        &mut self,
        robot: &str,
        w: &mut Watch,
        s: &Status,
        now_ms: u64,
        cfg: AlertConfig,
    ) -> Vec<Alert> {
        if s.mission != MissionState::NoPath {
            w.no_path_since = None;
            return Vec::new();
        }
        let since = match w.no_path_since {
            Some((t, id)) if id == s.goal_id => t,
            _ => {
                w.no_path_since = Some((now_ms, s.goal_id));
                now_ms
            }
        };
        let long = now_ms.saturating_sub(since) as f64 / 1000.0 >= cfg.no_path_after_s;
        if long && w.no_path_raised != Some(s.goal_id) {
            w.no_path_raised = Some(s.goal_id);
            let at = s
                .goal_m
                .map(|g| format!(" ({:.1}, {:.1})", g.0, g.1))
                .unwrap_or_default();
            return vec![self.raise(
                robot,
                AlertKind::MissionFailed,
                format!("{robot}: no path to goal{at}: {}", s.reason),
                now_ms,
            )];
        }
        Vec::new()
    }

    fn watch_gnss(
        &mut self,
        robot: &str,
        w: &mut Watch,
        s: &Status,
        pose: Option<&Pose>,
        now_ms: u64,
        cfg: AlertConfig,
    ) -> Vec<Alert> {
        let fix = pose.map_or(s.fix, |p| p.fix);
        let rank = if s.gnss_lost { 0 } else { fix_rank(fix) };
        w.best_fix = w.best_fix.max(rank);
        let mut out = Vec::new();
        if rank < w.best_fix {
            let since = *w.degraded_since.get_or_insert(now_ms);
            let long = now_ms.saturating_sub(since) as f64 / 1000.0 >= cfg.gnss_degraded_after_s;
            if long && w.gnss_alert.is_none() {
                let what = if s.gnss_lost {
                    "GNSS lost: navigating on SLAM and odometry only".to_string()
                } else {
                    format!("GNSS fix degraded to {fix:?}")
                };
                let a = self.raise(
                    robot,
                    AlertKind::GnssDegraded,
                    format!("{robot}: {what}"),
                    now_ms,
                );
                w.gnss_alert = Some(a.id);
                out.push(a);
            }
        } else {
            w.degraded_since = None;
            out.extend(self.set_active(w.gnss_alert.take(), false));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(mode: Mode, mission: MissionState, goal: Option<(f64, f64)>) -> Status {
        Status {
            mode,
            mission,
            goal_m: goal,
            goal_id: 7,
            fix: FixState::RtkFixed,
            ..Status::default()
        }
    }

    fn pose(x: f64) -> Pose {
        Pose {
            t_unix_ms: 0,
            seq: 0,
            x_m: x,
            y_m: 0.0,
            z_m: 0.0,
            yaw_rad: 0.0,
            pitch_rad: 0.0,
            roll_rad: 0.0,
            v_mps: 0.0,
            omega_rps: 0.0,
            fix: FixState::RtkFixed,
            lat_lon_deg: None,
        }
    }

    fn obs<'a>(s: &'a Status, p: &'a Pose) -> Observation<'a> {
        Observation {
            online: true,
            status: Some(s),
            pose: Some(p),
        }
    }

    #[test]
    fn a_robot_without_progress_is_stuck_once_and_recovers() {
        let mut a = Alerts::new(AlertConfig {
            stuck_after_s: 5.0,
            ..AlertConfig::default()
        });
        let s = status(Mode::Goal, MissionState::Driving, Some((10.0, 0.0)));
        let p = pose(0.0);
        assert!(a.observe("r", obs(&s, &p), 0).is_empty());
        assert!(a.observe("r", obs(&s, &p), 4_000).is_empty());
        let up = a.observe("r", obs(&s, &p), 5_100);
        assert_eq!(up.len(), 1);
        assert_eq!(up[0].kind, AlertKind::Stuck);
        assert!(up[0].message.contains("no progress"), "{}", up[0].message);
        assert!(a.observe("r", obs(&s, &p), 9_000).is_empty(), "raised once");
        // Moving on resolves it; it stays listed until acknowledged.
        let p2 = pose(2.0);
        let ch = a.observe("r", obs(&s, &p2), 9_500);
        assert_eq!(ch.len(), 1);
        assert!(!ch[0].active);
        assert!(a.ack(ch[0].id, 10_000));
        assert_eq!(a.list()[0].acked_unix_ms, Some(10_000));
        // Slow but steady progress is not stuck.
        let mut x = 2.0;
        for t in (10_000..40_000).step_by(1000) {
            x += 0.3;
            assert!(a.observe("r", obs(&s, &pose(x)), t).is_empty(), "{t}");
        }
    }

    #[test]
    fn offline_no_path_and_gnss_raise_alerts() {
        let mut a = Alerts::new(AlertConfig::default());
        let s = status(Mode::Idle, MissionState::Idle, None);
        let p = pose(0.0);
        a.observe("r", obs(&s, &p), 0);
        let off = a.observe(
            "r",
            Observation {
                online: false,
                status: Some(&s),
                pose: Some(&p),
            },
            1_000,
        );
        assert_eq!(off[0].kind, AlertKind::Offline);
        let back = a.observe("r", obs(&s, &p), 2_000);
        assert!(!back[0].active, "resolved");
        let np = status(Mode::Goal, MissionState::NoPath, Some((5.0, 5.0)));
        assert!(a.observe("r", obs(&np, &p), 3_000).is_empty());
        let failed = a.observe("r", obs(&np, &p), 5_500);
        assert_eq!(failed[0].kind, AlertKind::MissionFailed);
        assert!(
            failed[0].message.contains("(5.0, 5.0)"),
            "{}",
            failed[0].message
        );
        let mut float = pose(0.0);
        float.fix = FixState::RtkFloat;
        assert!(a.observe("r", obs(&s, &float), 6_000).is_empty());
        let g = a.observe("r", obs(&s, &float), 8_100);
        assert_eq!(g[0].kind, AlertKind::GnssDegraded);
        assert_eq!(a.list().len(), 3);
        // Kept across a restart: ids go on, causes are judged anew.
        let b = Alerts::restore(AlertConfig::default(), a.list().into_iter().rev().collect());
        assert!(b.list().iter().all(|x| !x.active));
        let mut b = b;
        let next = b.raise("r", AlertKind::Offline, "again".into(), 9_000);
        assert_eq!(next.id, 4);
    }
}
