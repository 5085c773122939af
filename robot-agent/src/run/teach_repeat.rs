//! Headless teach and repeat: teach a route by teleop, add obstacles, return home along it,
//! and score how closely the return tracked the taught path.

use super::obstacles::{distance_to_polyline, ObstacleFile};
use super::rig::{trace_enabled, Rig};
use super::HeadlessOptions;
use agent::command::{Command, CommandKind, Direction};
use agent::mission::Mode;
use agent::AgentConfig;
use serde::Serialize;

/// How far past a walker detour's rejoin point the robot still counts as on the detour for the
/// tracking numbers (it is converging onto the line there), metres.
const REJOIN_SETTLE_M: f64 = 1.0;
/// The report of a teach-and-repeat run (`robot-agent sim --headless --teach-repeat`).
#[derive(Clone, Debug, Serialize)]
pub struct TeachRepeatReport {
    /// `reached`, `blocked`, `timeout` or `collision`.
    pub outcome: String,
    /// RMS lateral distance to the taught path on free stretches, metres. Not free: within 3 m
    /// of an added obstacle, and any detour (round a person or an added obstacle) until 1 m past its
    /// rejoin point.
    pub tracking_rms_m: f64,
    /// Worst lateral distance on free stretches, metres.
    pub tracking_max_m: f64,
    /// Detours spliced in.
    pub detours: u32,
    /// Of those, detours around a person standing on the route (a walker within 2 m of the
    /// blockage when the detour was planned); their stretches are not free.
    pub walker_detours: u32,
    /// Per detour: straight-line distance from the rejoin point to the nearest added obstacle's
    /// footprint (for a detour around a person, to where the person stood), metres.
    pub rejoin_distance_m: Vec<f64>,
    /// Where detours began that no added obstacle explains (blocked point more than 3 m from
    /// every added obstacle), map frame, metres.
    pub unexplained_detours_m: Vec<[f64; 2]>,
    /// Collisions (truth).
    pub collisions: u32,
    /// Distance from the taught start (home) at the end, metres.
    pub final_error_m: f64,
    /// Taught waypoints.
    pub waypoints: usize,
    /// Taught route length, metres.
    pub route_length_m: f64,
    /// Simulated time of the return, seconds.
    pub time_s: f64,
    /// Sweeps (teach and return) left out of the map because SLAM's pose was thrown off.
    pub scans_not_mapped: u64,
    /// [`common::grid::map_digest`] of the robot's map at the end.
    pub map_digest: String,
    /// The recording (`--mcap`), with the run's digest.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub record: Option<crate::record::RecordSummary>,
}

/// Teach along the scenario's teach path by teleop, add obstacles, return home along the route.
pub fn run_teach_repeat(
    scenario: &sim::Scenario,
    cfg: AgentConfig,
    obstacles: Option<&ObstacleFile>,
    opts: &HeadlessOptions,
) -> anyhow::Result<TeachRepeatReport> {
    let teach = scenario
        .teach
        .clone()
        .ok_or_else(|| anyhow::anyhow!("scenario {} has no [teach] route", scenario.name))?;
    let mut rig = Rig::new(scenario, cfg, opts, "sim")?;
    if let Some(m) = &opts.mcap {
        rig.record_to(m, &format!("sim:{}", scenario.name), true)?;
    }
    while rig.agent.scans() < 3 {
        rig.step();
    }
    let t = rig.t_s();
    rig.command(Command::at(
        t,
        CommandKind::Record {
            name: "teach".into(),
        },
    ))?;
    // The operator: a scripted driver on the truth pose, sent through the agent's teleop path
    // exactly as the station's drive commands arrive.
    let mut driver = sim::drive::PathDriver::new(&teach.points, teach.speed_mps.min(0.5));
    let mut seq = 0u32;
    let mut taught_truth: Vec<(f64, f64)> = Vec::new();
    while !driver.is_done() {
        let ev = rig.step();
        if ev.control {
            let (v, w) = driver.command(&rig.truth());
            seq += 1;
            let t = rig.t_s();
            rig.command(Command::at(
                t,
                CommandKind::Drive {
                    seq,
                    // As the station's drive commands arrive: f32 on the wire.
                    v_mps: f64::from(v as f32),
                    omega_rps: f64::from(w as f32),
                    deadman: true,
                },
            ))?;
            let p = rig.truth();
            if trace_enabled() {
                eprintln!("trace teach t {:.1} {}", rig.t_s(), rig.pose_error_text());
            }
            if taught_truth
                .last()
                .is_none_or(|q| (q.0 - p.x_m).hypot(q.1 - p.y_m) >= 0.05)
            {
                taught_truth.push((p.x_m, p.y_m));
            }
        }
        if rig.t_s() > opts.timeout_s {
            anyhow::bail!("teach drive did not finish within {} s", opts.timeout_s);
        }
    }
    // The robot coasts to a stop; that is still the taught path.
    for _ in 0..50 {
        rig.step();
        let p = rig.truth();
        if taught_truth
            .last()
            .is_none_or(|q| (q.0 - p.x_m).hypot(q.1 - p.y_m) >= 0.05)
        {
            taught_truth.push((p.x_m, p.y_m));
        }
    }
    let t = rig.t_s();
    rig.command(Command::at(t, CommandKind::StopRecording))?;
    let route = rig
        .agent
        .take_taught_route()
        .ok_or_else(|| anyhow::anyhow!("no route recorded"))?;
    let waypoints = route.points.len();
    let route_length_m: f64 = route
        .points
        .windows(2)
        .map(|w| (w[1].x_m - w[0].x_m).hypot(w[1].y_m - w[0].y_m))
        .sum();
    let home = taught_truth.first().copied().unwrap_or_default();
    if let Some(obs) = obstacles {
        rig.sim.add_obstacles(&obs.obstacles());
    }
    let collisions_before = rig.collisions;
    let t = rig.t_s();
    rig.command(Command::at(
        t,
        CommandKind::Repeat {
            route: route.clone(),
            direction: Direction::Reverse,
        },
    ))?;
    let t_start = rig.t_s();
    // Per control cycle: lateral distance to the taught path, position, and whether the robot
    // was on a detour (not a free stretch, whatever the map says).
    let mut lateral: Vec<(f64, (f64, f64), bool)> = Vec::new();
    let mut seen_detours = (0usize, 0u32);
    // (detour index, where the walker stood when it was planned).
    let mut walker_detours: Vec<(usize, (f64, f64))> = Vec::new();
    // The rejoin point of the detour the robot is on or has just left.
    let mut settling: Option<(f64, f64)> = None;
    let outcome = loop {
        let ev = rig.step();
        if ev.collisions > 0 && opts.stop_on_collision {
            break "collision";
        }
        if ev.control {
            let p = rig.truth();
            // A detour (or re-plan) that begins with a walker within 2 m of the blockage is a
            // detour around that person.
            if let Some(f) = rig.agent.mission().repeat_or_last().map(|r| &r.follower) {
                if let Some(d) = f.detours.last() {
                    let now = (f.detours.len(), d.replans);
                    if now != seen_detours {
                        seen_detours = now;
                        let by_walker = rig.sim.walkers().into_iter().find(|w| {
                            (w.x_m - d.blocked_m.0).hypot(w.y_m - d.blocked_m.1) < 2.0 + w.radius_m
                        });
                        let k = f.detours.len() - 1;
                        if let Some(w) = by_walker {
                            walker_detours.retain(|(j, _)| *j != k);
                            walker_detours.push((k, (w.x_m, w.y_m)));
                        }
                    }
                }
            }
            // Any detour (round a person or round an added obstacle) is off the taught line on
            // purpose: not a free stretch, however far it swings from the obstacle (a wide
            // detour's return leg can pass more than the 3 m round the obstacle).
            let detour = rig
                .agent
                .mission()
                .repeat_or_last()
                .map(|r| &r.follower)
                .and_then(|f| {
                    let k = f.detours.len().checked_sub(1)?;
                    f.on_detour().then(|| f.detours[k].rejoin_m)
                });
            // The follower is back on the route once the rejoin point is within its reach
            // (`reached_radius_m`), still converging onto the line: that approach belongs to the
            // detour until the robot is `REJOIN_SETTLE_M` past the rejoin point.
            if let Some(j) = detour {
                settling = Some(j);
            }
            let near_rejoin =
                settling.is_some_and(|j| (p.x_m - j.0).hypot(p.y_m - j.1) <= REJOIN_SETTLE_M);
            if detour.is_none() && !near_rejoin {
                settling = None;
            }
            let on_detour = detour.is_some() || near_rejoin;
            lateral.push((
                distance_to_polyline(&taught_truth, (p.x_m, p.y_m)),
                (p.x_m, p.y_m),
                on_detour,
            ));
            if trace_enabled() {
                let est = rig
                    .agent
                    .localiser()
                    .pose_now()
                    .map(|p| p.planar)
                    .unwrap_or_default();
                let cmd = rig.agent.driver().last_cmd();
                let sv = rig.agent.driver().safety();
                let walker = rig
                    .sim
                    .walkers()
                    .iter()
                    .map(|w| {
                        let (c, s) = (p.yaw_rad.cos(), p.yaw_rad.sin());
                        let (dx, dy) = (w.x_m - p.x_m, w.y_m - p.y_m);
                        (c * dx + s * dy, -s * dx + c * dy)
                    })
                    .min_by(|a, b| a.0.hypot(a.1).total_cmp(&b.0.hypot(b.1)));
                eprintln!(
                    "trace   safety stop {} turn_blocked {} clearance {:.2} nearest walker (body frame) {:?}",
                    sv.stop, sv.turn_blocked, sv.clearance_m, walker
                );
                eprintln!(
                    "trace t {:.1} {} lat {:.3} cmd {:.2} {:.2} hold {} err {:?}",
                    rig.t_s(),
                    rig.pose_error_text(),
                    lateral.last().map_or(0.0, |l| l.0),
                    cmd.v_mps,
                    cmd.omega_rps,
                    rig.agent
                        .mission()
                        .repeat()
                        .is_some_and(|r| r.follower.holding()),
                    rig.agent.last_error()
                );
                if let Some(f) = rig.agent.mission().repeat_or_last().map(|r| &r.follower) {
                    let (k, n, left) = f.progress(&est);
                    let path = f.follow_path(&est);
                    eprintln!(
                        "trace   repeat {:?} next {k}/{n} ({:?}) left {left:.1} m follow {:?}",
                        rig.agent.mission().repeat().and_then(|r| r.last.as_ref()),
                        f.waypoints().get(k).map(|w| w.taught),
                        &path[..path.len().min(4)]
                    );
                }
            }
            if rig.agent.mode() != Mode::Repeat {
                break "reached";
            }
        }
        if rig.t_s() - t_start > opts.timeout_s {
            break "timeout";
        }
    };
    for _ in 0..100 {
        rig.step();
    }
    let detours = rig
        .agent
        .mission()
        .repeat_or_last()
        .map(|r| r.follower.detours.clone())
        .unwrap_or_default();
    // Free stretches: away from every obstacle that was added (their footprint plus 3 m), and
    // not on a detour.
    let near_obstacle = |p: (f64, f64)| obstacles.is_some_and(|o| o.distance_to(p) < 3.0);
    let free: Vec<f64> = lateral
        .iter()
        .filter(|(_, p, detour)| !near_obstacle(*p) && !detour)
        .map(|(d, _, _)| *d)
        .collect();
    let rms = if free.is_empty() {
        0.0
    } else {
        (free.iter().map(|d| d * d).sum::<f64>() / free.len() as f64).sqrt()
    };
    let max = free.iter().copied().fold(0.0, f64::max);
    // Past the obstacle: the added one, or where the person stood.
    let walker_at = |k: usize| walker_detours.iter().find(|(j, _)| *j == k).map(|w| w.1);
    let rejoin_distance_m = detours
        .iter()
        .enumerate()
        .map(|(k, d)| match walker_at(k) {
            Some(w) => (d.rejoin_m.0 - w.0).hypot(d.rejoin_m.1 - w.1),
            None => obstacles.map_or(0.0, |o| o.distance_to(d.rejoin_m)),
        })
        .collect();
    // Detours whose blockage is nowhere near an added obstacle or a walker: the mapper saw
    // something on a free stretch.
    let unexplained_detours_m = detours
        .iter()
        .enumerate()
        .filter(|(k, d)| {
            obstacles.is_none_or(|o| o.distance_to(d.blocked_m) > 3.0) && walker_at(*k).is_none()
        })
        .map(|(_, d)| [d.blocked_m.0, d.blocked_m.1])
        .collect();
    if let Some(png) = &opts.map_png {
        let path: Vec<(f64, f64)> = lateral.iter().map(|(_, p, _)| *p).collect();
        rig.draw_map(&path, png)?;
    }
    let truth = rig.truth();
    Ok(TeachRepeatReport {
        outcome: if rig.collisions > collisions_before {
            "collision".into()
        } else {
            outcome.into()
        },
        tracking_rms_m: rms,
        tracking_max_m: max,
        detours: detours.len() as u32,
        walker_detours: walker_detours.len() as u32,
        rejoin_distance_m,
        unexplained_detours_m,
        collisions: rig.collisions - collisions_before,
        final_error_m: (truth.x_m - home.0).hypot(truth.y_m - home.1),
        waypoints,
        route_length_m,
        time_s: rig.t_s() - t_start,
        scans_not_mapped: rig.agent.scans_not_mapped(),
        map_digest: common::grid::map_digest(&rig.agent.all_tiles()),
        record: rig.finish_recording(),
    })
}
