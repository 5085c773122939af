//! Scoring the traversability mapper in the built-in world (`robot-agent map eval`): the
//! scenario's `[drive]` polyline is driven by the scripted driver, every sweep goes through the
//! mapper at the true or the SLAM pose, and the classification before inflation is compared with
//! the world's truth labels over the cells the sensor observed.

use anyhow::Context;
use common::grid::{encode_tile, CellState};
use mapping::{Class, Mapper, RobotPose};
use nalgebra::{Isometry3, Point3};
use sensing::{Point, Scan};
use serde::Serialize;
use sim::labels::{REASON_HOLE, REASON_OBSTACLE, REASON_STEP};
use std::time::Instant;

/// Options of one evaluation run.
#[derive(Clone, Debug)]
pub struct MapEvalOptions {
    /// Simulator seed (noise, nothing else: walkers follow their scripts).
    pub seed: u64,
    /// Map at the simulator's true poses (de-skewed with the true motion) instead of SLAM's.
    pub use_truth_poses: bool,
    /// Stop after this much simulated time even if the drive is not done, seconds.
    pub max_duration_s: f64,
    /// Mapper parameters.
    pub mapper: mapping::Config,
    /// SLAM parameters (when not using truth poses).
    pub slam: slam::Config,
    /// Robot profile of the simulated robot (and of the truth labels).
    pub profile: common::robot::RobotProfile,
    /// Ignore truth cells within this distance of where any walker went: the cells walkers
    /// crossed are scored separately (`walker_cells`, `walker_false_obstacles`).
    pub walker_margin_m: f64,
    /// Write every published tile, exact (postcard of `common::grid::Tile`, before the wire's
    /// quantization), into this folder as `NNNNNN-TX_TY.tile`: a corpus for codec work.
    pub tiles_out: Option<std::path::PathBuf>,
}

impl Default for MapEvalOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            use_truth_poses: false,
            max_duration_s: 1200.0,
            mapper: mapping::Config::default(),
            slam: slam::Config::default(),
            profile: common::robot::RobotProfile::default(),
            walker_margin_m: 0.0,
            tiles_out: None,
        }
    }
}

/// The scores of one run (`robot-agent map eval` prints these).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct MapEvalReport {
    /// Scenario name.
    pub scenario: String,
    /// Scored cells: observed (traversable or obstacle before inflation) and labelled.
    pub cells: usize,
    /// Share of scored cells whose class matches the truth.
    pub accuracy: f64,
    /// Share of observed truth obstacles (solids, steps of at least `max_step_m`, slopes, holes)
    /// the mapper marks as obstacles.
    pub obstacle_recall: f64,
    /// Share of observed truth-traversable cells the mapper marks as obstacles.
    pub false_obstacle_rate: f64,
    /// Curb band (truth step of 4-11 cm, the heights the source smoothed away): share of those
    /// cells classified as the truth says (5 cm traversable, 10 cm obstacle).
    pub curb5_10_recall: f64,
    /// Cells in the curb band scored.
    pub curb_cells: usize,
    /// Of them, 10 cm class steps (truth obstacle) marked as obstacles.
    pub curb10_detected: f64,
    /// Of them, 5 cm class steps (truth traversable) left traversable.
    pub curb5_traversable: f64,
    /// Per-cell accuracy (no boundary tolerance).
    pub strict_accuracy: f64,
    /// Per-cell obstacle recall.
    pub strict_obstacle_recall: f64,
    /// Per-cell false obstacle rate.
    pub strict_false_obstacle_rate: f64,
    /// Truth obstacle cells scored.
    pub obstacle_cells: usize,
    /// Observed cells still undecided (too few points around): not scored.
    pub undecided_cells: usize,
    /// Cells with ground but no headroom seen (under car bodies, in edge shadows): not scored.
    pub overhung_cells: usize,
    /// Truth step cells not scored because the sensor saw only one side of the step.
    pub one_sided_steps: usize,
    /// Cells whose stale evidence free space cleared, over the run.
    pub cleared_cells: usize,
    /// Mean wall-clock time of one mapper update, milliseconds.
    pub ms_per_update: f64,
    /// Worst update, milliseconds.
    pub ms_max: f64,
    /// Sweeps mapped.
    pub scans: usize,
    /// Simulated seconds.
    pub duration_s: f64,
    /// Distance driven, metres.
    pub path_m: f64,
    /// Tiles published (every version).
    pub tiles_published: usize,
    /// Mean encoded size of a published tile, bytes.
    pub mean_tile_bytes: f64,
    /// Encoded bytes published per simulated second while driving.
    pub tile_bytes_per_s: f64,
    /// Truth-traversable cells that walkers crossed (scored in the totals too).
    pub walker_cells: usize,
    /// Of them, still marked as obstacles at the end.
    pub walker_false_obstacles: usize,
    /// SLAM fell back to its prior (0 with truth poses).
    pub slam_failures: usize,
    /// Largest horizontal SLAM position error over the run, metres (0 with truth poses).
    pub slam_max_error_m: f64,
    /// Largest SLAM height error, metres.
    pub slam_max_z_error_m: f64,
    /// Largest SLAM tilt error (angle between estimated and true up axes), degrees.
    pub slam_max_tilt_error_deg: f64,
    /// Mean SLAM tilt error, degrees.
    pub slam_mean_tilt_error_deg: f64,
    /// Collisions of the scripted drive (the drive should have none).
    pub collisions: usize,
    /// [`common::grid::map_digest`] of the final map: equal digests, equal maps.
    pub map_digest: String,
    /// Wrong cells by kind: missed obstacles by truth reason, false obstacles by mapper class.
    pub errors: ErrorCounts,
    /// The wrong cells themselves (global lattice index, kind), for drawing.
    #[serde(skip)]
    pub error_cells: Vec<(i64, i64, ErrorKind)>,
}

/// What went wrong in one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub enum ErrorKind {
    /// Truth obstacle (a solid) marked traversable.
    MissedSolid,
    /// Truth step marked traversable.
    MissedStep,
    /// Truth slope marked traversable.
    MissedSlope,
    /// Truth hole marked traversable.
    MissedHole,
    /// Truth traversable marked obstacle.
    FalseObstacle,
    /// Truth traversable marked negative obstacle.
    FalseNegativeObstacle,
}

/// Wrong cells by kind.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct ErrorCounts {
    /// Solids missed.
    pub missed_solid: usize,
    /// Steps missed.
    pub missed_step: usize,
    /// Slopes missed.
    pub missed_slope: usize,
    /// Holes missed.
    pub missed_hole: usize,
    /// False positive obstacles.
    pub false_obstacle: usize,
    /// False negative obstacles (drop-offs that are not there).
    pub false_negative_obstacle: usize,
}

/// Per-scan statistics as the run goes (for a progress line).
#[derive(Clone, Copy, Debug, Default)]
pub struct MapEvalProgress {
    /// Simulated time, seconds.
    pub t_s: f64,
    /// Share of the drive done (by vertices passed), 0..1.
    pub done: f64,
}

/// Drives the scenario's `[drive]` and maps every sweep; returns the scores and the mapper.
pub fn run(
    scenario: &sim::Scenario,
    opts: &MapEvalOptions,
    mut progress: impl FnMut(MapEvalProgress),
) -> anyhow::Result<(MapEvalReport, Mapper)> {
    let drive = scenario
        .drive
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("scenario {} has no [drive] polyline", scenario.name))?;
    let mut mcfg = opts.mapper.clone();
    mcfg.sensor_height_m = opts.profile.lidar.xyz_m[2];
    mcfg.footprint_length_m = opts.profile.length_m;
    mcfg.footprint_width_m = opts.profile.width_m;
    mcfg.h_r_m = opts.profile.height_m;
    let mut mapper = Mapper::new(mcfg)?;
    let mut scfg = opts.slam.clone();
    scfg.sensor.lidar_xyz_m = opts.profile.lidar.xyz_m;
    scfg.sensor.lidar_rpy_rad = opts.profile.lidar.rpy_deg.map(f64::to_radians);
    let mut slam = slam::Slam::new(scfg);
    let sim_cfg = sim::SimConfig {
        seed: opts.seed,
        robot: opts.profile.clone(),
        ..sim::SimConfig::default()
    };
    let mut simu = sim::Simulation::new(scenario, sim_cfg);
    let lidar_ext = simu.lidar_extrinsic();
    let mut driver = sim::drive::PathDriver::new(&drive.points, drive.speed_mps);
    let mut rep = MapEvalReport {
        scenario: scenario.name.clone(),
        ..MapEvalReport::default()
    };
    let dt = 0.01;
    let mut map_from_slam: Option<Isometry3<f64>> = None;
    let (mut tilt_sum, mut tilt_n) = (0.0f64, 0usize);
    let (mut ms_sum, mut tile_bytes) = (0.0f64, 0usize);
    let mut walker_trace: Vec<(f64, f64)> = Vec::new();
    let mut last = simu.truth_pose2();
    let mut last_progress = 0.0;
    let n_vertices = drive.points.len().max(1) as f64;
    while !driver.is_done() && simu.time_s() < opts.max_duration_s {
        let (v, w) = driver.command(&simu.truth_pose2());
        let out = simu.step(dt, v, w);
        rep.collisions += out.collisions.len();
        let p = simu.truth_pose2();
        rep.path_m += p.distance_to(&last);
        last = p;
        if let Some(o) = out.odom {
            slam.push_odometry(o);
        }
        for wk in simu.walkers() {
            if walker_trace
                .last()
                .is_none_or(|q| (q.0 - wk.x_m).hypot(q.1 - wk.y_m) > 0.1)
            {
                walker_trace.push((wk.x_m, wk.y_m));
            }
        }
        let Some(scan) = out.scan else { continue };
        let t = scan.stamp_s;
        let truth_base = simu.truth_pose_at(t).unwrap_or_else(|| simu.truth_pose());
        let (points_map, origin, robot) = if opts.use_truth_poses {
            let mid = simu
                .truth_pose_at(t + 0.05)
                .unwrap_or_else(|| simu.truth_pose())
                * lidar_ext;
            let o = mid.translation.vector;
            (
                deskew_with_truth(&simu, &scan, &lidar_ext),
                [o.x, o.y, o.z],
                robot_pose(&truth_base),
            )
        } else {
            let o = match slam.process(&scan) {
                Ok(o) => o,
                Err(e) => {
                    rep.slam_failures += 1;
                    tracing::warn!("SLAM at {t:.2} s: {e}");
                    continue;
                }
            };
            rep.slam_failures += usize::from(o.diagnostics.fell_back_to_prior);
            // The SLAM frame is anchored at the true first pose (what GNSS does on the robot),
            // so the scores measure SLAM drift, not an arbitrary frame offset.
            let anchor = *map_from_slam.get_or_insert(truth_base * o.pose_map_base.inverse());
            let pose_lidar = anchor * o.pose_map_lidar;
            let base = anchor * o.pose_map_base;
            let err = (base.translation.vector - truth_base.translation.vector)
                .xy()
                .norm();
            rep.slam_max_error_m = rep.slam_max_error_m.max(err);
            let dz = (base.translation.vector.z - truth_base.translation.vector.z).abs();
            rep.slam_max_z_error_m = rep.slam_max_z_error_m.max(dz);
            // Tilt error: the angle between the estimated and the true up axis.
            let up_est = base.rotation * nalgebra::Vector3::z();
            let up_true = truth_base.rotation * nalgebra::Vector3::z();
            let tilt = up_est.angle(&up_true).to_degrees();
            rep.slam_max_tilt_error_deg = rep.slam_max_tilt_error_deg.max(tilt);
            tilt_sum += tilt;
            tilt_n += 1;
            let pts = o.deskewed.as_deref().unwrap_or(&scan.points);
            let org = pose_lidar.translation.vector;
            (
                transform(pts, &pose_lidar),
                [org.x, org.y, org.z],
                robot_pose(&base),
            )
        };
        let t0 = Instant::now();
        let u = mapper.update_sweep(points_map, origin, &robot, t)?;
        rep.cleared_cells += u.cleared_cells;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        ms_sum += ms;
        rep.ms_max = rep.ms_max.max(ms);
        rep.scans += 1;
        if let Some(dir) = &opts.tiles_out {
            for (k, t) in u.tiles.iter().enumerate() {
                let seq = rep.tiles_published + k;
                let path = dir.join(format!("{seq:06}-{}_{}.tile", t.index.tx, t.index.ty));
                std::fs::write(&path, postcard::to_allocvec(t)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        rep.tiles_published += u.tiles.len();
        tile_bytes += u.tiles.iter().map(|t| encode_tile(t).len()).sum::<usize>();
        let done = driver_progress(&driver, &drive.points, &p) / n_vertices;
        if simu.time_s() - last_progress >= 1.0 {
            last_progress = simu.time_s();
            progress(MapEvalProgress {
                t_s: simu.time_s(),
                done,
            });
        }
    }
    rep.duration_s = simu.time_s();
    rep.slam_mean_tilt_error_deg = tilt_sum / tilt_n.max(1) as f64;
    rep.ms_per_update = ms_sum / rep.scans.max(1) as f64;
    rep.mean_tile_bytes = tile_bytes as f64 / rep.tiles_published.max(1) as f64;
    rep.tile_bytes_per_s = tile_bytes as f64 / rep.duration_s.max(1e-9);
    score(
        &mapper,
        simu.world(),
        &sim::LabelParams::from_profile(&opts.profile),
        &walker_trace,
        &mut rep,
    );
    rep.map_digest = common::grid::map_digest(&mapper.tiles());
    Ok((rep, mapper))
}

/// Scores the mapper's classes against the world's labels into `rep`.
///
/// Main numbers use a one-cell (one `grid_size`) tolerance at class boundaries, the usual
/// convention for scoring boundaries on a raster: a truth obstacle counts as found when the
/// mapper marks an obstacle in its cell or one of the 8 around it, and a mapper obstacle is
/// false only when no truth obstacle lies within that neighbourhood. A curb on a cell border
/// is labelled in both cells, a car's side in the cells its footprint touches; which of two
/// adjacent cells gets the points of a vertical face is a matter of centimetres. The per-cell
/// numbers are reported too (`strict_*`).
pub fn score(
    mapper: &Mapper,
    world: &sim::World,
    params: &sim::LabelParams,
    walker_trace: &[(f64, f64)],
    rep: &mut MapEvalReport,
) {
    let Some(((x0, y0), (x1, y1))) = mapper.bounds() else {
        return;
    };
    let lattice = mapper.lattice();
    let (w, h) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
    let truth = world.truth_labels(&lattice, x0, y0, w, h, params);
    // Walker cells: within a body radius plus a cell of any traced walker position.
    let mut walker = vec![false; w * h];
    let s = lattice.cell_size_f64();
    let r_cells = ((0.3 + s) / s).ceil() as i64;
    for &(x, y) in walker_trace {
        let (cx, cy) = lattice.cell_of(x, y);
        for dy in -r_cells..=r_cells {
            for dx in -r_cells..=r_cells {
                let (i, j) = (cx + dx - x0, cy + dy - y0);
                if i >= 0 && j >= 0 && (i as usize) < w && (j as usize) < h {
                    walker[j as usize * w + i as usize] = true;
                }
            }
        }
    }
    // Per cell: mapper says obstacle (Some) / traversable (Some(false)) / not decided (None),
    // truth obstacle / traversable / outside.
    let said: Vec<Option<bool>> = (0..w * h)
        .map(|k| {
            let (cx, cy) = (x0 + (k % w) as i64, y0 + (k / w) as i64);
            match mapper.class(cx, cy) {
                Class::Traversable => Some(false),
                Class::Obstacle | Class::NegativeObstacle => Some(true),
                _ => None,
            }
        })
        .collect();
    let truth_obst: Vec<Option<bool>> = truth
        .cells
        .iter()
        .map(|t| match t.state {
            CellState::Traversable => Some(false),
            CellState::Obstacle => Some(true),
            _ => None,
        })
        .collect();
    let around = |v: &[Option<bool>], i: usize, j: usize| -> bool {
        for dj in -1i64..=1 {
            for di in -1i64..=1 {
                let (a, b) = (i as i64 + di, j as i64 + dj);
                if a >= 0
                    && b >= 0
                    && (a as usize) < w
                    && (b as usize) < h
                    && v[b as usize * w + a as usize] == Some(true)
                {
                    return true;
                }
            }
        }
        false
    };
    let mut n = Counts::default();
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            let (cx, cy) = (x0 + i as i64, y0 + j as i64);
            let class = mapper.class(cx, cy);
            match class {
                Class::Undecided => rep.undecided_cells += 1,
                Class::Overhung => rep.overhung_cells += 1,
                _ => {}
            }
            let (Some(said_obstacle), Some(is_obstacle)) = (said[k], truth_obst[k]) else {
                continue;
            };
            let Some(t) = truth.get(cx, cy) else { continue };
            // A step is a relation between two surfaces: where the sensor saw only one side of
            // it (the far edge of a raised sidewalk, whose lower side lies in the edge's shadow),
            // it cannot be told from a gentle slope, so it is not scored.
            // Both sides were seen when, for some neighbour across the step, a return landed
            // below the step's middle on the lower side and one above it on the upper side.
            if t.reasons == REASON_STEP {
                let both_sides = [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)]
                    .iter()
                    .any(|(di, dj)| {
                        let (a, b) = (cx + di, cy + dj);
                        let Some(tn) = truth.get(a, b) else {
                            return false;
                        };
                        let (hc, hn) = (f64::from(t.height_m), f64::from(tn.height_m));
                        if (hc - hn).abs() < 0.04 {
                            return false;
                        }
                        let mid = 0.5 * (hc + hn) as f32;
                        let ((lo_x, lo_y), (hi_x, hi_y)) = if hn < hc {
                            ((a, b), (cx, cy))
                        } else {
                            ((cx, cy), (a, b))
                        };
                        let low_seen = mapper.height_range(lo_x, lo_y).is_some_and(|r| r.0 < mid);
                        let high_seen = mapper.height_range(hi_x, hi_y).is_some_and(|r| r.1 > mid);
                        low_seen && high_seen
                    });
                if !both_sides {
                    rep.one_sided_steps += 1;
                    continue;
                }
            }
            n.cells += 1;
            n.strict_correct += usize::from(said_obstacle == is_obstacle);
            // Tolerant verdicts.
            let found = !is_obstacle || said_obstacle || around(&said, i, j);
            let false_alarm = said_obstacle && !is_obstacle && !around(&truth_obst, i, j);
            let ok = if is_obstacle { found } else { !false_alarm };
            n.correct += usize::from(ok);
            if is_obstacle {
                n.obst += 1;
                n.obst_hit += usize::from(found);
                n.strict_obst_hit += usize::from(said_obstacle);
            } else {
                n.free += 1;
                n.free_miss += usize::from(false_alarm);
                n.strict_free_miss += usize::from(said_obstacle);
                if walker[k] {
                    rep.walker_cells += 1;
                    rep.walker_false_obstacles += usize::from(false_alarm);
                }
            }
            if !ok {
                let kind = if said_obstacle {
                    if class == Class::NegativeObstacle {
                        rep.errors.false_negative_obstacle += 1;
                        ErrorKind::FalseNegativeObstacle
                    } else {
                        rep.errors.false_obstacle += 1;
                        ErrorKind::FalseObstacle
                    }
                } else if t.reasons & REASON_OBSTACLE != 0 {
                    rep.errors.missed_solid += 1;
                    ErrorKind::MissedSolid
                } else if t.reasons & REASON_HOLE != 0 {
                    rep.errors.missed_hole += 1;
                    ErrorKind::MissedHole
                } else if t.reasons & REASON_STEP != 0 {
                    rep.errors.missed_step += 1;
                    ErrorKind::MissedStep
                } else {
                    rep.errors.missed_slope += 1;
                    ErrorKind::MissedSlope
                };
                rep.error_cells.push((cx, cy, kind));
            }
            // The curb band: cells whose largest jump is a 4-11 cm step (not a slope or solid).
            let step = f64::from(t.step_m);
            if (0.04..=0.11).contains(&step)
                && t.reasons & (REASON_OBSTACLE | sim::labels::REASON_SLOPE | REASON_HOLE) == 0
            {
                if is_obstacle {
                    n.c10 += 1;
                    n.c10_hit += usize::from(found);
                } else {
                    n.c5 += 1;
                    n.c5_ok += usize::from(!false_alarm);
                }
            }
        }
    }
    let ratio = |a: usize, b: usize| if b == 0 { 1.0 } else { a as f64 / b as f64 };
    let rate = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    rep.cells = n.cells;
    rep.accuracy = ratio(n.correct, n.cells);
    rep.obstacle_recall = ratio(n.obst_hit, n.obst);
    rep.false_obstacle_rate = rate(n.free_miss, n.free);
    rep.strict_accuracy = ratio(n.strict_correct, n.cells);
    rep.strict_obstacle_recall = ratio(n.strict_obst_hit, n.obst);
    rep.strict_false_obstacle_rate = rate(n.strict_free_miss, n.free);
    rep.obstacle_cells = n.obst;
    rep.curb_cells = n.c10 + n.c5;
    rep.curb5_10_recall = ratio(n.c10_hit + n.c5_ok, n.c10 + n.c5);
    rep.curb10_detected = ratio(n.c10_hit, n.c10);
    rep.curb5_traversable = ratio(n.c5_ok, n.c5);
}

#[derive(Default)]
struct Counts {
    cells: usize,
    correct: usize,
    strict_correct: usize,
    obst: usize,
    obst_hit: usize,
    strict_obst_hit: usize,
    free: usize,
    free_miss: usize,
    strict_free_miss: usize,
    c10: usize,
    c10_hit: usize,
    c5: usize,
    c5_ok: usize,
}

/// Roughly how many drive vertices are behind the robot (for progress only).
fn driver_progress(
    _d: &sim::drive::PathDriver,
    points: &[[f64; 2]],
    p: &common::geom::Pose2,
) -> f64 {
    let mut best = (f64::INFINITY, 0usize);
    for (k, q) in points.iter().enumerate() {
        let d = (q[0] - p.x_m).hypot(q[1] - p.y_m);
        if d < best.0 {
            best = (d, k);
        }
    }
    best.1 as f64
}

/// The mapper's robot pose from `map<-base_link` (base_link is on the ground under the centre).
fn robot_pose(base: &Isometry3<f64>) -> RobotPose {
    let t = base.translation.vector;
    let fwd = base.rotation * nalgebra::Vector3::x();
    RobotPose {
        x_m: t.x,
        y_m: t.y,
        z_m: t.z,
        yaw_rad: fwd.y.atan2(fwd.x),
    }
}

fn transform(points: &[Point], pose: &Isometry3<f64>) -> Vec<[f32; 3]> {
    let m = pose.to_homogeneous().cast::<f32>();
    points
        .iter()
        .map(|p| {
            let v = m * nalgebra::Vector4::new(p.x, p.y, p.z, 1.0);
            [v.x, v.y, v.z]
        })
        .collect()
}

/// Every return at the true lidar pose of its own firing time (1 ms bins).
fn deskew_with_truth(
    simu: &sim::Simulation,
    scan: &Scan,
    lidar_ext: &Isometry3<f64>,
) -> Vec<[f32; 3]> {
    let mut poses: Vec<Option<nalgebra::Matrix4<f32>>> = vec![None; 201];
    let fallback = simu.truth_pose() * lidar_ext;
    scan.points
        .iter()
        .map(|p| {
            let k = ((f64::from(p.t_s) * 1000.0).round().max(0.0) as usize).min(200);
            let m = poses[k].get_or_insert_with(|| {
                let t = scan.stamp_s + k as f64 * 1e-3;
                (simu.truth_pose_at(t).map_or(fallback, |b| b * lidar_ext))
                    .to_homogeneous()
                    .cast::<f32>()
            });
            let q = m.transform_point(&Point3::new(p.x, p.y, p.z));
            [q.x, q.y, q.z]
        })
        .collect()
}
