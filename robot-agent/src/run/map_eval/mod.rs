//! Scoring the traversability map in the built-in world (`robot-agent map eval`): the
//! scenario's `[drive]` polyline is driven by the scripted driver while the robot agent runs its
//! own pipeline on the simulated sensors (the same localiser, terrain map and grids as a live
//! robot: SLAM with GNSS and IMU fusion), and the classification before inflation is compared
//! with the world's truth labels over the cells the sensor observed. With `use_truth_poses` the
//! sweeps are mapped at the simulator's true poses instead: the upper bound, labelled as such.

use super::{HeadlessOptions, Rig, ScanMode};
use agent::AgentConfig;
use anyhow::Context;
use common::grid::CellState;
use mapping::{Class, Mapper};
use sim::labels::{REASON_HOLE, REASON_OBSTACLE, REASON_STEP};
use std::cell::RefCell;
use std::rc::Rc;

mod report;
pub use report::{
    ErrorCounts, ErrorKind, GraphReport, HeightDiagnostics, MapEvalProgress, MapEvalReport,
    Percentiles, RebuildCheck,
};

/// Options of one evaluation run.
#[derive(Clone, Debug)]
pub struct MapEvalOptions {
    /// Simulator seed (noise, nothing else: walkers follow their scripts).
    pub seed: u64,
    /// Map at the simulator's true poses (de-skewed with the true motion) instead of the
    /// agent's own localisation: the upper bound.
    pub use_truth_poses: bool,
    /// Stop after this much simulated time even if the drive is not done, seconds.
    pub max_duration_s: f64,
    /// After the drive, the robot stands still (the agent running on) for at most this long
    /// while a map rebuild is under way, so that the map scored is the one after the last
    /// correction, as an operator would see it a few seconds after the mission, seconds
    /// (0: score the map as it is when the drive ends).
    pub settle_max_s: f64,
    /// The agent (its mapper, SLAM, GNSS handling, robot profile; the profile is also the
    /// simulated robot's and the truth labels').
    pub agent: AgentConfig,
    /// Ignore truth cells within this distance of where any walker went: the cells walkers
    /// crossed are scored separately (`walker_cells`, `walker_false_obstacles`).
    pub walker_margin_m: f64,
    /// Write every published tile, exact (postcard of `common::grid::Tile`, before the wire's
    /// quantization), into this folder as `NNNNNN-TX_TY.tile`: a corpus for codec work.
    pub tiles_out: Option<std::path::PathBuf>,
    /// At the end, also map the pose graph's kept sweeps again at the poses the final map has
    /// them at and score that map (`rebuild_check`): what a rebuild loses with no correction.
    pub rebuild_check: bool,
    /// Map points whose cell is traced: after every sweep that changes the cell's description
    /// (`Mapper::describe`), a line with the time and the pose against the truth goes to
    /// stderr. Why a cell ended up wrong is usually in when it changed and from where.
    pub trace_cells: Vec<(f64, f64)>,
    /// Also map every sweep at its true pose into a second map and score where the robot's map
    /// puts the poles and trunks against it (`obstacle_shifts`): the localisation's share of
    /// the position error. Ignored with `use_truth_poses`.
    pub truth_twin: bool,
}

impl Default for MapEvalOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            use_truth_poses: false,
            max_duration_s: 1200.0,
            settle_max_s: 60.0,
            agent: AgentConfig::default(),
            walker_margin_m: 0.0,
            tiles_out: None,
            rebuild_check: false,
            trace_cells: Vec::new(),
            truth_twin: false,
        }
    }
}

/// Drives the scenario's `[drive]` with the agent running; returns the scores and the map.
pub fn run(
    scenario: &sim::Scenario,
    opts: &MapEvalOptions,
    mut progress: impl FnMut(MapEvalProgress),
) -> anyhow::Result<(MapEvalReport, Mapper)> {
    let drive = scenario
        .drive
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("scenario {} has no [drive] polyline", scenario.name))?;
    let headless = HeadlessOptions {
        seed: opts.seed,
        ..HeadlessOptions::default()
    };
    let mut rig = Rig::new(scenario, opts.agent.clone(), &headless, "eval")?;
    rig.scan_mode = if opts.use_truth_poses {
        ScanMode::TruthPoses
    } else {
        ScanMode::Localised
    };
    if opts.truth_twin && !opts.use_truth_poses {
        let cfg = rig.agent.mapper().config().clone();
        rig.truth_twin =
            Some(Mapper::new(cfg).map_err(|e| anyhow::anyhow!("truth twin's mapper: {e}"))?);
    }
    let write_error: Rc<RefCell<Option<anyhow::Error>>> = Rc::default();
    if let Some(dir) = opts.tiles_out.clone() {
        let err = write_error.clone();
        let mut seq = 0usize;
        rig.tile_sink = Some(Box::new(move |t| {
            let path = dir.join(format!("{seq:06}-{}_{}.tile", t.index.tx, t.index.ty));
            seq += 1;
            let r = postcard::to_allocvec(t)
                .map_err(anyhow::Error::from)
                .and_then(|b| {
                    std::fs::write(&path, b).with_context(|| format!("writing {}", path.display()))
                });
            if let Err(e) = r {
                err.borrow_mut().get_or_insert(e);
            }
        }));
    }
    let mut driver = sim::drive::PathDriver::new(&drive.points, drive.speed_mps);
    let mut rep = MapEvalReport {
        scenario: scenario.name.clone(),
        truth_poses: opts.use_truth_poses,
        ..MapEvalReport::default()
    };
    let mut walker_trace: Vec<(f64, f64)> = Vec::new();
    let mut keyframe_log = super::graph_eval::KeyframeLog::default();
    let mut traced: Vec<String> = vec![String::new(); opts.trace_cells.len()];
    let mut last = rig.sim.truth_pose2();
    let mut last_progress = 0.0;
    let n_vertices = drive.points.len().max(1) as f64;
    let mut drive_end_s = None;
    while rig.t_s() < opts.max_duration_s {
        let (v, w) = if driver.is_done() {
            let end = *drive_end_s.get_or_insert(rig.t_s());
            if !rig.agent.terrain().rebuild_running() || rig.t_s() - end >= opts.settle_max_s {
                break;
            }
            (0.0, 0.0)
        } else {
            driver.command(&rig.sim.truth_pose2())
        };
        rig.drive_override = Some(agent::Cmd {
            v_mps: v,
            omega_rps: w,
        });
        let ev = rig.step();
        rep.collisions += ev.collisions as usize;
        rep.slam_failures += usize::from(ev.slam_failed);
        let p = rig.sim.truth_pose2();
        rep.path_m += p.distance_to(&last);
        last = p;
        for wk in rig.sim.walkers() {
            if walker_trace
                .last()
                .is_none_or(|q| (q.0 - wk.x_m).hypot(q.1 - wk.y_m) > 0.1)
            {
                walker_trace.push((wk.x_m, wk.y_m));
            }
        }
        if ev.scan {
            keyframe_log.record(&rig);
            trace_cells(&rig, &opts.trace_cells, &mut traced);
        }
        if let Some(e) = write_error.borrow_mut().take() {
            return Err(e);
        }
        if ev.scan && rig.t_s() - last_progress >= 1.0 {
            last_progress = rig.t_s();
            progress(MapEvalProgress {
                t_s: rig.t_s(),
                done: driver_progress(&drive.points, &p) / n_vertices,
            });
        }
    }
    rep.duration_s = rig.t_s();
    rep.settle_s = drive_end_s.map_or(0.0, |end| rig.t_s() - end);
    rep.scans = rig.scan.n as usize;
    rep.ms_per_update = rig.scan.mean();
    rep.ms_max = rig.scan.max;
    rep.tiles_published = rig.tiles_published;
    rep.mean_tile_bytes = rig.tile_bytes as f64 / rig.tiles_published.max(1) as f64;
    rep.tile_bytes_per_s = rig.tile_bytes as f64 / rep.duration_s.max(1e-9);
    rep.slam_max_error_m = rig.loc.xy_max_m;
    rep.slam_max_z_error_m = rig.loc.z_max_m;
    rep.slam_max_tilt_error_deg = rig.loc.tilt_max_deg;
    rep.slam_mean_tilt_error_deg = rig.loc.tilt_mean_deg;
    let (mut z, mut tilt): (Vec<f64>, Vec<f64>) =
        rig.loc_samples.iter().map(|s| (s[0], s[1])).unzip();
    rep.heights.pose_z_error_m = Percentiles::of(&mut z);
    rep.heights.pose_tilt_error_deg = Percentiles::of(&mut tilt);
    rep.scans_not_mapped = rig.agent.scans_not_mapped();
    rep.cleared_cells = rig.agent.terrain().cleared_cells();
    rep.ceiling_wiped_cells = rig.agent.terrain().ceiling_wiped_cells();
    let mapper = rig.agent.mapper();
    score(
        mapper,
        rig.sim.world(),
        &sim::LabelParams::from_profile(&opts.agent.profile),
        &walker_trace,
        &mut rep,
    );
    rep.obstacle_positions = super::obstacle_positions::score(mapper, rig.sim.world());
    if let Some(twin) = &rig.truth_twin {
        rep.obstacle_shifts = Some(super::obstacle_positions::shifts(
            mapper,
            twin,
            rig.sim.world(),
        ));
    }
    if let Some(g) = rig.agent.localiser().graph_stats() {
        let (map_rebuilds, kept_sweeps) = rig.agent.terrain().rebuild_counts();
        let (kept_bytes, kept_dropped) = rig.agent.terrain().rebuild_memory();
        rep.graph = GraphReport {
            keyframes: g.keyframes,
            gnss_factors: g.gnss_factors,
            gravity_factors: g.gravity_factors,
            loops: g.loops,
            optimisations: g.optimisations,
            map_rebuilds,
            kept_sweeps,
            kept_mb: kept_bytes as f64 * 1e-6,
            kept_dropped,
            loop_rejections: [
                g.loop_no_descriptor,
                g.loop_no_candidate,
                g.loop_icp_failed,
                g.loop_poor_fit,
                g.loop_inconsistent,
            ],
        };
    }
    if let Some(g) = rig.agent.localiser().graph() {
        let poses: Vec<_> = g
            .graph()
            .keyframes()
            .iter()
            .map(|k| (k.stamp_s, k.pose))
            .collect();
        rep.graph_keyframes = keyframe_log.score(&poses);
    }
    if opts.rebuild_check {
        let blf = *rig.agent.localiser().base_from_lidar();
        if let Some(m) = rig.agent.terrain().remap_unchanged(&blf)? {
            let mut r = MapEvalReport::default();
            score(
                &m,
                rig.sim.world(),
                &sim::LabelParams::from_profile(&opts.agent.profile),
                &walker_trace,
                &mut r,
            );
            rep.rebuild_check = Some(RebuildCheck {
                accuracy: r.accuracy,
                false_obstacle_rate: r.false_obstacle_rate,
                obstacle_recall: r.obstacle_recall,
                obstacle_positions: super::obstacle_positions::score(&m, rig.sim.world()),
            });
        }
    }
    rep.map_digest = common::grid::map_digest(&mapper.tiles());
    let Rig { agent, .. } = rig;
    Ok((rep, agent.into_mapper()))
}

/// Prints each traced cell's description when it differs from the one printed last (`last`).
fn trace_cells(rig: &Rig, at: &[(f64, f64)], last: &mut [String]) {
    let mapper = rig.agent.mapper();
    for (&(x, y), last) in at.iter().zip(last.iter_mut()) {
        let (cx, cy) = mapper.lattice().cell_of(x, y);
        let now = mapper.describe(cx, cy);
        if now != *last {
            eprintln!("trace t {:.1} {} | {now}", rig.t_s(), rig.pose_error_text());
            *last = now;
        }
    }
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
    height_errors(mapper, &truth, &said, x0, y0, w, h, rep);
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

/// The map's heights against the world's over flat scored cells, and the difference of those
/// errors between 4-neighbours (`HeightDiagnostics`).
#[allow(clippy::too_many_arguments)]
fn height_errors(
    mapper: &Mapper,
    truth: &sim::labels::TruthGrid,
    said: &[Option<bool>],
    x0: i64,
    y0: i64,
    w: usize,
    h: usize,
    rep: &mut MapEvalReport,
) {
    let min_n = mapper.config().min_points_per_cell;
    let err: Vec<Option<f64>> = (0..w * h)
        .map(|k| {
            let (cx, cy) = (x0 + (k % w) as i64, y0 + (k / w) as i64);
            said[k]?;
            let t = truth.get(cx, cy)?;
            if t.state != CellState::Traversable || t.step_m >= 0.02 || t.slope_deg >= 3.0 {
                return None;
            }
            let s = mapper.height_stats(cx, cy);
            if s.n >= min_n {
                Some(s.mean_m - f64::from(t.height_m))
            } else {
                None
            }
        })
        .collect();
    let mut cell: Vec<f64> = err.iter().flatten().copied().collect();
    let mut pairs = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let Some(e) = err[j * w + i] else { continue };
            if i + 1 < w {
                if let Some(r) = err[j * w + i + 1] {
                    pairs.push(e - r);
                }
            }
            if j + 1 < h {
                if let Some(u) = err[(j + 1) * w + i] {
                    pairs.push(e - u);
                }
            }
        }
    }
    rep.heights.cell_height_error_m = Percentiles::of(&mut cell);
    rep.heights.neighbour_error_m = Percentiles::of(&mut pairs);
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
fn driver_progress(points: &[[f64; 2]], p: &common::geom::Pose2) -> f64 {
    let mut best = (f64::INFINITY, 0usize);
    for (k, q) in points.iter().enumerate() {
        let d = (q[0] - p.x_m).hypot(q[1] - p.y_m);
        if d < best.0 {
            best = (d, k);
        }
    }
    best.1 as f64
}
