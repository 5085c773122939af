//! The incremental traversability mapper and its cell store.
//!
//! `Mapper::update` runs the stages, each in its own module:
//!
//! - [`free_space`]: the sweep's beams marched through the robot's body band (headroom, and
//!   stored points that have gone);
//! - [`evidence`]: height and isolated-point filters, binning under the ceilings, stray points,
//!   the two evidence epochs, the footprint as evidence;
//! - [`reclassify`]: which cells to judge and the rules' verdict within the processing distance,
//!   then [`far_rules`] beyond it;
//! - [`negative_obstacles`]: drop-offs and their lips;
//! - [`inflation`]: the output cells' state and cost.
//!
//! This file keeps what they share: the cells per tile ([`cell_data::CellData`] and the output
//! cells), the lookups into them, the changed-tile bookkeeping and the per-cell reads. The
//! reads of whole tiles and windows (the planner's view) are in [`view`]. Frame corrections are
//! in [`follow_frame`], swapping in a map rebuilt at corrected poses in [`rebuild`], read-only
//! diagnostics in [`inspect`].

mod cell_data;
mod evidence;
mod far_rules;
mod fast_hash;
mod follow_frame;
mod free_space;
mod inflation;
mod inspect;
mod negative_obstacles;
mod rebuild;
pub use rebuild::Replaced;
mod reclassify;
mod revisit;
mod view;
mod window;

use crate::classify::{Class, Rules};
use crate::config::Config;
use cell_data::CellData;
use common::grid::{Cell, Lattice, TileIndex};
use fast_hash::{FastMap, FastSet};
use nalgebra::Isometry3;
use sensing::{Point, Scan};
pub use view::PlannerView;
use window::Window;

/// How much higher than the live map's ground a rebuild's ceilings take it
/// ([`Mapper::update_sweep_under`]), metres: the live heights follow the frame's shifts and may
/// stand up to ~0.2 m off the corrected poses' frame (docs/algorithms.md §3.7), and a ceiling set
/// that much too low would drop the top of what stands near the robot's height.
pub const CEILING_HINT_MARGIN_M: f32 = 0.3;

/// Why an update was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MapError {
    /// The robot pose or the time is not finite.
    #[error("robot pose or time is not finite")]
    BadPose,
    /// Time went backwards by an evidence epoch or more.
    #[error(
        "time {t_s} s is an evidence epoch or more before the previous update ({previous_s} s)"
    )]
    TimeWentBack {
        /// This update.
        t_s: f64,
        /// The previous update.
        previous_s: f64,
    },
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
}

/// Where the robot is: the map-frame position of the ground under its centre, and its heading.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RobotPose {
    /// x, metres, map frame.
    pub x_m: f64,
    /// y, metres, map frame.
    pub y_m: f64,
    /// Height of the ground under the robot, metres, map frame.
    pub z_m: f64,
    /// Heading, radians (x axis of base_link from the map x axis).
    pub yaw_rad: f64,
}

impl RobotPose {
    /// The robot under a sensor mounted `sensor_height_m` above the ground on the robot's up axis.
    pub fn from_sensor_pose(pose_map_sensor: &Isometry3<f64>, sensor_height_m: f64) -> Self {
        let up = pose_map_sensor.rotation * nalgebra::Vector3::z();
        let ground = pose_map_sensor.translation.vector - up * sensor_height_m;
        let fwd = pose_map_sensor.rotation * nalgebra::Vector3::x();
        Self {
            x_m: ground.x,
            y_m: ground.y,
            z_m: ground.z,
            yaw_rad: fwd.y.atan2(fwd.x),
        }
    }

    fn is_finite(&self) -> bool {
        self.x_m.is_finite()
            && self.y_m.is_finite()
            && self.z_m.is_finite()
            && self.yaw_rad.is_finite()
    }
}

/// How an update's points relate to the evidence already held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Evidence {
    /// One sweep: its points add to the cells' evidence of the current epoch.
    Scan,
    /// The whole (SLAM) map around the robot: each cell's points replace what the cell held; a
    /// cell whose points did not change is not touched.
    MapCloud,
}

/// What one update did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UpdateReport {
    /// Tiles whose output cells changed in this update, sorted.
    pub changed_tiles: Vec<TileIndex>,
    /// Points received.
    pub points_in: usize,
    /// Points dropped: not finite.
    pub dropped_non_finite: usize,
    /// Points dropped by the height filter (above the climb cone or out of range).
    pub dropped_height: usize,
    /// Points dropped by the isolated-point filter.
    pub dropped_isolated: usize,
    /// Points above their cell's ceiling `h_max2`.
    pub dropped_ceiling: usize,
    /// Points held back as possible stray dynamic points (waiting for a second scan).
    pub held_stray: usize,
    /// Cells whose evidence changed.
    pub dirty_cells: usize,
    /// Cells reclassified.
    pub classified_cells: usize,
    /// Cells whose class changed.
    pub class_changes: usize,
    /// Beams marched for free space.
    pub beams_marched: usize,
    /// Cells whose old evidence a beam contradicted (walkers gone, stray points).
    pub cleared_cells: usize,
    /// Cells whose stored returns stood above this sweep's ceiling for them: taken in under a
    /// ceiling set before the ground below was known (a canopy), dropped for this sweep's.
    pub ceiling_wiped: usize,
    /// Cells whose points this sweep were ignored: seen much better from closer before.
    pub far_skipped: usize,
    /// Cells whose older epoch, seen only from much farther than this sweep, gave way to it.
    pub far_superseded: usize,
    /// Samples the revisit offset was fitted to in this update, this sweep's and the last few
    /// sweeps' ground cells against an earlier visit's (0: no offset fitted).
    pub revisit_pairs: usize,
    /// An earlier visit's cells moved onto the current frame by the revisit offset.
    pub revisit_moved: usize,
}

/// `x.floor() as i64` without a libm call (the default x86-64 target has no SSE4.1 `roundsd`,
/// and this runs for every return and every beam step).
#[inline]
fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// `a.hypot(b)` without libm's overflow care, which these magnitudes never need.
#[inline]
fn norm2(a: f64, b: f64) -> f64 {
    (a * a + b * b).sqrt()
}

/// Largest `|f(x, y)|` over the corners of the square of half-side `half_m` about (`x_m`,
/// `y_m`): for a plane (or an isometry's height change), the largest anywhere in the square.
fn largest_at_corners(x_m: f64, y_m: f64, half_m: f64, f: impl Fn(f64, f64) -> f64) -> f64 {
    [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)]
        .iter()
        .map(|(sx, sy)| f(x_m + sx * half_m, y_m + sy * half_m).abs())
        .fold(0.0, f64::max)
}

/// One tile's cells: what the mapper keeps and what it outputs.
struct TileSlot {
    index: TileIndex,
    data: Vec<CellData>,
    /// Each cell's ground ([`CellData::ground`]), kept beside the data: the beam march and the
    /// ceilings look it up for tens of thousands of cells per sweep, and 4 bytes a cell stay in
    /// cache where the whole cell does not.
    ground: Vec<f32>,
    /// The current output cells.
    live: Vec<Cell>,
    /// One bit per cell (64 a word, row-major like `data`): the cell was ever handed out
    /// mutably ([`Mapper::data_mut`], the only way a cell gets content). A cell without its
    /// bit is still the default, empty one, so whole-map passes ([`Mapper::follow_frame`])
    /// read these 512 bytes a tile instead of every cell's ~200.
    held: Vec<u64>,
    /// An output cell changed since the tile was last handed out as changed.
    changed: bool,
}

/// The traversability mapper. Feed it scans or map clouds with the robot pose and a time; it
/// returns the tiles that changed and keeps the grid for the planner.
pub struct Mapper {
    cfg: Config,
    rules: Rules,
    lattice: Lattice,
    slot_of: FastMap<TileIndex, usize>,
    slots: Vec<TileSlot>,
    /// Cells with new evidence that were outside the processing distance when it arrived.
    pending: FastSet<(i64, i64)>,
    win: Window,
    scan_id: u32,
    robot: Option<RobotPose>,
    /// Frame corrections too small to apply yet (see [`Mapper::follow_frame`]).
    frame_lag: nalgebra::Isometry3<f64>,
    /// The last revisit's height offset of the old map, and the samples of the last few
    /// sweeps it is fitted to (see [`Mapper::align_revisit`]).
    revisit: Option<revisit::RevisitOffset>,
    revisit_samples: std::collections::VecDeque<revisit::Sample>,
    last_t_s: Option<f64>,
    /// Sorted (distance, dx, dy) offsets within the cost distance, for inflation.
    offsets: Vec<(f64, i64, i64)>,
    /// Reclassify every cell of the window on every update (the baseline the incremental
    /// path is measured and tested against).
    full: bool,
    /// The last tile -> slot lookup (`usize::MAX`: none yet).
    last_slot: std::cell::Cell<(TileIndex, usize)>,
    /// 1 / cell size, per metre.
    inv_cell_m: f64,
    /// The lattice's cell edge, metres (its rounding done once: centres are asked for per cell).
    cell_m: f64,
}

impl Mapper {
    /// A mapper with an empty grid.
    pub fn new(cfg: Config) -> Result<Self, MapError> {
        cfg.validate()?;
        let l = cfg.grid_size_m;
        let range_cells = (cfg.max_range_m / l).ceil() as i64;
        let view_half = i64::from(cfg.num_of_grid_cells / 2);
        let half = range_cells.max(view_half) + i64::from(cfg.ceiling_radius_cells) + 8;
        let offsets = inflation::inflation_offsets(&cfg);
        let cfg_cell = cfg.lattice().cell_size_f64();
        Ok(Self {
            rules: Rules::new(&cfg),
            lattice: cfg.lattice(),
            cfg,
            slot_of: FastMap::default(),
            slots: Vec::new(),
            pending: FastSet::default(),
            win: Window::new(half),
            scan_id: 0,
            robot: None,
            frame_lag: nalgebra::Isometry3::identity(),
            revisit: None,
            revisit_samples: Default::default(),
            last_t_s: None,
            offsets,
            full: false,
            last_slot: std::cell::Cell::new((TileIndex { tx: 0, ty: 0 }, usize::MAX)),
            inv_cell_m: 1.0 / cfg_cell,
            cell_m: cfg_cell,
        })
    }

    /// Switches to reclassifying the whole window on every update (slow; the baseline).
    pub fn set_full_reclassification(&mut self, on: bool) {
        self.full = on;
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The lattice the cells live on.
    pub fn lattice(&self) -> Lattice {
        self.lattice
    }

    /// The last robot pose given.
    pub fn robot(&self) -> Option<RobotPose> {
        self.robot
    }

    /// One LiDAR scan (sensor frame) with the sensor's map pose.
    pub fn update_scan(
        &mut self,
        scan: &Scan,
        pose_map_sensor: &Isometry3<f64>,
        robot: &RobotPose,
        t_s: f64,
    ) -> Result<UpdateReport, MapError> {
        let m = pose_map_sensor.to_homogeneous().cast::<f32>();
        let pts: Vec<[f32; 3]> = scan
            .points
            .iter()
            .map(|p| {
                let v = m * nalgebra::Vector4::new(p.x, p.y, p.z, 1.0);
                [v.x, v.y, v.z]
            })
            .collect();
        let o = pose_map_sensor.translation.vector;
        self.update(pts, Some([o.x, o.y, o.z]), robot, t_s, Evidence::Scan, None)
    }

    /// One sweep already in the map frame (e.g. de-skewed), seen from `sensor_map` (the sensor's
    /// map-frame position): like [`Mapper::update_scan`], with the beams' free space.
    pub fn update_sweep(
        &mut self,
        pts_map: Vec<[f32; 3]>,
        sensor_map: [f64; 3],
        robot: &RobotPose,
        t_s: f64,
    ) -> Result<UpdateReport, MapError> {
        self.update(pts_map, Some(sensor_map), robot, t_s, Evidence::Scan, None)
    }

    /// [`Mapper::update_sweep`] for a map rebuilt from thinned sweeps (a pose graph correction,
    /// docs/algorithms.md §3.7): the ceilings also take `live`'s ground (the map made from every
    /// sweep) as seen ground, raised by [`CEILING_HINT_MARGIN_M`]. One sweep in six may cross a
    /// tree's canopy with no ring on the ground below; without the live ground its returns set
    /// their own ceiling and come in as the cells' surface (an obstacle ringed by steps), where
    /// the live map, made from every sweep, had dropped them above the ground it knew.
    pub fn update_sweep_under(
        &mut self,
        pts_map: Vec<[f32; 3]>,
        sensor_map: [f64; 3],
        robot: &RobotPose,
        t_s: f64,
        live: &Mapper,
    ) -> Result<UpdateReport, MapError> {
        self.update(
            pts_map,
            Some(sensor_map),
            robot,
            t_s,
            Evidence::Scan,
            Some(live),
        )
    }

    /// The map cloud around the robot (map frame), e.g. from SLAM.
    pub fn update_cloud(
        &mut self,
        cloud_map: &[Point],
        robot: &RobotPose,
        t_s: f64,
    ) -> Result<UpdateReport, MapError> {
        let pts = cloud_map.iter().map(|p| [p.x, p.y, p.z]).collect();
        self.update_points(pts, robot, t_s, Evidence::MapCloud)
    }

    /// Map-frame points without a sensor origin (no free-space reasoning: every cell counts as
    /// having headroom), the robot, the time, and how to treat the points.
    pub fn update_points(
        &mut self,
        pts: Vec<[f32; 3]>,
        robot: &RobotPose,
        t_s: f64,
        kind: Evidence,
    ) -> Result<UpdateReport, MapError> {
        self.update(pts, None, robot, t_s, kind, None)
    }

    /// The core step: one update's stages in order.
    fn update(
        &mut self,
        mut pts: Vec<[f32; 3]>,
        sensor: Option<[f64; 3]>,
        robot: &RobotPose,
        t_s: f64,
        kind: Evidence,
        ground_hint: Option<&Mapper>,
    ) -> Result<UpdateReport, MapError> {
        let t_s = self.begin_update(sensor, robot, t_s)?;
        let mut rep = UpdateReport {
            points_in: pts.len(),
            ..Default::default()
        };
        let before = pts.len();
        pts.retain(|p| p.iter().all(|v| v.is_finite()));
        rep.dropped_non_finite = before - pts.len();

        // Free space: where this sweep's beams crossed the robot's body band above the ground.
        // Computed from every return, before the range and height filters: a beam that ends far
        // away still proves the space it crossed near the robot empty.
        let (rcx, rcy) = self.lattice.cell_of(robot.x_m, robot.y_m);
        self.win.clear();
        self.win.cx0 = rcx;
        self.win.cy0 = rcy;
        if let Some(o) = sensor {
            rep.beams_marched = self.march_beams(&pts, o, robot);
        }
        // 1-3. Filters, then binning under the per-cell ceilings.
        self.filter_points(&mut pts, robot, &mut rep);
        self.bin_points(&pts, kind, ground_hint, &mut rep);
        let mut dirty = Vec::new();
        // An earlier visit's ground onto the current frame, before anything compares with it.
        self.align_revisit(robot, t_s, kind, &mut dirty, &mut rep);
        // Free space first (it wipes what has gone), then the sweep's evidence.
        if sensor.is_some() {
            self.apply_free_space(&mut dirty, &mut rep);
        }
        self.merge_evidence(robot, t_s, kind, sensor.is_some(), &mut dirty, &mut rep);
        rep.dirty_cells = dirty.len();
        // 6a. Proprioception: the footprint is traversable ground at the robot's height.
        self.drive_footprint(robot, t_s, &mut dirty);
        // 4-6. Classification and the far rules, negative obstacles, inflation.
        self.reclassify(dirty, robot, &mut rep);
        rep.changed_tiles = self.take_changed_tiles();
        Ok(rep)
    }

    /// Refuses a non-finite pose, sensor or time, and time going back by an evidence epoch
    /// (`evidence_epoch_s`) or more; otherwise takes the robot pose and returns the time the
    /// update counts as. Sensors stamp differently: a LiDAR sweep carries its revolution's
    /// start, delivered a period later, while a depth frame carries its capture time, so a
    /// sweep routinely arrives up to a period older than the depth frame mapped just before
    /// it. Such an update is merged as of the newest time (it belongs to the same epoch);
    /// refusing it dropped every LiDAR sweep of a robot with a depth camera.
    fn begin_update(
        &mut self,
        sensor: Option<[f64; 3]>,
        robot: &RobotPose,
        t_s: f64,
    ) -> Result<f64, MapError> {
        if sensor.is_some_and(|o| !o.iter().all(|v| v.is_finite())) {
            return Err(MapError::BadPose);
        }
        if !robot.is_finite() || !t_s.is_finite() {
            return Err(MapError::BadPose);
        }
        let mut t_eff = t_s;
        if let Some(prev) = self.last_t_s {
            if t_s <= prev - self.cfg.evidence_epoch_s {
                return Err(MapError::TimeWentBack {
                    t_s,
                    previous_s: prev,
                });
            }
            t_eff = t_s.max(prev);
        }
        self.last_t_s = Some(t_eff);
        self.robot = Some(*robot);
        self.scan_id = self.scan_id.wrapping_add(1);
        Ok(t_eff)
    }

    /// Horizontal distance from the robot to a cell's centre, metres.
    #[inline]
    fn distance_m(&self, cx: i64, cy: i64, robot: &RobotPose) -> f64 {
        let (px, py) = self.center_m(cx, cy);
        norm2(px - robot.x_m, py - robot.y_m)
    }

    /// A cell's stored ground ([`CellData::ground`]); infinity where nothing is stored.
    #[inline]
    fn ground(&self, cx: i64, cy: i64) -> f32 {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        match self.slot(t) {
            Some(s) => {
                self.slots[s].ground[r as usize * self.lattice.tile_cells as usize + c as usize]
            }
            None => f32::INFINITY,
        }
    }

    /// Brings a cell's stored ground up to date after its evidence or driven height changed.
    #[inline]
    fn refresh_ground(&mut self, cx: i64, cy: i64) {
        let min_n = self.rules.min_points();
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        if let Some(s) = self.slot(t) {
            let k = r as usize * self.lattice.tile_cells as usize + c as usize;
            let slot = &mut self.slots[s];
            slot.ground[k] = slot.data[k].ground(min_n);
        }
    }

    #[inline]
    fn data(&self, cx: i64, cy: i64) -> Option<&CellData> {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        let s = self.slot(t)?;
        Some(&self.slots[s].data[r as usize * self.lattice.tile_cells as usize + c as usize])
    }

    /// The slot of a tile; lookups come in runs within one tile, so the last answer is kept.
    #[inline]
    fn slot(&self, t: TileIndex) -> Option<usize> {
        let (lt, ls) = self.last_slot.get();
        if lt == t && ls != usize::MAX {
            return Some(ls);
        }
        let s = *self.slot_of.get(&t)?;
        self.last_slot.set((t, s));
        Some(s)
    }

    /// The cell holding map point (x, y) (the lattice's rule without its per-call rounding).
    #[inline]
    fn cell_of(&self, x_m: f64, y_m: f64) -> (i64, i64) {
        (
            floor_i64(x_m * self.inv_cell_m),
            floor_i64(y_m * self.inv_cell_m),
        )
    }

    /// Centre of a global cell, map frame (the lattice's rule).
    #[inline]
    fn center_m(&self, cx: i64, cy: i64) -> (f64, f64) {
        (
            (cx as f64 + 0.5) * self.cell_m,
            (cy as f64 + 0.5) * self.cell_m,
        )
    }

    #[inline]
    fn data_mut(&mut self, cx: i64, cy: i64) -> &mut CellData {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        let n = self.lattice.tile_cells as usize;
        let s = match self.slot(t) {
            Some(s) => s,
            None => {
                self.slots.push(TileSlot {
                    index: t,
                    data: vec![CellData::default(); n * n],
                    ground: vec![f32::INFINITY; n * n],
                    live: vec![Cell::UNKNOWN; n * n],
                    held: vec![0; (n * n).div_ceil(64)],
                    changed: false,
                });
                self.slot_of.insert(t, self.slots.len() - 1);
                self.slots.len() - 1
            }
        };
        let k = r as usize * n + c as usize;
        let slot = &mut self.slots[s];
        slot.held[k >> 6] |= 1 << (k & 63);
        &mut slot.data[k]
    }

    /// Writes an output cell, marking its tile changed when the cell differs.
    #[inline]
    fn write_live(&mut self, cx: i64, cy: i64, cell: Cell) {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        let Some(s) = self.slot(t) else {
            return;
        };
        let n = self.lattice.tile_cells as usize;
        let k = r as usize * n + c as usize;
        let slot = &mut self.slots[s];
        if slot.live[k] != cell {
            slot.live[k] = cell;
            slot.changed = true;
        }
    }

    /// The tiles whose output cells changed since the last call, sorted. What is published
    /// when, with which version, is the consumer's policy, not the mapper's.
    fn take_changed_tiles(&mut self) -> Vec<TileIndex> {
        let mut out: Vec<TileIndex> = self
            .slots
            .iter_mut()
            .filter_map(|s| std::mem::take(&mut s.changed).then_some(s.index))
            .collect();
        out.sort_unstable();
        out
    }

    /// The final cell (after inflation) at a global lattice index.
    pub fn cell(&self, cx: i64, cy: i64) -> Cell {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        match self.slot(t) {
            Some(s) => {
                self.slots[s].live[r as usize * self.lattice.tile_cells as usize + c as usize]
            }
            None => Cell::UNKNOWN,
        }
    }

    /// The classification before inflation at a global lattice index (what is evaluated
    /// against truth labels).
    pub fn class(&self, cx: i64, cy: i64) -> Class {
        self.data(cx, cy).map(|d| d.class).unwrap_or_default()
    }
}
