//! What `robot-agent map eval` reports: the scores, the height and pose-graph diagnostics and the
//! progress line of one evaluation run.

use serde::Serialize;

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
    /// Cells whose evidence a lower ceiling dropped (a canopy taken in before its ground was
    /// seen), over the run.
    pub ceiling_wiped_cells: usize,
    /// Mean wall-clock time of one sweep through the agent (localisation and mapping; mapping
    /// alone with truth poses), milliseconds.
    pub ms_per_update: f64,
    /// Worst sweep, milliseconds.
    pub ms_max: f64,
    /// Sweeps mapped.
    pub scans: usize,
    /// Simulated seconds.
    pub duration_s: f64,
    /// Of it, how long the robot stood still after the drive for a map rebuild to land,
    /// seconds.
    pub settle_s: f64,
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
    /// Whether the sweeps were mapped at the simulator's true poses (the upper bound) rather
    /// than at the agent's own.
    pub truth_poses: bool,
    /// SLAM fell back to its prior (0 with truth poses).
    pub slam_failures: usize,
    /// Largest horizontal error of the agent's pose over the run, metres (0 with truth poses).
    pub slam_max_error_m: f64,
    /// Largest height error of the agent's pose, metres.
    pub slam_max_z_error_m: f64,
    /// Largest tilt error of the agent's pose (angle between estimated and true up axes), degrees.
    pub slam_max_tilt_error_deg: f64,
    /// Mean tilt error, degrees.
    pub slam_mean_tilt_error_deg: f64,
    /// Where height errors come from: the agent's pose against the truth per sweep, and the
    /// map's heights against the world's.
    pub heights: HeightDiagnostics,
    /// Sweeps left out of the map because their pose was not trusted.
    pub scans_not_mapped: u64,
    /// Collisions of the scripted drive (the drive should have none).
    pub collisions: usize,
    /// [`common::grid::map_digest`] of the final map: equal digests, equal maps.
    pub map_digest: String,
    /// Wrong cells by kind: missed obstacles by truth reason, false obstacles by mapper class.
    pub errors: ErrorCounts,
    /// Where the map put the world's poles and tree trunks against the truth.
    pub obstacle_positions: crate::run::obstacle_positions::ObstaclePositions,
    /// With `--truth-twin`: where the map puts the poles and trunks against the map of the
    /// same sweeps at their true poses (the localisation's share of the position error).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub obstacle_shifts: Option<crate::run::obstacle_positions::ObstacleShifts>,
    /// The pose graph's work (zero when `[graph] enabled` is false): keyframes, GNSS factors,
    /// loops, optimisations, map rebuilds and the sweeps kept for them.
    pub graph: GraphReport,
    /// The graph's keyframes against the truth: live pose when made, graph pose at the end.
    pub graph_keyframes: crate::run::graph_eval::GraphKeyframes,
    /// With `--rebuild-check`: the kept sweeps mapped again at the poses the final map has
    /// them at, scored like the map (what a rebuild loses without any correction).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rebuild_check: Option<RebuildCheck>,
    /// The wrong cells themselves (global lattice index, kind), for drawing.
    #[serde(skip)]
    pub error_cells: Vec<(i64, i64, ErrorKind)>,
}

/// Percentiles of one error, in the report's units.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct Percentiles {
    /// Values measured.
    pub n: usize,
    /// 1st percentile.
    pub p1: f64,
    /// 5th percentile.
    pub p5: f64,
    /// Median.
    pub p50: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Percentiles {
    /// The percentiles of `v` (sorted in place); all zero when empty.
    pub fn of(v: &mut [f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Self {
            n: v.len(),
            p1: at(0.01),
            p5: at(0.05),
            p50: at(0.5),
            p95: at(0.95),
            p99: at(0.99),
            max: v[v.len() - 1],
        }
    }
}

/// Height errors of a run: what a false or missed curb can come from.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct HeightDiagnostics {
    /// The agent's pose height minus the true height after each sweep, metres (empty with
    /// truth poses). A constant offset is harmless; its spread between passes is not.
    pub pose_z_error_m: Percentiles,
    /// Angle between the agent's and the true up axis after each sweep, degrees.
    pub pose_tilt_error_deg: Percentiles,
    /// Over scored flat cells (truth step under 2 cm, slope under 3 deg): the cell's mean
    /// height minus the truth's, metres (grass lifts the mean by about half its height).
    pub cell_height_error_m: Percentiles,
    /// Over 4-neighbour pairs of those cells: the difference of their height errors, metres:
    /// what a step rule reads as a step that is not there (or adds to one that is).
    pub neighbour_error_m: Percentiles,
}

/// The pose graph's counters over a run.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct GraphReport {
    /// Keyframes made.
    pub keyframes: usize,
    /// GNSS factors.
    pub gnss_factors: usize,
    /// Gravity factors.
    pub gravity_factors: usize,
    /// Loops accepted.
    pub loops: usize,
    /// Optimisations.
    pub optimisations: usize,
    /// Terrain map rebuilds after them.
    pub map_rebuilds: u64,
    /// Sweeps kept for rebuilding at the end.
    pub kept_sweeps: usize,
    /// Megabytes (10^6 bytes) the kept sweeps hold at the end.
    pub kept_mb: f64,
    /// Sweeps dropped from the store to stay under `map_rebuild_max_mb`.
    pub kept_dropped: u64,
    /// Loop searches per outcome: no usable descriptor, no candidate close enough, ICP failed,
    /// ICP fit too poor, fit but further than the graph can have drifted.
    pub loop_rejections: [usize; 5],
}

/// The final map's kept sweeps mapped again at unchanged poses, scored.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct RebuildCheck {
    /// Share of scored cells whose class matches the truth.
    pub accuracy: f64,
    /// Share of observed truth-traversable cells marked obstacles.
    pub false_obstacle_rate: f64,
    /// Share of observed truth obstacles marked obstacles.
    pub obstacle_recall: f64,
    /// Poles and trunks in that map.
    pub obstacle_positions: crate::run::obstacle_positions::ObstaclePositions,
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
