//! Keeps a navigation computer's waypoint list in step with the mission terranav runs
//! (methods.md §7): a new mission's route goes out as a `$NALST` list (from the waypoint the agent
//! heads for), every later change of the route (a detour spliced in, a point pushed off an
//! obstacle, a re-planned path) as the one `$CAREM`/`$CAINS` edit that turns the NC's list into
//! the route, and the speed as `$CASPD` whenever it changes and once a second besides (UDP loses
//! datagrams; the speed is what stops the robot). No mission: speed 0.
//!
//! The list covers the route from where the mission started; waypoints the NC has passed stay in
//! it, so the ids of the points ahead never shift under the NC's feet except by the edits.

use super::OrpheusGateway;
use crate::runtime::route::RouteOrder;

/// 1-sigma position error sent with every waypoint, metres: the route comes from RTK-anchored
/// poses; the NC's own tolerance for reaching a point is its business.
pub const WAYPOINT_ERR_M: f64 = 0.05;

/// The speed is sent again after this long even when unchanged, seconds.
pub const SPEED_REPEAT_S: f64 = 1.0;

/// Two waypoints closer than this are the same, degrees (about 1 mm): the NC's list holds what
/// the sentences carried, rounded to 1e-6 minutes.
const SAME_DEG: f64 = 1e-8;

/// What was sent so far.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct SyncCounts {
    /// Route lists sent.
    pub lists: u64,
    /// Edits sent (one `$CAREM`...`$CAINS,END` exchange each).
    pub edits: u64,
    /// Waypoints removed by edits.
    pub removed: u64,
    /// Waypoints inserted by edits.
    pub inserted: u64,
    /// `$CASPD` sentences sent.
    pub speeds: u64,
}

/// See the module docs.
#[derive(Clone, Debug, Default)]
pub struct RouteSync {
    mission: Option<String>,
    /// Index in the mission's route of the NC's waypoint 0.
    offset: usize,
    speed: Option<(u8, f64)>,
    /// What was sent so far.
    pub counts: SyncCounts,
}

impl RouteSync {
    /// A sync that has sent nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// The sentences that bring the NC (whose list `gw` mirrors) to `order` at session time
    /// `t_s`; `None`: no mission, hold the robot.
    pub fn update(
        &mut self,
        gw: &mut OrpheusGateway,
        order: Option<&RouteOrder>,
        t_s: f64,
    ) -> Vec<String> {
        let mut out = Vec::new();
        let pct = match order {
            None => {
                self.mission = None;
                0
            }
            Some(o) => {
                if self.mission.as_deref() != Some(o.mission.as_str()) {
                    self.offset = o.next.min(o.waypoints_deg.len());
                    out.extend(gw.send_list(&o.waypoints_deg[self.offset..], WAYPOINT_ERR_M));
                    self.mission = Some(o.mission.clone());
                    self.counts.lists += 1;
                } else {
                    let want = &o.waypoints_deg[self.offset.min(o.waypoints_deg.len())..];
                    if let Some((from, to, new)) = edit_span(gw, want) {
                        let (removed, inserted) = (to - from, new.len());
                        match gw.splice(from as u32, to as u32, new, WAYPOINT_ERR_M) {
                            Ok(lines) => {
                                out.extend(lines);
                                self.counts.edits += 1;
                                self.counts.removed += removed as u64;
                                self.counts.inserted += inserted as u64;
                            }
                            // Cannot happen for a span inside the list; resend it whole.
                            Err(_) => out.extend(gw.send_list(want, WAYPOINT_ERR_M)),
                        }
                    }
                }
                o.speed_pct
            }
        };
        let due = match self.speed {
            Some((last, at)) => last != pct || t_s - at >= SPEED_REPEAT_S || !out.is_empty(),
            None => true,
        };
        if due {
            out.push(OrpheusGateway::speed_limit(pct));
            self.speed = Some((pct, t_s));
            self.counts.speeds += 1;
        }
        out
    }

    /// The mission whose route the NC has.
    pub fn mission(&self) -> Option<&str> {
        self.mission.as_deref()
    }
}

fn same(a: (f64, f64), b: (f64, f64)) -> bool {
    (a.0 - b.0).abs() < SAME_DEG && (a.1 - b.1).abs() < SAME_DEG
}

/// An edit of the NC's list: ids `from..to` replaced by the points.
type Span<'a> = (usize, usize, &'a [(f64, f64)]);

/// The one edit that turns the NC's list into `want`: the ids between the common prefix and the
/// common suffix replaced by `want`'s points between them.
fn edit_span<'a>(gw: &OrpheusGateway, want: &'a [(f64, f64)]) -> Option<Span<'a>> {
    let have: Vec<(f64, f64)> = gw.route().iter().map(|p| (p.lat_deg, p.lon_deg)).collect();
    let prefix = have
        .iter()
        .zip(want)
        .take_while(|(a, b)| same(**a, **b))
        .count();
    if prefix == have.len() && prefix == want.len() {
        return None;
    }
    let suffix = have[prefix..]
        .iter()
        .rev()
        .zip(want[prefix..].iter().rev())
        .take_while(|(a, b)| same(**a, **b))
        .count();
    Some((
        prefix,
        have.len() - suffix,
        &want[prefix..want.len() - suffix],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::navcomp::ReferenceNavComputer;

    fn order(mission: &str, pts: &[(f64, f64)], next: usize, pct: u8) -> RouteOrder {
        RouteOrder {
            t_s: 0.0,
            mission: mission.into(),
            waypoints_deg: pts.to_vec(),
            next,
            speed_pct: pct,
            hold: None,
        }
    }

    fn line(n: usize) -> Vec<(f64, f64)> {
        (0..n).map(|i| (48.0 + i as f64 * 1e-5, 11.0)).collect()
    }

    fn apply(nc: &mut ReferenceNavComputer, lines: &[String]) {
        for l in lines {
            nc.apply(l).unwrap();
        }
    }

    #[test]
    fn a_new_mission_sends_its_list_from_the_next_waypoint_then_edits_only_changes() {
        let mut gw = OrpheusGateway::new();
        let mut s = RouteSync::new();
        let route = line(10);
        let out = s.update(&mut gw, Some(&order("repeat:a#1", &route, 2, 100)), 0.0);
        assert_eq!(out.iter().filter(|l| l.starts_with("$NALST")).count(), 9);
        assert!(out.last().unwrap().starts_with("$CASPD,100"));
        assert_eq!(gw.route().len(), 8);
        assert!((gw.route()[0].lat_deg - route[2].0).abs() < 1e-9);
        // Nothing changed: nothing to send until the speed is due again.
        assert!(s
            .update(&mut gw, Some(&order("repeat:a#1", &route, 3, 100)), 0.5)
            .is_empty());
        assert_eq!(
            s.update(&mut gw, Some(&order("repeat:a#1", &route, 3, 100)), 1.0),
            vec![OrpheusGateway::speed_limit(100)]
        );
        // A detour replaces route points 5..7 by three points: one edit, and the NC's copy of
        // the list follows (the ids are shifted by the offset 2).
        let mut nc = ReferenceNavComputer {
            route: gw.route().to_vec(),
            speed_pct: 100,
        };
        let mut detoured = route.clone();
        detoured.splice(5..7, [(48.1, 11.1), (48.2, 11.2), (48.3, 11.3)]);
        let out = s.update(&mut gw, Some(&order("repeat:a#1", &detoured, 4, 100)), 1.2);
        assert_eq!(out.iter().filter(|l| l.starts_with("$CAREM,")).count(), 3);
        assert_eq!(out.iter().filter(|l| l.starts_with("$CAINS,")).count(), 4);
        apply(&mut nc, &out);
        let want = &detoured[2..];
        assert_eq!(nc.route.len(), want.len());
        for (p, w) in nc.route.iter().zip(want) {
            assert!(same((p.lat_deg, p.lon_deg), *w), "{p:?} vs {w:?}");
        }
        assert_eq!(s.counts.edits, 1);
        assert_eq!((s.counts.removed, s.counts.inserted), (2, 3));
    }

    #[test]
    fn holding_and_ending_send_speed_zero_and_a_new_mission_a_new_list() {
        let mut gw = OrpheusGateway::new();
        let mut s = RouteSync::new();
        let route = line(4);
        s.update(&mut gw, Some(&order("goal:1#1", &route, 0, 80)), 0.0);
        assert_eq!(
            s.update(&mut gw, Some(&order("goal:1#1", &route, 0, 0)), 0.1),
            vec![OrpheusGateway::speed_limit(0)]
        );
        assert!(
            s.update(&mut gw, None, 0.2).is_empty(),
            "already at 0: nothing until the repeat is due"
        );
        assert_eq!(
            s.update(&mut gw, None, 1.2),
            vec![OrpheusGateway::speed_limit(0)]
        );
        let out = s.update(&mut gw, Some(&order("goal:2#2", &line(3), 0, 50)), 1.3);
        assert_eq!(out.iter().filter(|l| l.starts_with("$NALST")).count(), 4);
        assert_eq!(s.counts.lists, 2);
        assert_eq!(s.mission(), Some("goal:2#2"));
    }
}
