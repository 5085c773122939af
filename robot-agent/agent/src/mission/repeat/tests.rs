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
