//! The terrain map: the traversability mapper (`mapping`) and the planning grids built from it.
//!
//! Each sweep is mapped at its localised pose. Planning reads a window of final cells around the
//! robot once per cycle and builds from it the planning grid (cost rule, then the layers of
//! [`layers`]: the robot's footprint cleared, a lasting safety stop stamped) and, while
//! repeating, the taught route's corridor grid.

pub mod cell_correction;
pub mod cell_mask;
pub mod layers;
pub mod rebuild;
#[cfg(test)]
mod rebuild_tests;

use crate::config::AgentConfig;
use crate::localiser::{FrameShift, PoseMap};
use crate::mission::teach_view::{TaughtCell, TeachView};
use common::geom::Pose2;
use common::grid::{Cell, CellState, Lattice, Tile, TileIndex};
use planning::{CostRule, GridWindow, PlanGrid, PlannerConfig};
use sensing::Scan;

/// Largest bounding box of the cells a correction touched that is held as one mask (one byte
/// a cell, three times while it is grown; 8M cells: a 570 m square at 0.2 m); a larger one
/// replaces whole tiles.
const STALE_MASK_MAX_CELLS: usize = 8 << 20;

/// Sizes the terrain map needs from the robot profile and the safety stop, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Body {
    /// Half the larger of the footprint's length and width: the disc the robot stands on.
    footprint_radius_m: f64,
    /// Half the body width plus the safety stop's side margin: how far a lasting stop's point
    /// keeps the body's centre away.
    stop_reach_m: f64,
    /// Half the body width plus `corridor_margin_m`: how far either side of a taught route its
    /// corridor reaches.
    corridor_radius_m: f64,
}

/// Parameters of the taught corridor's obstacle test.
#[derive(Clone, Copy, Debug, PartialEq)]
struct CorridorRule {
    new_obstacle_rise_m: f32,
    newest_evidence_min_points: u32,
}

/// What mapping one sweep did.
#[derive(Clone, Debug, Default)]
pub struct MapUpdate {
    /// Tiles whose cells changed.
    pub changed_tiles: Vec<TileIndex>,
    /// Cells reclassified.
    pub classified_cells: usize,
    /// Cells whose class changed.
    pub class_changes: usize,
}

/// The mapper's robot pose: `base_link` (on the ground under the centre) and its heading.
fn robot_pose(pose: &PoseMap) -> mapping::RobotPose {
    let t = pose.iso.translation.vector;
    mapping::RobotPose {
        x_m: t.x,
        y_m: t.y,
        z_m: t.z,
        yaw_rad: pose.planar.yaw_rad,
    }
}

/// Maps one kept sweep into `mapper` at the pose it was last given, under `live`'s ground
/// (`Mapper::update_sweep_under`).
fn map_kept(
    mapper: &mut mapping::Mapper,
    r: &rebuild::Remap,
    base_from_lidar: &nalgebra::Isometry3<f64>,
    live: &mapping::Mapper,
) -> Result<mapping::UpdateReport, mapping::MapError> {
    let (pts, origin) = rebuild::to_map(r, base_from_lidar);
    let robot = robot_pose(&PoseMap::from_iso(r.map_from_base));
    mapper.update_sweep_under(pts, origin, &robot, r.t_s, live)
}

/// Cells whose evidence the mapper dropped, since the start: by free space (stale evidence)
/// and by a lower ceiling (a canopy taken in before its ground was seen).
#[derive(Debug, Default)]
struct WipeCounts {
    cleared: usize,
    ceiling: usize,
}

impl WipeCounts {
    /// Adds an update's (live or rebuild) to the totals.
    fn add(&mut self, u: &mapping::UpdateReport) {
        self.cleared += u.cleared_cells;
        self.ceiling += u.ceiling_wiped;
    }
}

/// See the module docs.
pub struct TerrainMap {
    mapper: mapping::Mapper,
    planner: PlannerConfig,
    body: Body,
    corridor_rule: CorridorRule,
    map_follow_radius_m: f64,
    wiped: WipeCounts,
    /// Sweeps kept for rebuilding after the pose graph's corrections (with `[graph] enabled`).
    kept: Option<rebuild::SweepStore>,
    /// The rebuild under way, if any (the live `mapper` serves meanwhile).
    shadow: Option<rebuild::Shadow>,
    /// Kept sweeps fed to the shadow per live sweep (0: the whole rebuild at once).
    sweeps_per_tick: usize,
    /// Rebuilds done (swapped in).
    rebuilds: u64,
    /// Corrections that re-targeted a running rebuild instead of starting it again.
    retargets: u64,
}

impl TerrainMap {
    /// An empty map.
    pub fn new(cfg: &AgentConfig) -> Result<Self, mapping::MapError> {
        let p = &cfg.profile;
        let sc = &cfg.control.safety;
        Ok(Self {
            mapper: mapping::Mapper::new(cfg.mapper.clone())?,
            planner: cfg.planner.clone(),
            body: Body {
                footprint_radius_m: 0.5 * p.length_m.max(p.width_m),
                stop_reach_m: 0.5 * sc.body_width_m + sc.stop_side_m,
                corridor_radius_m: 0.5 * p.width_m + cfg.repeat.corridor_margin_m,
            },
            corridor_rule: CorridorRule {
                new_obstacle_rise_m: cfg.repeat.new_obstacle_rise_m as f32,
                newest_evidence_min_points: cfg.repeat.newest_evidence_min_points,
            },
            map_follow_radius_m: cfg.gnss.map_follow_radius_m,
            wiped: WipeCounts::default(),
            kept: cfg.slam.graph.enabled.then(|| {
                rebuild::SweepStore::new(
                    cfg.slam.graph.map_rebuild_spacing_m,
                    cfg.slam.graph.map_rebuild_min_move_m,
                    cfg.mapper.max_range_m,
                    cfg.slam.graph.map_rebuild_max_mb,
                )
            }),
            shadow: None,
            sweeps_per_tick: cfg.slam.graph.map_rebuild_sweeps_per_tick,
            rebuilds: 0,
            retargets: 0,
        })
    }

    /// Maps one sweep (`scan` in the lidar frame at `pose_map_lidar`) seen from the robot at
    /// `pose`.
    pub fn update(
        &mut self,
        scan: &Scan,
        pose_map_lidar: &nalgebra::Isometry3<f64>,
        pose: &PoseMap,
    ) -> Result<MapUpdate, mapping::MapError> {
        let u = self
            .mapper
            .update_scan(scan, pose_map_lidar, &robot_pose(pose), scan.stamp_s)?;
        self.wiped.add(&u);
        Ok(MapUpdate {
            changed_tiles: u.changed_tiles,
            classified_cells: u.classified_cells,
            class_changes: u.class_changes,
        })
    }

    /// Maps a sweep already in the map frame (`points_map`, seen from `sensor_m`) with the
    /// robot at `robot`, both given from outside: the truth-pose upper bound of an evaluation.
    pub fn update_at(
        &mut self,
        points_map: Vec<[f32; 3]>,
        sensor_m: [f64; 3],
        robot: &mapping::RobotPose,
        t_s: f64,
    ) -> Result<mapping::UpdateReport, mapping::MapError> {
        let u = self.mapper.update_sweep(points_map, sensor_m, robot, t_s)?;
        self.wiped.add(&u);
        Ok(u)
    }

    /// A sweep just mapped (lidar frame) at `pose` from the SLAM pose `slam_from_base`: kept
    /// for rebuilding when the pose graph runs and the robot moved far enough since the last.
    pub fn keep_sweep(
        &mut self,
        t_s: f64,
        slam_from_base: &nalgebra::Isometry3<f64>,
        pose: &PoseMap,
        points: &[sensing::Point],
    ) {
        if let Some(k) = self.kept.as_mut() {
            // While a rebuild runs, every sweep (see `SweepStore::respace`).
            k.offer(
                t_s,
                slam_from_base,
                &pose.iso,
                points,
                self.shadow.is_some(),
            );
        }
    }

    /// The pose graph moved the past (`map_from_slam_at(t)`: `map<-slam` for a pose made at
    /// `t`). When some kept sweep moved by more than `map_rebuild_min_move_m`, a rebuild from
    /// the kept sweeps at their corrected poses starts; when one is under way it re-targets
    /// (goes on, feeding the sweeps it has not fed yet at their new poses) if only those moved,
    /// and starts again if one it fed moved (its map has that sweep in the wrong place). With
    /// `map_rebuild_sweeps_per_tick = 0` the rebuild runs to its end here. Returns the tiles to
    /// publish again when a rebuilt map replaced this one (see [`TerrainMap::advance_rebuild`]).
    pub fn correct(
        &mut self,
        t_s: f64,
        base_from_lidar: &nalgebra::Isometry3<f64>,
        map_from_slam_at: impl Fn(f64) -> Option<nalgebra::Isometry3<f64>>,
    ) -> Result<Vec<TileIndex>, mapping::MapError> {
        let Some(kept) = self.kept.as_mut() else {
            return Ok(Vec::new());
        };
        // A shadow that fed nothing yet has nothing in a wrong place.
        let fed_until = self
            .shadow
            .as_ref()
            .map(|s| s.fed_until.unwrap_or(f64::NEG_INFINITY));
        let c = kept.correct(map_from_slam_at, fed_until);
        let (max_move_m, moved) = kept.last_move();
        tracing::info!(
            "map rebuild at {t_s:.2} s: correction moves kept sweeps by up to {max_move_m:.3} m ({moved} of {} over the minimum): {c:?} (a running rebuild had fed {:?})",
            kept.len(),
            self.shadow.as_ref().map(|s| s.fed)
        );
        match c {
            rebuild::Correction::None => return Ok(Vec::new()),
            rebuild::Correction::Retarget => self.retargets += 1,
            rebuild::Correction::Restart => {
                self.shadow = Some(rebuild::Shadow::new(
                    mapping::Mapper::new(self.mapper.config().clone())?,
                    t_s,
                    cell_correction::CellMoves::new(
                        self.mapper.lattice(),
                        kept.min_move_m(),
                        kept.near_range_m(),
                    ),
                ));
            }
        }
        if self.sweeps_per_tick == 0 {
            return self.feed_shadow(t_s, base_from_lidar, usize::MAX);
        }
        Ok(Vec::new())
    }

    /// One step of a rebuild under way (call once per live sweep, before mapping it): the
    /// shadow map is fed up to `map_rebuild_sweeps_per_tick` kept sweeps, oldest first (the
    /// live sweeps kept meanwhile included, so it catches up with the robot), and once none is
    /// left it replaces the map, its observed cells stamped `t_s` (newer than anything the
    /// live map published). Returns the tiles to publish again then, else nothing.
    pub fn advance_rebuild(
        &mut self,
        t_s: f64,
        base_from_lidar: &nalgebra::Isometry3<f64>,
    ) -> Result<Vec<TileIndex>, mapping::MapError> {
        self.feed_shadow(t_s, base_from_lidar, self.sweeps_per_tick.max(1))
    }

    fn feed_shadow(
        &mut self,
        t_s: f64,
        base_from_lidar: &nalgebra::Isometry3<f64>,
        n: usize,
    ) -> Result<Vec<TileIndex>, mapping::MapError> {
        let radius_m = self.map_follow_radius_m;
        let (Some(kept), Some(sh)) = (self.kept.as_ref(), self.shadow.as_mut()) else {
            return Ok(Vec::new());
        };
        for r in kept.after(sh.fed_until, n) {
            sh.follow_frames_before(r.t_s, radius_m);
            sh.moves.add(&r, base_from_lidar);
            // The live map's ground keeps a canopy the thinned sweeps saw alone out of the
            // rebuilt cells (`Mapper::update_sweep_under`).
            match map_kept(&mut sh.mapper, &r, base_from_lidar, &self.mapper) {
                Ok(u) => self.wiped.add(&u),
                Err(e) => {
                    // The shadow cannot go past a sweep it refuses: this rebuild is given up,
                    // the live map stays, the next correction starts another.
                    self.shadow = None;
                    return Err(e);
                }
            }
            sh.fed_until = Some(r.t_s);
            sh.fed += 1;
        }
        if kept.has_after(sh.fed_until) {
            return Ok(Vec::new());
        }
        let (Some(mut sh), Some(kept)) = (self.shadow.take(), self.kept.as_mut()) else {
            return Ok(Vec::new());
        };
        // Every kept sweep is fed: the shifts since the newest one come now, as they came to
        // the live map.
        sh.follow_frames_before(f64::INFINITY, radius_m);
        let cfg = self.mapper.config();
        let reach_m = cfg.max_range_m.max(cfg.clear_reach_m) + cfg.cost_distance_m;
        let lattice = self.mapper.lattice();
        let stale = kept.stale_tiles(&lattice, reach_m);
        // The step rule reads two cells around a cell, the costs `cost_distance_m`.
        let grow = 2 + (cfg.cost_distance_m / lattice.cell_size_f64()).ceil() as i64;
        let cells = sh.moves.finish(&stale, grow, STALE_MASK_MAX_CELLS);
        kept.swapped();
        let thinned = kept.respace();
        let held = self.mapper.tile_count();
        let r = self.mapper.replace_cells_with(
            sh.mapper,
            t_s,
            |t| stale.contains(&t),
            |cx, cy| cells.is_rebuilt(cx, cy),
            |cx, cy| cells.dz_m(cx, cy),
        );
        tracing::info!(
            "map rebuild swapped in at {t_s:.2} s: {} kept sweeps fed since {:.2} s, {} of {held} tiles replaced, {} of their cells within reach of a move, {} of those rebuilt ({} obstacles the live map held traversable cleared), {thinned} sweeps kept meanwhile thinned to the spacing",
            sh.fed,
            sh.started_s,
            r.tiles.len(),
            cells
                .stale_cells()
                .map_or_else(|| "all".to_string(), |n| n.to_string()),
            r.rebuilt_cells,
            r.thinned_cleared,
        );
        self.rebuilds += 1;
        Ok(r.tiles)
    }

    /// True while a rebuilt map is being made and has not replaced the live one yet.
    pub fn rebuild_running(&self) -> bool {
        self.shadow.is_some()
    }

    /// Rebuilds after pose graph corrections (swapped in), and the sweeps kept for them.
    pub fn rebuild_counts(&self) -> (u64, usize) {
        (self.rebuilds, self.kept.as_ref().map_or(0, |k| k.len()))
    }

    /// The rebuild store's memory: bytes held and sweeps dropped to stay under the cap.
    pub fn rebuild_memory(&self) -> (usize, u64) {
        self.kept
            .as_ref()
            .map_or((0, 0), |k| (k.bytes(), k.dropped()))
    }

    /// Kept sweeps a rebuild under way has fed its shadow map (None: no rebuild runs).
    pub fn rebuild_progress(&self) -> Option<usize> {
        self.shadow.as_ref().map(|s| s.fed)
    }

    /// The kept sweeps mapped again, in a fresh mapper, at the poses the current map has them
    /// at (no correction): what a rebuild makes of the live map's own sweeps, to tell what the
    /// rebuild loses from what a correction moves (`robot-agent map eval --rebuild-check`).
    /// None without a store (graph off).
    pub fn remap_unchanged(
        &self,
        base_from_lidar: &nalgebra::Isometry3<f64>,
    ) -> Result<Option<mapping::Mapper>, mapping::MapError> {
        let Some(kept) = self.kept.as_ref() else {
            return Ok(None);
        };
        let mut m = mapping::Mapper::new(self.mapper.config().clone())?;
        let mut after = None;
        // A few at a time: restored to f32 the whole store would take twice its memory.
        loop {
            let batch = kept.after(after, 16);
            if batch.is_empty() {
                return Ok(Some(m));
            }
            for r in batch {
                map_kept(&mut m, &r, base_from_lidar, &self.mapper)?;
                after = Some(r.t_s);
            }
        }
    }

    /// Corrections that re-targeted a running rebuild.
    pub fn rebuild_retargets(&self) -> u64 {
        self.retargets
    }

    /// Cells whose stale evidence free space cleared, since the start.
    pub fn cleared_cells(&self) -> usize {
        self.wiped.cleared
    }

    /// Cells whose evidence a lower ceiling dropped (a canopy taken in before its ground was
    /// seen), since the start.
    pub fn ceiling_wiped_cells(&self) -> usize {
        self.wiped.ceiling
    }

    /// The map frame moved (a GNSS or gravity correction): the stored heights within
    /// `map_follow_radius_m` follow it (the last quarter tapering off), so the correction itself
    /// draws no false steps between old and new sweeps (docs/algorithms.md §4.13).
    pub fn follow_frame(&mut self, shift: &FrameShift) {
        self.mapper.follow_frame(shift, self.map_follow_radius_m);
        // The shadow is behind: it follows the shift once it has fed the sweeps the live map
        // had taken before it (see `rebuild::Shadow::follow_frames_before`), not now.
        if let Some(sh) = self.shadow.as_mut() {
            let after = self
                .kept
                .as_ref()
                .and_then(rebuild::SweepStore::newest_t_s)
                .unwrap_or(f64::NEG_INFINITY);
            sh.pending_shifts.push((after, *shift));
        }
    }

    /// The planning window around `pose` and the mapper's cells in it: what both the planning
    /// grid and a route's corridor grid are built from (read once per cycle).
    pub fn window(&self, pose: &Pose2) -> (GridWindow, mapping::PlannerView) {
        let window = self.window_at(pose);
        let view = self
            .mapper
            .view(window.min_cx, window.min_cy, window.width, window.height);
        (window, view)
    }

    /// The planning window (`num_of_grid_cells` square) centred on `pose`.
    fn window_at(&self, pose: &Pose2) -> GridWindow {
        GridWindow::centred(
            self.mapper.lattice(),
            pose.x_m,
            pose.y_m,
            self.planner.num_of_grid_cells,
        )
    }

    /// The planning grid around `pose`, with a lasting stop at `stop_m` stamped in.
    pub fn plan_grid(&self, pose: &Pose2, stop_m: Option<(f64, f64)>) -> PlanGrid {
        let (window, view) = self.window(pose);
        self.plan_grid_in(pose, &window, &view, stop_m)
    }

    /// [`TerrainMap::plan_grid`] over a window already read.
    pub fn plan_grid_in(
        &self,
        pose: &Pose2,
        window: &GridWindow,
        view: &mapping::PlannerView,
        stop_m: Option<(f64, f64)>,
    ) -> PlanGrid {
        let rule = CostRule::from_config(&self.planner);
        let mut grid = PlanGrid::from_cells(window, &rule, |cx, cy| view.get(cx, cy));
        self.stamp_layers(&mut grid, window, pose, stop_m, |cx, cy| {
            view.get(cx, cy).state
        });
        grid
    }

    /// The planning grid around `pose` (as [`TerrainMap::plan_grid`]) filled only where a check
    /// of `path` reads it ([`PlanGrid::along_path`]): the same answer for that path at a small
    /// part of the cost, for the check after every sweep.
    pub fn path_check_grid(
        &self,
        pose: &Pose2,
        path: &[(f64, f64)],
        stop_m: Option<(f64, f64)>,
    ) -> PlanGrid {
        let window = self.window_at(pose);
        let rule = CostRule::from_config(&self.planner);
        // Cells of the window read straight from the mapper: a window's view is a copy of all
        // of them.
        let m = &self.mapper;
        let mut grid = PlanGrid::along_path(&window, &rule, path, |cx, cy| m.cell(cx, cy));
        self.stamp_layers(&mut grid, &window, pose, stop_m, |cx, cy| {
            m.cell(cx, cy).state
        });
        grid
    }

    /// The footprint clearing and a lasting stop's disc, over a planning grid built on `window`.
    fn stamp_layers(
        &self,
        grid: &mut PlanGrid,
        window: &GridWindow,
        pose: &Pose2,
        stop_m: Option<(f64, f64)>,
        state_of: impl Fn(i64, i64) -> common::grid::CellState,
    ) {
        let r_m = self.body.footprint_radius_m;
        let robot = (pose.x_m, pose.y_m);
        layers::clear_footprint(grid, window, robot, r_m, state_of);
        if let Some(at) = stop_m {
            let s = grid.cell_size_m();
            layers::stamp_blocked_disc(
                grid,
                at,
                self.body.stop_reach_m + s,
                Some((robot, r_m + 0.5 * s)),
            );
        }
    }

    /// The grid a taught route's corridor is checked on (see [`layers::corridor`]), with a
    /// lasting stop at `stop_m` stamped in: with the teach-time view, only obstacles standing
    /// higher than at teach time block.
    pub fn corridor_grid(
        &self,
        window: &GridWindow,
        view: &mapping::PlannerView,
        taught: Option<&TeachView>,
        stop_m: Option<(f64, f64)>,
    ) -> PlanGrid {
        let rise = self.corridor_rule.new_obstacle_rise_m;
        let mut grid = layers::corridor(window, self.body.corridor_radius_m, |cx, cy| {
            view.get(cx, cy).state == CellState::Obstacle
                && taught.is_none_or(|v| v.is_new_obstacle(cx, cy, self.robust_top_m(cx, cy), rise))
        });
        if let Some(at) = stop_m {
            let s = grid.cell_size_m();
            layers::stamp_blocked_disc(&mut grid, at, self.body.stop_reach_m + s, None);
        }
        grid
    }

    /// How far either side of a taught route its corridor reaches, metres.
    pub fn corridor_radius_m(&self) -> f64 {
        self.body.corridor_radius_m
    }

    /// The teach-time view of the cells a repeat's corridor check can reach along `line_m`.
    pub fn capture_teach_view(&self, line_m: &[(f64, f64)]) -> TeachView {
        let m = &self.mapper;
        TeachView::capture(
            line_m,
            self.body.corridor_radius_m,
            &m.lattice(),
            |cx, cy| {
                let (ground, (_, top)) = (m.height_m(cx, cy)?, m.height_range(cx, cy)?);
                Some(TaughtCell {
                    obstacle: m.class(cx, cy).is_obstacle(),
                    ground_m: ground as f32,
                    top_m: top,
                })
            },
        )
    }

    /// How high a cell's evidence stands, robust to a stray return or two: its highest point,
    /// but no more than two standard deviations above its mean (a car or a trunk fills its
    /// cells with returns; a single point 30 cm up in grass does not). When the cell's newest
    /// evidence epoch alone holds `newest_evidence_min_points` returns, it is judged on that
    /// epoch: what stands there now (a person who crossed the route a minute ago left returns in
    /// the older epoch that the newer one, all ground, contradicts).
    pub fn robust_top_m(&self, cx: i64, cy: i64) -> Option<f32> {
        let newest = self.mapper.newest_height_stats(cx, cy);
        let s = if newest.n >= self.corridor_rule.newest_evidence_min_points {
            newest
        } else {
            self.mapper.height_stats(cx, cy)
        };
        (s.n > 0).then(|| s.max_m.min(s.mean_m + 2.0 * s.var_m2.sqrt()) as f32)
    }

    /// Logs (debug) the obstacle cells within the corridor's reach of a blocked route point,
    /// with why each is what it is.
    pub fn log_blocking_cells(&self, at_m: (f64, f64), taught: Option<&TeachView>) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        let lattice = self.mapper.lattice();
        let (cx, cy) = lattice.cell_of(at_m.0, at_m.1);
        let r = (self.body.corridor_radius_m / lattice.cell_size_f64()).ceil() as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                if self.mapper.class(cx + dx, cy + dy).is_obstacle() {
                    tracing::debug!(
                        "repeat: blocking {}; at teach time {:?}; top now {:?}",
                        self.mapper.describe(cx + dx, cy + dy),
                        taught.and_then(|v| v.get(cx + dx, cy + dy)),
                        self.robust_top_m(cx + dx, cy + dy)
                    );
                }
            }
        }
    }

    /// The lattice tiles live on.
    pub fn lattice(&self) -> Lattice {
        self.mapper.lattice()
    }

    /// Every current tile.
    pub fn tiles(&self) -> Vec<Tile> {
        self.mapper.tiles()
    }

    /// The current cells of one tile.
    pub fn tile_cells(&self, index: TileIndex) -> Option<&[Cell]> {
        self.mapper.tile_cells(index)
    }

    /// The mapper (evaluation, rendering).
    pub fn mapper(&self) -> &mapping::Mapper {
        &self.mapper
    }

    /// The mapper, taking the terrain map apart.
    pub fn into_mapper(self) -> mapping::Mapper {
        self.mapper
    }
}
