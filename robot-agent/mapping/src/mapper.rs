//! The incremental traversability mapper: evidence per lattice cell, dirty-cell reclassification,
//! inflation, proprioception, negative obstacles, and changed tiles out.

use crate::classify::{CellStats, Class, Neighbourhood, Rules, Verdict};
use crate::config::Config;
use crate::filters;
use common::grid::{Cell, CellState, Lattice, Tile, TileIndex};
use nalgebra::Isometry3;
use sensing::{Point, Scan};
use std::collections::{HashMap, HashSet};
use std::hash::{BuildHasherDefault, Hasher};

/// Why an update was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MapError {
    /// The robot pose or the time is not finite.
    #[error("robot pose or time is not finite")]
    BadPose,
    /// Time went backwards.
    #[error("time {t_s} s is before the previous update ({previous_s} s)")]
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
    /// Cells whose points this sweep were ignored: seen much better from closer before.
    pub far_skipped: usize,
}

/// The planner's view: a window of final cells around the robot, row-major, row 0 southmost.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerView {
    /// The lattice.
    pub lattice: Lattice,
    /// Global lattice column of the window's cell (0, 0).
    pub min_cx: i64,
    /// Global lattice row of the window's cell (0, 0).
    pub min_cy: i64,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width * height` cells (state, cost, height, evidence).
    pub cells: Vec<Cell>,
}

impl PlannerView {
    /// The cell at a global lattice index; unknown outside the window.
    pub fn get(&self, cx: i64, cy: i64) -> Cell {
        let (x, y) = (cx - self.min_cx, cy - self.min_cy);
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return Cell::UNKNOWN;
        }
        self.cells[y as usize * self.width as usize + x as usize]
    }
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

/// Multiplicative hash for small integer keys (deterministic, no per-process seed).
#[derive(Default, Clone, Copy)]
struct FxHasher(u64);

impl Hasher for FxHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(u64::from(*b));
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i32(&mut self, v: i32) {
        self.write_u64(v as u32 as u64);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
}

type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FxHasher>>;
type FastSet<K> = HashSet<K, BuildHasherDefault<FxHasher>>;

/// Running height moments.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Moments {
    n: u32,
    sz: f64,
    szz: f64,
    /// Highest point; a riser's points pull a cell's mean halfway down the step, its top does not.
    zmax: f32,
    /// Lowest point: the cell's ground when something stands on it.
    zmin: f32,
}

impl Default for Moments {
    fn default() -> Self {
        Self {
            n: 0,
            sz: 0.0,
            szz: 0.0,
            zmax: f32::NEG_INFINITY,
            zmin: f32::INFINITY,
        }
    }
}

impl Moments {
    fn add(&mut self, z: f64) {
        self.n += 1;
        self.sz += z;
        self.szz += z * z;
        self.zmax = self.zmax.max(z as f32);
        self.zmin = self.zmin.min(z as f32);
    }
    fn merged(&self, o: &Moments) -> Moments {
        Moments {
            n: self.n + o.n,
            sz: self.sz + o.sz,
            szz: self.szz + o.szz,
            zmax: self.zmax.max(o.zmax),
            zmin: self.zmin.min(o.zmin),
        }
    }
    /// The same points moved up by `dz`.
    fn shifted(&self, dz: f64) -> Moments {
        if self.n == 0 {
            return *self;
        }
        let n = f64::from(self.n);
        Moments {
            n: self.n,
            sz: self.sz + n * dz,
            szz: self.szz + 2.0 * dz * self.sz + n * dz * dz,
            zmax: self.zmax + dz as f32,
            zmin: self.zmin + dz as f32,
        }
    }
    fn stats(&self) -> CellStats {
        if self.n == 0 {
            return CellStats::default();
        }
        let n = f64::from(self.n);
        let mean = self.sz / n;
        CellStats {
            n: self.n,
            mean_m: mean,
            var_m2: (self.szz / n - mean * mean).max(0.0),
            max_m: f64::from(self.zmax),
            min_m: f64::from(self.zmin),
        }
    }
}

/// Everything the mapper keeps about one lattice cell.
#[derive(Clone, Copy, Debug)]
struct CellData {
    /// Evidence of the newest epoch with observations, and of the one before.
    cur: Moments,
    prev: Moments,
    /// Closest robot distance each epoch's evidence was seen from, metres.
    cur_range_m: f32,
    prev_range_m: f32,
    /// Session time evidence was last accepted into the cell, seconds.
    accepted_s: f32,
    /// Closest robot distance from which this cell was judged a drop-off, metres.
    neg_range_m: f32,
    /// Closest robot distance from which the cell's current class was judged, metres.
    class_range_m: f32,
    epoch: i64,
    /// Points far above the cell's ground seen in one scan only, waiting for confirmation.
    pending: Moments,
    pending_scan: u32,
    /// MapCloud mode: the moments last received, to tell unchanged cells.
    last_cloud: Moments,
    hits: u8,
    last_scan: u32,
    stamp_s: u32,
    /// A beam crossed the band between `clear_low_m` and the robot's height above this cell's
    /// ground: the space the robot body needs was seen empty at least once.
    headroom: bool,
    /// Free space wiped this cell from beyond the processing distance since it was last
    /// classified: it may be judged again from out there (towards traversable or unknown).
    far_wiped: bool,
    /// The robot's footprint covered this cell (proprioception), at this ground height.
    driven: bool,
    driven_z: f32,
    class: Class,
}

impl Default for CellData {
    fn default() -> Self {
        Self {
            cur: Moments::default(),
            prev: Moments::default(),
            cur_range_m: f32::INFINITY,
            prev_range_m: f32::INFINITY,
            accepted_s: f32::NEG_INFINITY,
            neg_range_m: f32::INFINITY,
            class_range_m: f32::INFINITY,
            epoch: 0,
            pending: Moments::default(),
            pending_scan: 0,
            last_cloud: Moments::default(),
            hits: 0,
            last_scan: 0,
            stamp_s: 0,
            headroom: false,
            far_wiped: false,
            driven: false,
            driven_z: 0.0,
            class: Class::default(),
        }
    }
}

impl CellData {
    fn evidence(&self) -> Moments {
        self.cur.merged(&self.prev)
    }

    /// The cell's ground: its lowest return when it has evidence enough, else where the robot
    /// drove over it, else infinity (unknown).
    fn ground(&self, min_n: u32) -> f32 {
        let e = self.evidence();
        if e.n >= min_n {
            e.zmin
        } else if self.driven {
            self.driven_z
        } else {
            f32::INFINITY
        }
    }

    /// Whether the robot's proof that it drove here still holds: it does unless the current
    /// evidence shows something standing on the driven ground (a car parked, a tree fallen on
    /// a taught route since), which only observation can judge.
    fn driven_free(&self, stand_m: f32) -> bool {
        self.driven && {
            let ev = self.evidence();
            ev.n == 0 || ev.zmax <= self.driven_z + stand_m
        }
    }
}

struct TileSlot {
    index: TileIndex,
    data: Vec<CellData>,
    /// Each cell's ground ([`CellData::ground`]), kept beside the data: the beam march and the
    /// ceilings look it up for tens of thousands of cells per sweep, and 4 bytes a cell stay in
    /// cache where the whole cell does not.
    ground: Vec<f32>,
    /// The current output cells.
    live: Vec<Cell>,
    /// An output cell changed since the tile was last handed out as changed.
    changed: bool,
}

/// The beams of one sweep over one cell.
#[derive(Clone, Copy)]
struct Pass {
    /// The ground the cell's crossing beams are measured from (NaN: not visited this sweep).
    g: f32,
    /// The lowest crossing in the headroom band (absolute height, metres).
    lo: f32,
    /// Beams that crossed the cell in the headroom band.
    n: u16,
}

impl Default for Pass {
    fn default() -> Self {
        Self {
            g: f32::NAN,
            lo: f32::INFINITY,
            n: 0,
        }
    }
}

/// Scratch arrays over a square window of cells around the robot, reused between updates.
struct Window {
    half: i64,
    side: usize,
    cx0: i64,
    cy0: i64,
    zmin: Vec<f32>,
    ceiling: Vec<f32>,
    low: Vec<Moments>,
    high: Vec<Moments>,
    touched: Vec<usize>,
    mark: Vec<u32>,
    generation: u32,
    /// Free space of this sweep per cell, all a beam step needs in one place.
    pass: Vec<Pass>,
    /// Stored ground per cell for the ceilings (NaN: not looked up; reset after each use).
    stored_ground: Vec<f32>,
    pass_touched: Vec<usize>,
    /// Per-cell stats as the rules see them, cached during `reclassify` (generation, stats).
    stats: Vec<std::cell::Cell<(u32, CellStats)>>,
    stats_generation: u32,
    /// Whether `stats` may be used: only while evidence stands still.
    stats_on: bool,
}

impl Window {
    fn new(half: i64) -> Self {
        let side = (2 * half + 1) as usize;
        let n = side * side;
        Self {
            half,
            side,
            cx0: 0,
            cy0: 0,
            zmin: vec![f32::INFINITY; n],
            ceiling: vec![f32::INFINITY; n],
            low: vec![Moments::default(); n],
            high: vec![Moments::default(); n],
            touched: Vec::new(),
            mark: vec![0; n],
            generation: 0,
            pass: vec![Pass::default(); n],
            stored_ground: vec![f32::NAN; n],
            pass_touched: Vec::new(),
            stats: vec![std::cell::Cell::new((0, CellStats::default())); n],
            stats_generation: 0,
            stats_on: false,
        }
    }
    fn local(&self, cx: i64, cy: i64) -> Option<usize> {
        let (x, y) = (cx - self.cx0 + self.half, cy - self.cy0 + self.half);
        (x >= 0 && y >= 0 && (x as usize) < self.side && (y as usize) < self.side)
            .then(|| y as usize * self.side + x as usize)
    }
    fn global(&self, i: usize) -> (i64, i64) {
        (
            (i % self.side) as i64 - self.half + self.cx0,
            (i / self.side) as i64 - self.half + self.cy0,
        )
    }
    fn clear(&mut self) {
        for &i in &self.touched {
            self.zmin[i] = f32::INFINITY;
            self.ceiling[i] = f32::INFINITY;
            self.low[i] = Moments::default();
            self.high[i] = Moments::default();
        }
        self.touched.clear();
        for &i in &self.pass_touched {
            self.pass[i] = Pass::default();
        }
        self.pass_touched.clear();
    }
    /// Starts using the stats cache afresh (evidence will stand still until `end_stats`).
    fn begin_stats(&mut self) {
        self.stats_generation = self.stats_generation.wrapping_add(1);
        if self.stats_generation == 0 {
            self.stats
                .iter_mut()
                .for_each(|c| *c.get_mut() = (0, CellStats::default()));
            self.stats_generation = 1;
        }
        self.stats_on = true;
    }

    /// Evidence may change again: the stats cache is off.
    fn end_stats(&mut self) {
        self.stats_on = false;
    }

    /// Starts a new de-duplication generation for `mark`.
    fn next_generation(&mut self) -> u32 {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.generation = 1;
        }
        self.generation
    }
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

/// The headroom band stops this far below the robot's height: a beam passing just under `h_r`
/// over a cell says little about the robot's top (and a car body's top is about that high).
const HEADROOM_TOP_MARGIN_M: f64 = 0.2;
/// How far the ground beyond the processing distance may lie above or below the robot's for a
/// beam still to be marched there, metres (the terrain, not the band, limits the far march).
const FAR_TERRAIN_SLACK_M: f64 = 0.5;
/// Points this far above their cell's lowest return in the sweep go through the isolated-point
/// filter; lower ones are ground and cannot raise an obstacle on their own, metres.
const SUSPECT_ABOVE_M: f32 = 0.04;

impl Mapper {
    /// A mapper with an empty grid.
    pub fn new(cfg: Config) -> Result<Self, MapError> {
        cfg.validate()?;
        let l = cfg.grid_size_m;
        let range_cells = (cfg.max_range_m / l).ceil() as i64;
        let view_half = i64::from(cfg.num_of_grid_cells / 2);
        let half = range_cells.max(view_half) + i64::from(cfg.ceiling_radius_cells) + 8;
        let rc = (cfg.cost_distance_m / l).ceil() as i64;
        let mut offsets = Vec::new();
        for dy in -rc..=rc {
            for dx in -rc..=rc {
                let d = (dx as f64).hypot(dy as f64) * l;
                if d <= cfg.cost_distance_m + 1e-9 {
                    offsets.push((d, dx, dy));
                }
            }
        }
        offsets.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
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
        self.update(pts, Some([o.x, o.y, o.z]), robot, t_s, Evidence::Scan)
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
        self.update(pts_map, Some(sensor_map), robot, t_s, Evidence::Scan)
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
        self.update(pts, None, robot, t_s, kind)
    }

    /// The core step.
    fn update(
        &mut self,
        mut pts: Vec<[f32; 3]>,
        sensor: Option<[f64; 3]>,
        robot: &RobotPose,
        t_s: f64,
        kind: Evidence,
    ) -> Result<UpdateReport, MapError> {
        if sensor.is_some_and(|o| !o.iter().all(|v| v.is_finite())) {
            return Err(MapError::BadPose);
        }
        if !robot.is_finite() || !t_s.is_finite() {
            return Err(MapError::BadPose);
        }
        if let Some(prev) = self.last_t_s {
            if t_s < prev {
                return Err(MapError::TimeWentBack {
                    t_s,
                    previous_s: prev,
                });
            }
        }
        self.last_t_s = Some(t_s);
        self.robot = Some(*robot);
        self.scan_id = self.scan_id.wrapping_add(1);
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

        // 1-2. Height filter around the robot, isolated points.
        rep.dropped_height = filters::height_filter(
            &mut pts,
            [robot.x_m, robot.y_m, robot.z_m],
            self.cfg.h_r_m,
            self.cfg.phi_max_deg.to_radians(),
            self.cfg.max_range_m,
        );
        {
            // Only points above their cell's lowest return this sweep are worth testing.
            let li: Vec<Option<usize>> = pts
                .iter()
                .map(|p| {
                    let (cx, cy) = self.cell_of(f64::from(p[0]), f64::from(p[1]));
                    self.win.local(cx, cy)
                })
                .collect();
            for (p, l) in pts.iter().zip(&li) {
                if let Some(i) = *l {
                    if self.win.zmin[i] == f32::INFINITY {
                        self.win.touched.push(i);
                    }
                    self.win.zmin[i] = self.win.zmin[i].min(p[2]);
                }
            }
            let test: Vec<bool> = pts
                .iter()
                .zip(&li)
                .map(|(p, l)| l.is_none_or(|i| p[2] > self.win.zmin[i] + SUSPECT_ABOVE_M))
                .collect();
            rep.dropped_isolated =
                filters::isolated_point_filter_where(&mut pts, &self.cfg.isolated_pairs, &test);
            for &i in &self.win.touched {
                self.win.zmin[i] = f32::INFINITY;
            }
            self.win.touched.clear();
        }

        // 3. Binning with the per-cell ceiling, into the scratch window.
        let mut cells_of = Vec::with_capacity(pts.len());
        for p in &pts {
            let (cx, cy) = self.cell_of(f64::from(p[0]), f64::from(p[1]));
            let li = self.win.local(cx, cy);
            cells_of.push(li);
            if let Some(i) = li {
                if self.win.zmin[i] == f32::INFINITY {
                    self.win.touched.push(i);
                }
                self.win.zmin[i] = self.win.zmin[i].min(p[2]);
            }
        }
        self.win.touched.sort_unstable();
        self.compute_ceilings();
        let stray_on = kind == Evidence::Scan && self.cfg.stray_height_m > 0.0;
        // The ground reference for stray points: the lowest point in the cell this scan, or the
        // ground the cell already showed, whichever is lower.
        let mut ref_z: FastMap<usize, f32> = FastMap::default();
        if stray_on {
            for &i in &self.win.touched {
                let (cx, cy) = self.win.global(i);
                let mut r = self.win.zmin[i];
                if let Some(d) = self.data(cx, cy) {
                    let e = d.evidence().stats();
                    if e.n >= self.rules.min_points() {
                        r = r.min(e.mean_m as f32);
                    }
                }
                ref_z.insert(i, r);
            }
        }
        for (p, li) in pts.iter().zip(&cells_of) {
            let Some(i) = *li else { continue };
            if p[2] > self.win.ceiling[i] {
                rep.dropped_ceiling += 1;
                continue;
            }
            let high = stray_on
                && ref_z
                    .get(&i)
                    .is_some_and(|r| p[2] > r + self.cfg.stray_height_m as f32);
            if high {
                self.win.high[i].add(f64::from(p[2]));
            } else {
                self.win.low[i].add(f64::from(p[2]));
            }
        }

        // Merge into the cells' evidence; collect dirty cells.
        let epoch = (t_s / self.cfg.evidence_epoch_s).floor() as i64;
        let stamp = t_s.max(0.0).min(f64::from(u32::MAX)) as u32;
        let scan = self.scan_id;
        let mut dirty = Vec::new();
        if sensor.is_some() {
            self.apply_free_space(&mut dirty, &mut rep);
        }
        let touched = std::mem::take(&mut self.win.touched);
        dirty.reserve(touched.len());
        for &i in &touched {
            let (low, high) = (self.win.low[i], self.win.high[i]);
            if low.n == 0 && high.n == 0 {
                continue;
            }
            let (cx, cy) = self.win.global(i);
            let (ccx, ccy) = self.center_m(cx, cy);
            let range_m = norm2(ccx - robot.x_m, ccy - robot.y_m) as f32;
            let far_factor = self.cfg.far_evidence_factor as f32;
            let stale_s = self.cfg.evidence_stale_s as f32;
            let grows = self.cfg.max_step_m as f32;
            let d = self.data_mut(cx, cy);
            // A cell seen well from close by keeps that view against much poorer ones from far
            // away (the moving vantage would otherwise let a sparse far glimpse replace a curb
            // seen at 3 m). Changes are still caught: things that went by free space, things
            // that came by the far view showing points higher than the cell held, anything once
            // the close view is `evidence_stale_s` old.
            let best = d.cur_range_m.min(d.prev_range_m);
            // Unless the far view shows something new: standing up above what the cell held, or a
            // surface lower than it (a cover gone from a hole).
            let incoming = low.merged(&high);
            let held = d.evidence();
            let news = incoming.zmax > held.zmax + grows || incoming.zmin < held.zmin - grows;
            let far = kind == Evidence::Scan
                && d.cur.n > 0
                && range_m > far_factor * best + 1.0
                && !news
                && (t_s as f32) - d.accepted_s < stale_s;
            if far {
                rep.far_skipped += 1;
                continue;
            }
            d.accepted_s = t_s as f32;
            let changed = match kind {
                Evidence::MapCloud => {
                    let m = low.merged(&high);
                    if m == d.last_cloud {
                        false
                    } else {
                        d.last_cloud = m;
                        d.cur = m;
                        d.cur_range_m = range_m;
                        d.prev = Moments::default();
                        d.prev_range_m = f32::INFINITY;
                        true
                    }
                }
                Evidence::Scan => {
                    let mut add = low;
                    if high.n > 0 {
                        if d.pending.n > 0 && d.pending_scan != scan {
                            // Seen again in a later scan: not a stray point.
                            add = add.merged(&d.pending).merged(&high);
                            d.pending = Moments::default();
                        } else {
                            d.pending = high;
                            d.pending_scan = scan;
                            rep.held_stray += high.n as usize;
                        }
                    } else {
                        d.pending = Moments::default();
                    }
                    if add.n > 0 {
                        if epoch > d.epoch || d.cur.n == 0 {
                            d.prev = d.cur;
                            d.prev_range_m = d.cur_range_m;
                            d.cur = Moments::default();
                            d.cur_range_m = f32::INFINITY;
                            d.epoch = epoch;
                        }
                        d.cur = d.cur.merged(&add);
                        d.cur_range_m = d.cur_range_m.min(range_m);
                    }
                    add.n > 0
                }
            };
            if sensor.is_none() {
                // No beams to judge by: a map cloud's cells are taken as they come.
                d.headroom = true;
            }
            if d.last_scan != scan {
                d.last_scan = scan;
                d.hits = d.hits.saturating_add(1);
            }
            d.stamp_s = stamp;
            if changed {
                self.refresh_ground(cx, cy);
                dirty.push((cx, cy));
            }
        }
        self.win.touched = touched;
        rep.dirty_cells = dirty.len();

        // 6a. Proprioception: the footprint is traversable ground at the robot's height.
        for (cx, cy) in self.footprint_cells(robot) {
            let d = self.data_mut(cx, cy);
            if !d.driven || (d.driven_z - robot.z_m as f32).abs() > 0.01 {
                d.driven = true;
                d.driven_z = robot.z_m as f32;
                d.stamp_s = stamp;
                self.refresh_ground(cx, cy);
                dirty.push((cx, cy));
            }
        }

        self.reclassify(dirty, robot, &mut rep);
        rep.changed_tiles = self.take_changed_tiles();
        Ok(rep)
    }

    /// Reclassifies every cell of the window from the stored evidence (the full baseline).
    pub fn reclassify_all(&mut self) -> UpdateReport {
        let mut rep = UpdateReport::default();
        let Some(robot) = self.robot else { return rep };
        self.reclassify(Vec::new(), &robot, &mut rep);
        rep
    }

    /// The map frame moved under the robot by `delta` (a GNSS or gravity correction of the
    /// frame: new map point = `delta` * old). Stored heights follow it, so the map stays what a
    /// map kept in the SLAM frame and shown through the current anchor would be: left alone,
    /// a correction of the frame's tilt or height sets new scans of the same ground off
    /// against the stored heights as false steps. Cells within `radius_m` of the robot follow
    /// fully and the last quarter of the radius tapers to nothing, so no ring of cells is left
    /// as a step against its neighbours (a hard edge at 30 m, or following only the cells seen
    /// in the last 20 s, made 3-7 % of `slopes` false obstacles with the robot's own poses).
    /// Horizontal moves are ignored (a few centimetres, within a cell). Returns the cells moved.
    pub fn follow_frame(&mut self, delta: &Isometry3<f64>, radius_m: f64) -> usize {
        let Some(robot) = self.robot else { return 0 };
        let full_m = 0.75 * radius_m;
        let taper_m = (radius_m - full_m).max(1e-9);
        let dz_at = |x: f64, y: f64, z: f64| (delta * nalgebra::Point3::new(x, y, z)).z - z;
        let corners = [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)];
        let worst = corners
            .iter()
            .map(|(sx, sy)| {
                dz_at(
                    robot.x_m + sx * radius_m,
                    robot.y_m + sy * radius_m,
                    robot.z_m,
                )
                .abs()
            })
            .fold(0.0, f64::max);
        // Nothing to do for a purely horizontal correction (or a non-finite one).
        if !worst.is_finite() || worst <= 1e-5 {
            return 0;
        }
        let n = self.lattice.tile_cells as i64;
        let l = self.cfg.grid_size_m;
        let r2 = radius_m * radius_m;
        let min_n = self.rules.min_points();
        let mut moved = 0;
        for slot in &mut self.slots {
            let (x0, y0) = (i64::from(slot.index.tx) * n, i64::from(slot.index.ty) * n);
            // Skip tiles wholly outside the radius.
            let tile_m = n as f64 * l;
            let (tx, ty) = (x0 as f64 * l, y0 as f64 * l);
            let nx = robot.x_m.clamp(tx, tx + tile_m) - robot.x_m;
            let ny = robot.y_m.clamp(ty, ty + tile_m) - robot.y_m;
            if nx * nx + ny * ny > r2 {
                continue;
            }
            for (i, d) in slot.data.iter_mut().enumerate() {
                let (c, r) = ((i as i64) % n, (i as i64) / n);
                let x = (x0 + c) as f64 * l + 0.5 * l;
                let y = (y0 + r) as f64 * l + 0.5 * l;
                let (ex, ey) = (x - robot.x_m, y - robot.y_m);
                let e2 = ex * ex + ey * ey;
                if e2 > r2 || (d.cur.n == 0 && d.prev.n == 0 && !d.driven) {
                    continue;
                }
                let weight = ((radius_m - e2.sqrt()) / taper_m).clamp(0.0, 1.0);
                let z = if d.cur.n > 0 {
                    d.cur.stats().mean_m
                } else {
                    robot.z_m
                };
                let dz = weight * dz_at(x, y, z);
                d.cur = d.cur.shifted(dz);
                d.prev = d.prev.shifted(dz);
                d.pending = d.pending.shifted(dz);
                if d.driven {
                    d.driven_z += dz as f32;
                }
                slot.ground[i] = d.ground(min_n);
                moved += 1;
            }
        }
        if let Some(r) = self.robot.as_mut() {
            r.z_m += dz_at(r.x_m, r.y_m, r.z_m);
        }
        moved
    }

    /// Marks the cells of the window that this sweep's beams crossed inside the headroom band:
    /// from `clear_low_m` up to `h_r - HEADROOM_TOP_MARGIN_M` above the cell's own ground (its
    /// lowest return of this sweep, or its stored mean). Every `beam_stride`-th return is
    /// marched, out to `processing_distance`. Returns the number of beams marched.
    fn march_beams(&mut self, pts: &[[f32; 3]], o: [f64; 3], robot: &RobotPose) -> usize {
        let l = self.cfg.grid_size_m;
        let inv_l = 1.0 / l;
        // The cells' ground: this sweep's lowest return per cell first.
        for p in pts {
            let (cx, cy) = (
                floor_i64(f64::from(p[0]) * inv_l),
                floor_i64(f64::from(p[1]) * inv_l),
            );
            if let Some(i) = self.win.local(cx, cy) {
                if self.win.zmin[i] == f32::INFINITY {
                    self.win.touched.push(i);
                }
                self.win.zmin[i] = self.win.zmin[i].min(p[2]);
            }
        }
        let step = 0.7 * l;
        let low = self.cfg.clear_low_m as f32;
        let high = (self.cfg.h_r_m - HEADROOM_TOP_MARGIN_M) as f32;
        let reach = self.cfg.processing_distance_m.max(self.cfg.clear_reach_m);
        let zs = o[2];
        let near = self.cfg.processing_distance_m;
        let h0 = zs - robot.z_m;
        let (band_lo, band_hi) = (
            f64::from(low) - FAR_TERRAIN_SLACK_M,
            f64::from(high) + FAR_TERRAIN_SLACK_M,
        );
        let stride = self.cfg.beam_stride.max(1);
        let mut marched = 0usize;
        let side = self.win.side;
        let (ux0, uy0) = (
            o[0] * inv_l - (self.win.cx0 - self.win.half) as f64,
            o[1] * inv_l - (self.win.cy0 - self.win.half) as f64,
        );
        for p in pts.iter().step_by(stride) {
            let (px, py, pz) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            let (dx, dy) = (px - o[0], py - o[1]);
            let d = norm2(dx, dy);
            if d < 2.0 * l {
                continue;
            }
            // Never the last cells (the return's own and the one it may straddle).
            let mut f1 = (1.0 - 1.5 * l / d).min(reach / d);
            if f1 <= 0.0 {
                continue;
            }
            if f1 * d > near {
                // Beyond the processing distance only the beam's stretch that can still be in
                // a cell's band is marched: the band about the robot's ground, widened by how
                // far the terrain may rise or fall out there. Steeper rings leave it early.
                let k = (pz - zs) / d;
                let r_end = if k > 0.0 {
                    (band_hi - h0) / k
                } else if k < 0.0 {
                    (band_lo - h0) / k
                } else {
                    f64::INFINITY
                };
                f1 = f1.min(r_end.max(near) / d);
            }
            marched += 1;
            let n = ((f1 * d) / step).ceil() as usize + 1;
            let mut last = usize::MAX;
            // Stepped in window cells: the step's cell is its coordinates truncated (negative
            // ones are outside the window anyway).
            let per = f1 / ((n - 1) as f64);
            let (sx, sy, sz) = (dx * per * inv_l, dy * per * inv_l, (pz - zs) * per);
            for k in 1..n {
                let kf = k as f64;
                let (ux, uy) = (ux0 + sx * kf, uy0 + sy * kf);
                if ux < 0.0 || uy < 0.0 {
                    continue;
                }
                let (ix, iy) = (ux as usize, uy as usize);
                if ix >= side || iy >= side {
                    continue;
                }
                let i = iy * side + ix;
                if i == last {
                    continue;
                }
                last = i;
                if self.win.pass[i].g.is_nan() {
                    // First visit this sweep: the cell's ground, or infinity when unknown.
                    let (cx, cy) = self.win.global(i);
                    let g = self.win.zmin[i].min(self.ground(cx, cy));
                    self.win.pass[i].g = g;
                    self.win.pass_touched.push(i);
                }
                let g = self.win.pass[i].g;
                let z = (zs + sz * kf) as f32;
                let h = z - g;
                if !(low..=high).contains(&h) {
                    continue;
                }
                let ps = &mut self.win.pass[i];
                ps.n = ps.n.saturating_add(1);
                if z < ps.lo {
                    ps.lo = z;
                }
            }
        }
        // The sweep's ground lookup is done: the normal binning starts from a clean slate.
        for &i in &self.win.touched {
            self.win.zmin[i] = f32::INFINITY;
        }
        self.win.touched.clear();
        marched
    }

    /// Applies the sweep's free space: every crossed cell has seen headroom; a cell whose stored
    /// points stand higher than where a beam just crossed it freely, with nothing of this sweep
    /// up there, held something that has gone (a walker, a stray point): its old evidence is
    /// dropped so this sweep's points rebuild it.
    fn apply_free_space(&mut self, dirty: &mut Vec<(i64, i64)>, rep: &mut UpdateReport) {
        let touched = std::mem::take(&mut self.win.pass_touched);
        let near_passes = self.cfg.clear_min_beams.max(1);
        let margin = self.cfg.clear_margin_m as f32;
        let stand_m = self.cfg.stray_height_m as f32;
        let pd_cells2 = (self.cfg.processing_distance_m / self.cfg.grid_size_m).powi(2);
        let (rcx, rcy) = (self.win.cx0, self.win.cy0);
        for &i in &touched {
            let (cx, cy) = self.win.global(i);
            let (n, lo) = (self.win.pass[i].n, self.win.pass[i].lo);
            if n == 0 {
                continue;
            }
            let far = ((cx - rcx).pow(2) + (cy - rcy).pow(2)) as f64 > pd_cells2;
            let min_passes = if far { 1 } else { near_passes };
            // This sweep's own returns in the cell up at the beams' height: still occupied.
            let now_top = self.win.low[i].zmax.max(self.win.high[i].zmax);
            let occupied_now = now_top >= lo - margin;
            let Some(d) = self.data(cx, cy) else {
                continue;
            };
            if d.driven_free(stand_m) {
                continue;
            }
            let stale = n >= min_passes
                && !occupied_now
                && d.evidence().n > 0
                && d.evidence().zmax > lo + margin
                && (!far || self.neighbours_free_now(cx, cy, lo - margin));
            // A lone grazing beam from afar is too thin to grant headroom (it slips under car
            // bodies at their edges); it only wipes what has gone.
            let first_headroom = !d.headroom && !far;
            if stale || first_headroom {
                let d = self.data_mut(cx, cy);
                d.headroom = true;
                if stale {
                    d.cur = Moments::default();
                    d.prev = Moments::default();
                    d.pending = Moments::default();
                    d.cur_range_m = f32::INFINITY;
                    d.prev_range_m = f32::INFINITY;
                    d.class_range_m = f32::INFINITY;
                    d.far_wiped = far;
                    rep.cleared_cells += 1;
                    self.refresh_ground(cx, cy);
                }
                dirty.push((cx, cy));
            }
        }
        self.win.pass_touched = touched;
    }

    /// Whether none of this sweep's returns in the 8 cells around stands at or above `z`: far
    /// away one beam wipes a cell only where nothing of the sweep is up there next door either
    /// (a beam slipping past a car's edge inside a boundary cell must not wipe it).
    fn neighbours_free_now(&self, cx: i64, cy: i64, z: f32) -> bool {
        for dy in -1..=1 {
            for dx in -1..=1 {
                if let Some(j) = self.win.local(cx + dx, cy + dy) {
                    if self.win.low[j].zmax.max(self.win.high[j].zmax) >= z {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// The ceiling `h_max2` of every touched cell: the lowest ground within
    /// `ceiling_radius_cells`, from this sweep or (where this sweep's rings left a gap) from what
    /// the cells showed before, plus `h_r` and the climb allowance to that cell. Without the stored
    /// ground a tree canopy between two rings would set its own ceiling and come in as an obstacle.
    fn compute_ceilings(&mut self) {
        let r = i64::from(self.cfg.ceiling_radius_cells);
        let tan_phi = self.cfg.phi_max_deg.to_radians().tan() as f32;
        let l = self.cfg.grid_size_m as f32;
        let h_r = self.cfg.h_r_m as f32;
        let side = self.win.side as i64;
        let mut looked_up: Vec<usize> = Vec::new();
        // The climb allowance per offset, once.
        let span = (2 * r + 1) as usize;
        let cone: Vec<f32> = (0..span * span)
            .map(|k| {
                let (dx, dy) = ((k % span) as i64 - r, (k / span) as i64 - r);
                tan_phi * l * ((dx * dx + dy * dy) as f32).sqrt()
            })
            .collect();
        for k in 0..self.win.touched.len() {
            let i = self.win.touched[k];
            let (x, y) = ((i as i64) % side, (i as i64) / side);
            let mut best = f32::INFINITY;
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= side {
                    continue;
                }
                let row = ((dy + r) as usize) * span;
                for dx in -r..=r {
                    let xx = x + dx;
                    if xx < 0 || xx >= side {
                        continue;
                    }
                    let j = (yy * side + xx) as usize;
                    let mut sg = self.win.stored_ground[j];
                    if sg.is_nan() {
                        let (cx, cy) = self.win.global(j);
                        sg = self.ground(cx, cy);
                        self.win.stored_ground[j] = sg;
                        looked_up.push(j);
                    }
                    let z = self.win.zmin[j].min(sg);
                    best = best.min(z + cone[row + (dx + r) as usize]);
                }
            }
            self.win.ceiling[i] = best + h_r;
        }
        for j in looked_up {
            self.win.stored_ground[j] = f32::NAN;
        }
    }

    fn footprint_cells(&self, robot: &RobotPose) -> Vec<(i64, i64)> {
        let (hl, hw) = (
            self.cfg.footprint_length_m / 2.0,
            self.cfg.footprint_width_m / 2.0,
        );
        if hl <= 0.0 || hw <= 0.0 {
            return Vec::new();
        }
        let (c, s) = (robot.yaw_rad.cos(), robot.yaw_rad.sin());
        let rad = hl.hypot(hw);
        let (x0, y0) = self.lattice.cell_of(robot.x_m - rad, robot.y_m - rad);
        let (x1, y1) = self.lattice.cell_of(robot.x_m + rad, robot.y_m + rad);
        let mut out = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let (px, py) = self.center_m(cx, cy);
                let (dx, dy) = (px - robot.x_m, py - robot.y_m);
                let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
                if u.abs() <= hl && v.abs() <= hw {
                    out.push((cx, cy));
                }
            }
        }
        out
    }

    /// Steps 4-6: classify the cells around `dirty` (or the whole window in full mode), find
    /// negative obstacles, and refresh inflation and costs where classes changed.
    fn reclassify(&mut self, dirty: Vec<(i64, i64)>, robot: &RobotPose, rep: &mut UpdateReport) {
        let (rcx, rcy) = self.lattice.cell_of(robot.x_m, robot.y_m);
        self.win.cx0 = rcx;
        self.win.cy0 = rcy;
        let l = self.cfg.grid_size_m;
        let pd_cells = self.cfg.processing_distance_m / l;
        self.win.begin_stats();
        let within = |cx: i64, cy: i64| norm2((cx - rcx) as f64, (cy - rcy) as f64) <= pd_cells;

        // The cells to classify: dirty ones dilated by the 5x5 rule neighbourhood.
        let mut todo: Vec<(i64, i64)> = Vec::new();
        let g = self.win.next_generation();
        if self.full {
            let h = i64::from(self.cfg.num_of_grid_cells / 2);
            for cy in rcy - h..rcy + h {
                for cx in rcx - h..rcx + h {
                    if self.data(cx, cy).is_some() {
                        todo.push((cx, cy));
                    }
                }
            }
        } else {
            let add = |win: &mut Window,
                       cx: i64,
                       cy: i64,
                       todo: &mut Vec<(i64, i64)>,
                       pending: &mut FastSet<(i64, i64)>| {
                if let Some(i) = win.local(cx, cy) {
                    if win.mark[i] != g {
                        win.mark[i] = g;
                        todo.push((cx, cy));
                    }
                } else {
                    pending.insert((cx, cy));
                }
            };
            for &(cx, cy) in &dirty {
                for dy in -2..=2 {
                    for dx in -2..=2 {
                        add(
                            &mut self.win,
                            cx + dx,
                            cy + dy,
                            &mut todo,
                            &mut self.pending,
                        );
                    }
                }
            }
            // Cells that got evidence while far away and are now within reach.
            let mut now: Vec<(i64, i64)> = self
                .pending
                .iter()
                .copied()
                .filter(|&(cx, cy)| within(cx, cy))
                .collect();
            now.sort_unstable();
            for (cx, cy) in now {
                self.pending.remove(&(cx, cy));
                add(&mut self.win, cx, cy, &mut todo, &mut self.pending);
            }
        }

        // Classification (step 4). Collect the cells whose class changed.
        let mut changed: Vec<(i64, i64)> = Vec::new();
        let mut refreshed: Vec<(i64, i64)> = Vec::new();
        for &(cx, cy) in &todo {
            if !within(cx, cy) {
                if let Some(d) = self.data(cx, cy).copied() {
                    if !self.full {
                        self.pending.insert((cx, cy));
                    }
                    // A cell judged traversable from close by may still turn into an obstacle
                    // from out here: the lower side of a step that lay in the step's shadow
                    // when the robot passed shows up in a later, distant view. Only that way
                    // round (distant evidence never clears), and only for a step verdict
                    // against a lower neighbour seen from afar (`shadowed_step`).
                    let pd = self.cfg.processing_distance_m as f32;
                    if self.cfg.far_step_distance_m > 0.0
                        && d.class == Class::Traversable
                        && d.class_range_m <= pd
                        && !d.driven_free(self.cfg.stray_height_m as f32)
                        && self.distance_m(cx, cy, robot) <= self.cfg.far_step_distance_m
                        && self.shadowed_step(cx, cy, &d)
                    {
                        self.data_mut(cx, cy).class = Class::Obstacle;
                        changed.push((cx, cy));
                    }
                    // A cell left unknown from close by whose evidence came from out here, and
                    // whose rules now find a step, continues an obstacle judged from close by
                    // beside it: the upper treads of a stair whose lower ones were judged as
                    // the robot passed. Only beside such an obstacle, so sparse far views of
                    // open ground raise nothing.
                    if self.cfg.far_step_distance_m > 0.0
                        && d.class == Class::Unknown
                        && d.class_range_m <= pd
                        && !d.far_wiped
                    {
                        let beside_close_obstacle = (-1..=1).any(|dy| {
                            (-1..=1).any(|dx| {
                                (dx != 0 || dy != 0)
                                    && self.data(cx + dx, cy + dy).is_some_and(|n| {
                                        n.class == Class::Obstacle && n.class_range_m <= pd
                                    })
                            })
                        });
                        if beside_close_obstacle
                            && self.distance_m(cx, cy, robot) <= self.cfg.far_step_distance_m
                            && matches!(
                                self.rules.classify(&self.neighbourhood(cx, cy)),
                                Verdict::Step | Verdict::NeighbourStep | Verdict::TopStep
                            )
                        {
                            self.data_mut(cx, cy).class = Class::Obstacle;
                            changed.push((cx, cy));
                        }
                    }
                    // An obstacle that free space wiped out here (its evidence gone) is judged
                    // again from what is left, but only towards traversable or unknown: far
                    // evidence does not raise obstacles (the far-step rule aside). A trail a
                    // walker left behind the robot clears this way once the robot has turned
                    // and sees through it from afar. Only the wiped cell itself: the cells
                    // beside it that were steps against it keep their close verdicts, because a
                    // grazing beam can also slip past a ramp's side face inside its boundary
                    // cell, and clearing the foot of that face would be worse than a trail's
                    // fringe (measured on `slopes`: recall 0.988 -> 0.967).
                    let again = d.class == Class::Obstacle && d.far_wiped;
                    if again {
                        let dist = self.distance_m(cx, cy, robot);
                        let nb = self.neighbourhood(cx, cy);
                        let v = self.rules.classify(&nb).class();
                        let new = match v {
                            Class::Traversable if d.headroom => Some(Class::Traversable),
                            Class::Unknown => Some(Class::Unknown),
                            _ => None,
                        };
                        if let Some(c) = new.filter(|&c| c != d.class) {
                            let dm = self.data_mut(cx, cy);
                            dm.class = c;
                            if c == Class::Traversable {
                                dm.class_range_m = dist as f32;
                            }
                            changed.push((cx, cy));
                        }
                    }
                    // Not classified out here, but its height is news for the tile.
                    refreshed.push((cx, cy));
                }
                continue;
            }
            let Some(d) = self.data(cx, cy) else { continue };
            let old = d.class;
            let new = if d.driven_free(self.cfg.stray_height_m as f32) {
                Class::Traversable
            } else {
                let nb = self.neighbourhood(cx, cy);
                let mut v = self.rules.classify(&nb).class();
                if v == Class::Traversable && !d.headroom {
                    v = Class::Overhung;
                }
                // A negative obstacle stays one until the cell is actually observed, and the lip
                // of a drop stays one while the unobserved drop beside it does.
                if old == Class::NegativeObstacle
                    && (v == Class::Unknown
                        || (v == Class::Traversable && self.beside_drop(cx, cy)))
                {
                    old
                } else {
                    v
                }
            };
            rep.classified_cells += 1;
            refreshed.push((cx, cy));
            // An obstacle judged from close by is not cleared by a verdict from much farther
            // away, where a 10 cm face is a couple of sparse returns (free space still clears
            // it: a wiped cell forgets where it was judged from).
            let dist = self.distance_m(cx, cy, robot) as f32;
            let judged_at = d.class_range_m;
            let far = dist > self.cfg.far_evidence_factor as f32 * judged_at + 1.0;
            let new = if old.is_obstacle() && !new.is_obstacle() && far {
                old
            } else {
                new
            };
            let dm = self.data_mut(cx, cy);
            dm.far_wiped = false;
            if new != old {
                dm.class = new;
                dm.class_range_m = dist;
                changed.push((cx, cy));
            } else {
                dm.class_range_m = dm.class_range_m.min(dist);
            }
        }

        // Negative obstacles (step 6b).
        changed.extend(self.negative_obstacles(robot));
        self.win.end_stats();
        rep.class_changes = changed.len();

        // Inflation and costs (step 5), around cells whose class changed.
        let g = self.win.next_generation();
        let rc = (self.cfg.cost_distance_m / l).ceil() as i64;
        let mut out_cells: Vec<(i64, i64)> = Vec::new();
        let mark = |win: &mut Window, cx: i64, cy: i64, out: &mut Vec<(i64, i64)>| {
            if let Some(i) = win.local(cx, cy) {
                if win.mark[i] != g {
                    win.mark[i] = g;
                    out.push((cx, cy));
                }
            }
        };
        if self.full {
            let h = i64::from(self.cfg.num_of_grid_cells / 2);
            for cy in rcy - h..rcy + h {
                for cx in rcx - h..rcx + h {
                    if self.data(cx, cy).is_some() {
                        mark(&mut self.win, cx, cy, &mut out_cells);
                    }
                }
            }
        } else {
            // Around each changed cell, which cells within twice the cost distance are sources,
            // looked up once: every output cell of the block finds its nearest source in that
            // map instead of looking up its own disc of neighbours.
            let w = 4 * rc + 1;
            let at = |x: i64, y: i64| ((y + 2 * rc) * w + x + 2 * rc) as usize;
            let mut src = vec![false; (w * w) as usize];
            for &(cx, cy) in &changed {
                for dy in -2 * rc..=2 * rc {
                    for dx in -2 * rc..=2 * rc {
                        src[at(dx, dy)] = self
                            .data(cx + dx, cy + dy)
                            .is_some_and(|n| self.is_source(n.class));
                    }
                }
                for dy in -rc..=rc {
                    for dx in -rc..=rc {
                        let (ox, oy) = (cx + dx, cy + dy);
                        if self.data(ox, oy).is_none() {
                            continue;
                        }
                        let Some(i) = self.win.local(ox, oy) else {
                            continue;
                        };
                        if self.win.mark[i] == g {
                            continue;
                        }
                        self.win.mark[i] = g;
                        let near = self.inflation_from(|ex, ey| src[at(dx + ex, dy + ey)]);
                        let cell = self.output_cell(ox, oy, Some(near));
                        self.write_live(ox, oy, cell);
                    }
                }
            }
        }
        for (cx, cy) in out_cells {
            let cell = self.output_cell(cx, cy, None);
            self.write_live(cx, cy, cell);
        }
        // Cells whose class and nearby sources did not change keep their state and cost; only
        // their height, hits and stamp are news. (The nearest-source search is most of the
        // output's cost, and most refreshed cells are open ground with no source in reach.)
        if !self.full {
            for (cx, cy) in refreshed {
                let Some(i) = self.win.local(cx, cy) else {
                    continue;
                };
                if self.win.mark[i] == g {
                    continue;
                }
                self.win.mark[i] = g;
                let shown = self.cell(cx, cy);
                let cell = self.output_cell(cx, cy, Some((shown.state, shown.cost)));
                self.write_live(cx, cy, cell);
            }
        }
    }

    fn is_source(&self, c: Class) -> bool {
        c.is_obstacle() || (self.cfg.inflate_undecided && c == Class::Undecided)
    }

    /// The final cell: state and cost from the class and the nearest inflation source. `kept`:
    /// the state and cost a traversable cell is to show, known already (no source near it
    /// changed since it was computed, or its nearest source was found another way).
    fn output_cell(&self, cx: i64, cy: i64, kept: Option<(CellState, u8)>) -> Cell {
        let Some(d) = self.data(cx, cy) else {
            return Cell::UNKNOWN;
        };
        let ev = d.evidence().stats();
        let height_m = if d.driven && ev.n < self.rules.min_points() {
            f64::from(d.driven_z)
        } else {
            ev.mean_m
        };
        let height_cm = (height_m * 100.0)
            .round()
            .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
        let (state, cost) = match d.class {
            Class::Unknown | Class::Undecided | Class::Overhung => return Cell::UNKNOWN,
            Class::Obstacle | Class::NegativeObstacle => (CellState::Obstacle, 255),
            Class::Traversable => match kept {
                Some(k @ (CellState::Traversable | CellState::Inflated, _)) => k,
                _ => self.inflation(cx, cy),
            },
        };
        let height_cm = if d.class == Class::NegativeObstacle && ev.n == 0 {
            0
        } else {
            height_cm
        };
        Cell {
            state,
            cost,
            height_cm,
            hits: d.hits.max(1),
            stamp_s: d.stamp_s,
        }
    }

    /// State and cost of a traversable cell from the nearest inflation source around it.
    fn inflation(&self, cx: i64, cy: i64) -> (CellState, u8) {
        self.inflation_from(|dx, dy| {
            self.data(cx + dx, cy + dy)
                .is_some_and(|n| self.is_source(n.class))
        })
    }

    /// [`Self::inflation`] with `source(dx, dy)` telling whether the cell at that offset is an
    /// inflation source.
    fn inflation_from(&self, source: impl Fn(i64, i64) -> bool) -> (CellState, u8) {
        let near = self.offsets.iter().find(|(_, dx, dy)| source(*dx, *dy));
        match near {
            Some((dist, _, _)) if *dist <= self.cfg.obstacle_distance_m + 1e-9 => {
                (CellState::Inflated, 254)
            }
            Some((dist, _, _)) => {
                let c = f64::from(self.cfg.cost_max)
                    * (-(dist - self.cfg.obstacle_distance_m) / self.cfg.cost_decay_m).exp();
                (CellState::Traversable, c.round() as u8)
            }
            None => (CellState::Traversable, 0),
        }
    }

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

    /// Unknown cells in reach of the sensor whose neighbour towards the robot is observed
    /// ground and beyond which the surface is missing or much lower: a drop-off, hole or
    /// platform edge. Returns the cells whose class changed.
    fn negative_obstacles(&mut self, robot: &RobotPose) -> Vec<(i64, i64)> {
        let l = self.cfg.grid_size_m;
        let r_min = self.cfg.blind_radius_m() + l;
        let r_max = self.cfg.negative_obstacle_distance_m;
        if r_max <= r_min {
            return Vec::new();
        }
        let tan_phi = self.cfg.phi_max_deg.to_radians().tan();
        let drop_m = self.cfg.max_step_m.max(self.cfg.h_max_m()) * 2.0;
        let beyond_cells = (3.0 / l).ceil() as i64;
        let (x0, y0) = self.lattice.cell_of(robot.x_m - r_max, robot.y_m - r_max);
        let (x1, y1) = self.lattice.cell_of(robot.x_m + r_max, robot.y_m + r_max);
        let mut changed = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let (px, py) = self.center_m(cx, cy);
                let (dx, dy) = (px - robot.x_m, py - robot.y_m);
                let dist = norm2(dx, dy);
                if dist < r_min || dist > r_max {
                    continue;
                }
                let old = self.data(cx, cy).map(|d| d.class).unwrap_or_default();
                if old != Class::Unknown && old != Class::NegativeObstacle {
                    continue;
                }
                if self
                    .data(cx, cy)
                    .is_some_and(|d| d.evidence().n > 0 || d.driven)
                {
                    continue;
                }
                let (ux, uy) = (dx / dist, dy / dist);
                // The neighbour nearest the robot must be observed, drivable ground (or the lip
                // this pass marked before: observed ground too). A neighbour, not the cell one
                // step along the ray: on an oblique ray that step often lands beside the edge.
                let is_ground = |d: &CellData| {
                    d.class == Class::Traversable
                        || (d.class == Class::NegativeObstacle && (d.evidence().n > 0 || d.driven))
                };
                let mut best: Option<(f64, i64, i64)> = None;
                for (ex, ey) in [
                    (1, 0),
                    (-1, 0),
                    (0, 1),
                    (0, -1),
                    (1, 1),
                    (1, -1),
                    (-1, 1),
                    (-1, -1),
                ] {
                    let (nx, ny) = (cx + ex, cy + ey);
                    if !self.data(nx, ny).is_some_and(is_ground) {
                        continue;
                    }
                    let (qx, qy) = self.center_m(nx, ny);
                    let dq = norm2(qx - robot.x_m, qy - robot.y_m);
                    if dq < dist && best.is_none_or(|b| dq < b.0) {
                        best = Some((dq, nx, ny));
                    }
                }
                let Some((_, bx, by)) = best else {
                    continue;
                };
                let Some(edge) = self.data(bx, by) else {
                    continue;
                };
                let edge_was_lip = edge.class == Class::NegativeObstacle;
                let h_edge = if edge.evidence().n > 0 {
                    edge.evidence().stats().mean_m
                } else {
                    f64::from(edge.driven_z)
                };
                // Walk outwards: the first observed cell beyond tells whether the surface continues.
                let mut drop = true;
                for k in 1..=beyond_cells {
                    let (qx, qy) = self
                        .lattice
                        .cell_of(px + ux * l * k as f64, py + uy * l * k as f64);
                    if let Some(q) = self
                        .data(qx, qy)
                        .filter(|q| q.evidence().n >= self.rules.min_points())
                    {
                        let h_q = q.evidence().stats().mean_m;
                        // Lower than a step plus half the steepest drivable slope over the
                        // unseen gap: a slope that steep would have been seen from here.
                        drop = h_q < h_edge - drop_m - l * (k + 1) as f64 * 0.5 * tan_phi;
                        break;
                    }
                }
                // A drop seen from close by is not undone by a look from farther away (the
                // shadow behind an edge grows with distance and blurs into a slope).
                let marked_at = self.data(cx, cy).map_or(f32::INFINITY, |d| d.neg_range_m);
                if !drop && old == Class::NegativeObstacle && dist as f32 > marked_at + 1.0 {
                    continue;
                }
                let new = if drop {
                    Class::NegativeObstacle
                } else {
                    Class::Unknown
                };
                if drop {
                    let d = self.data_mut(cx, cy);
                    d.neg_range_m = d.neg_range_m.min(dist as f32);
                } else if old == Class::NegativeObstacle {
                    self.data_mut(cx, cy).neg_range_m = f32::INFINITY;
                }
                if new != old {
                    self.data_mut(cx, cy).class = new;
                    changed.push((cx, cy));
                }
                // The edge cell holds the lip of the drop: a wheel there is over it. A lip whose
                // drop turned out to be a ring gap goes back to what its own evidence says.
                if drop {
                    let e = self.data_mut(bx, by);
                    if e.class == Class::Traversable && !e.driven {
                        e.class = Class::NegativeObstacle;
                        changed.push((bx, by));
                    }
                } else if edge_was_lip && !self.beside_drop(bx, by) {
                    let mut v = self.rules.classify(&self.neighbourhood(bx, by)).class();
                    let e = self.data_mut(bx, by);
                    if e.driven {
                        v = Class::Traversable;
                    } else if v == Class::Traversable && !e.headroom {
                        v = Class::Overhung;
                    }
                    e.class = v;
                    changed.push((bx, by));
                }
            }
        }
        changed
    }

    /// Whether a step test (profile, neighbour or top) fires at a cell because of a neighbour
    /// seen only from beyond the processing distance that lies lower than the cell: the far
    /// side of a raised edge, in the edge's shadow while the robot passed on the near side. Far
    /// views that make a neighbour look higher (grass tops at grazing angles) do not count.
    fn shadowed_step(&self, cx: i64, cy: i64, d: &CellData) -> bool {
        let pd = self.cfg.processing_distance_m as f32;
        let own = d.evidence().stats();
        let lower_far = (-1..=1)
            .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
            .any(|(dx, dy)| {
                self.data(cx + dx, cy + dy).is_some_and(|n| {
                    let e = n.evidence();
                    e.n >= self.rules.min_points()
                        && n.cur_range_m.min(n.prev_range_m) > pd
                        && e.stats().mean_m < own.mean_m - 0.5 * self.cfg.max_step_m
                })
            });
        lower_far
            && matches!(
                self.rules.classify(&self.neighbourhood(cx, cy)),
                Verdict::Step | Verdict::NeighbourStep | Verdict::TopStep
            )
    }

    /// Horizontal distance from the robot to a cell's centre, metres.
    fn distance_m(&self, cx: i64, cy: i64, robot: &RobotPose) -> f64 {
        let (px, py) = self.center_m(cx, cy);
        norm2(px - robot.x_m, py - robot.y_m)
    }

    /// True when an 8-neighbour is a drop-off without evidence enough to be observed.
    fn beside_drop(&self, cx: i64, cy: i64) -> bool {
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                (dx != 0 || dy != 0)
                    && self.data(cx + dx, cy + dy).is_some_and(|n| {
                        n.class == Class::NegativeObstacle
                            && n.evidence().n < self.rules.min_points()
                            && !n.driven
                    })
            })
        })
    }

    fn neighbourhood(&self, cx: i64, cy: i64) -> Neighbourhood {
        let mut nb = Neighbourhood::default();
        let on = self.win.stats_on;
        let g = self.win.stats_generation;
        for (y, row) in nb.iter_mut().enumerate() {
            for (x, s) in row.iter_mut().enumerate() {
                let (nx, ny) = (cx + x as i64 - 2, cy + y as i64 - 2);
                // Neighbourhoods overlap (a cell is in up to 25 of them per update): inside
                // `reclassify`, where evidence stands still, each cell's stats are computed once.
                match self.win.local(nx, ny).filter(|_| on) {
                    Some(i) => {
                        let (cg, st) = self.win.stats[i].get();
                        *s = if cg == g {
                            st
                        } else {
                            let st = self.rule_stats(nx, ny);
                            self.win.stats[i].set((g, st));
                            st
                        };
                    }
                    None => *s = self.rule_stats(nx, ny),
                }
            }
        }
        nb
    }

    /// A cell as the rules see it: its evidence's stats, the driven ground when the evidence is
    /// too thin, or only the point count.
    fn rule_stats(&self, cx: i64, cy: i64) -> CellStats {
        let min = self.rules.min_points();
        let Some(d) = self.data(cx, cy) else {
            return CellStats::default();
        };
        let st = d.evidence().stats();
        if st.n >= min {
            st
        } else if d.driven {
            CellStats {
                n: min,
                mean_m: f64::from(d.driven_z),
                var_m2: 0.0,
                max_m: f64::from(d.driven_z),
                min_m: f64::from(d.driven_z),
            }
        } else {
            CellStats {
                n: st.n,
                ..CellStats::default()
            }
        }
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
    fn refresh_ground(&mut self, cx: i64, cy: i64) {
        let min_n = self.rules.min_points();
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        if let Some(s) = self.slot(t) {
            let k = r as usize * self.lattice.tile_cells as usize + c as usize;
            let slot = &mut self.slots[s];
            slot.ground[k] = slot.data[k].ground(min_n);
        }
    }

    fn data(&self, cx: i64, cy: i64) -> Option<&CellData> {
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        let s = self.slot(t)?;
        Some(&self.slots[s].data[r as usize * self.lattice.tile_cells as usize + c as usize])
    }

    /// The slot of a tile; lookups come in runs within one tile, so the last answer is kept.
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
                    changed: false,
                });
                self.slot_of.insert(t, self.slots.len() - 1);
                self.slots.len() - 1
            }
        };
        &mut self.slots[s].data[r as usize * n + c as usize]
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

    /// The mean height of a cell's evidence (or the driven height), if any.
    pub fn height_m(&self, cx: i64, cy: i64) -> Option<f64> {
        let d = self.data(cx, cy)?;
        let e = d.evidence();
        if e.n > 0 {
            Some(e.stats().mean_m)
        } else if d.driven {
            Some(f64::from(d.driven_z))
        } else {
            None
        }
    }

    /// The current content of every tile held, sorted (version 0: versions count publications,
    /// which the publisher does).
    pub fn tiles(&self) -> Vec<Tile> {
        let mut v: Vec<Tile> = self
            .slots
            .iter()
            .map(|s| Tile {
                index: s.index,
                lattice: self.lattice,
                version: 0,
                cells: s.live.clone(),
            })
            .collect();
        v.sort_by_key(|t| t.index);
        v
    }

    /// The current output cells of one tile (row-major, row 0 southmost), if the tile is held.
    pub fn tile_cells(&self, index: TileIndex) -> Option<&[Cell]> {
        self.slot(index).map(|s| self.slots[s].live.as_slice())
    }

    /// The planner's window (`num_of_grid_cells` square) centred on the last robot pose.
    pub fn planner_view(&self) -> PlannerView {
        let w = self.cfg.num_of_grid_cells;
        let r = self.robot.unwrap_or_default();
        let (cx, cy) = self.lattice.cell_of(r.x_m, r.y_m);
        self.view(cx - i64::from(w / 2), cy - i64::from(w / 2), w, w)
    }

    /// Any window of final cells.
    pub fn view(&self, min_cx: i64, min_cy: i64, width: u32, height: u32) -> PlannerView {
        let mut cells = Vec::with_capacity(width as usize * height as usize);
        for y in 0..i64::from(height) {
            for x in 0..i64::from(width) {
                cells.push(self.cell(min_cx + x, min_cy + y));
            }
        }
        PlannerView {
            lattice: self.lattice,
            min_cx,
            min_cy,
            width,
            height,
            cells,
        }
    }

    /// Global cell index bounds (min, max inclusive) of all tiles held, if any.
    pub fn bounds(&self) -> Option<((i64, i64), (i64, i64))> {
        let n = i64::from(self.lattice.tile_cells);
        let mut it = self
            .slots
            .iter()
            .map(|s| self.lattice.tile_first_cell(s.index));
        let first = it.next()?;
        let (mut lo, mut hi) = (first, first);
        for (x, y) in it {
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        Some((lo, (hi.0 + n - 1, hi.1 + n - 1)))
    }
}

impl Mapper {
    /// The rule that decides a cell now (diagnostics: why is this cell an obstacle?).
    pub fn explain(&self, cx: i64, cy: i64) -> crate::classify::Verdict {
        self.rules.classify(&self.neighbourhood(cx, cy))
    }

    /// Lowest and highest point of a cell's current evidence, metres (None: no returns).
    pub fn height_range(&self, cx: i64, cy: i64) -> Option<(f32, f32)> {
        let e = self.data(cx, cy)?.evidence();
        (e.n > 0).then_some((e.zmin, e.zmax))
    }

    /// One line on why a cell is what it is (logs and diagnostics): class, the rules' verdict
    /// now, both evidence epochs, proprioception, last change.
    pub fn describe(&self, cx: i64, cy: i64) -> String {
        let Some(d) = self.data(cx, cy) else {
            return format!("cell ({cx}, {cy}) never observed");
        };
        let ep = |m: &Moments| {
            let s = m.stats();
            if m.n == 0 {
                "-".to_string()
            } else {
                format!(
                    "n {} mean {:.3} sd {:.3} [{:.3}, {:.3}]",
                    m.n,
                    s.mean_m,
                    s.var_m2.sqrt(),
                    m.zmin,
                    m.zmax
                )
            }
        };
        format!(
            "cell ({cx}, {cy}) {:?} (rules now: {:?}); cur {} from {:.1} m | prev {} from {:.1} m; headroom {}; driven {} at {:.3}; changed {} s; judged from {:.1} m",
            d.class,
            self.explain(cx, cy),
            ep(&d.cur),
            d.cur_range_m,
            ep(&d.prev),
            d.prev_range_m,
            d.headroom,
            d.driven,
            d.driven_z,
            d.stamp_s,
            d.class_range_m
        )
    }

    /// Height statistics of one cell's current evidence (n = 0: none).
    pub fn height_stats(&self, cx: i64, cy: i64) -> CellStats {
        self.data(cx, cy)
            .map(|d| d.evidence().stats())
            .unwrap_or_default()
    }

    /// Height statistics of a cell's newest evidence epoch alone (`evidence_epoch_s` long):
    /// what the sensor saw there most recently.
    pub fn newest_height_stats(&self, cx: i64, cy: i64) -> CellStats {
        self.data(cx, cy).map(|d| d.cur.stats()).unwrap_or_default()
    }
}
