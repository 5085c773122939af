//! Where the map put the world's upright obstacles (poles and tree trunks) against where they
//! are: the measure of issue 18's loop scenario (`robot-agent map eval`, `obstacle_positions`).
//!
//! For each true pole or trunk, the mapped obstacle cells (class before inflation) whose centres
//! lie within `SEARCH_M` of its surface and nearer to it than to any other pole or trunk are its
//! cells; the error is the distance from their centroid to the true centre. A thin post seen
//! from one side has its cells on that side, so even a perfect map has an error of up to about
//! the radius plus half a cell: the truth-pose run gives that floor. An object with no cell is
//! counted as not found (not seen, or drifted further than the search reach).

use mapping::{Class, Mapper};
use serde::Serialize;

/// Cells this far outside an object's surface still count as its cells, metres: beyond the
/// few decimetres of a good map's blur, short of the gaps between neighbouring objects.
const SEARCH_M: f64 = 1.0;

/// The obstacle-position scores.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct ObstaclePositions {
    /// Poles and trunks in the world.
    pub objects: usize,
    /// Of them, with mapped obstacle cells within the search reach.
    pub found: usize,
    /// Mean centroid error over the found ones, metres.
    pub mean_error_m: f64,
    /// Median centroid error, metres.
    pub median_error_m: f64,
    /// Largest centroid error, metres.
    pub max_error_m: f64,
    /// Mean distance of the objects' cell centres from the true surface, metres.
    pub mean_surface_distance_m: f64,
    /// Per found object: x, y (truth, metres), centroid error (metres), cells.
    pub per_object: Vec<(f64, f64, f64, usize)>,
}

/// Scores the mapper's obstacle cells against the scenario's poles and trunks.
pub fn score(mapper: &Mapper, scenario: &sim::Scenario) -> ObstaclePositions {
    let objects: Vec<(f64, f64, f64)> = scenario
        .pole
        .iter()
        .map(|p| (p.x_m, p.y_m, p.radius_m))
        .chain(
            scenario
                .tree
                .iter()
                .map(|t| (t.x_m, t.y_m, t.trunk_radius_m)),
        )
        .collect();
    let mut out = ObstaclePositions {
        objects: objects.len(),
        ..Default::default()
    };
    let lattice = mapper.lattice();
    // Per object: sum of x, y, surface distance, count.
    let mut acc = vec![(0.0, 0.0, 0.0, 0usize); objects.len()];
    for (i, &(ox, oy, r)) in objects.iter().enumerate() {
        let reach = r + SEARCH_M;
        let (c0x, c0y) = lattice.cell_of(ox - reach, oy - reach);
        let (c1x, c1y) = lattice.cell_of(ox + reach, oy + reach);
        for cy in c0y..=c1y {
            for cx in c0x..=c1x {
                if !matches!(mapper.class(cx, cy), Class::Obstacle) {
                    continue;
                }
                let (x, y) = lattice.cell_center_m(cx, cy);
                let surface =
                    |(px, py, pr): (f64, f64, f64)| ((x - px).hypot(y - py) - pr).max(0.0);
                let d = surface((ox, oy, r));
                if d > SEARCH_M {
                    continue;
                }
                let nearest = objects
                    .iter()
                    .enumerate()
                    .all(|(j, &o)| j == i || surface(o) >= d);
                if nearest {
                    let a = &mut acc[i];
                    a.0 += x;
                    a.1 += y;
                    a.2 += d;
                    a.3 += 1;
                }
            }
        }
    }
    let mut errors = Vec::new();
    let mut surface_sum = 0.0;
    let mut cells = 0usize;
    for (&(ox, oy, _), &(sx, sy, sd, n)) in objects.iter().zip(&acc) {
        if n == 0 {
            continue;
        }
        let e = (sx / n as f64 - ox).hypot(sy / n as f64 - oy);
        errors.push(e);
        surface_sum += sd;
        cells += n;
        out.per_object.push((ox, oy, e, n));
    }
    out.found = errors.len();
    if !errors.is_empty() {
        out.mean_error_m = errors.iter().sum::<f64>() / errors.len() as f64;
        out.max_error_m = errors.iter().copied().fold(0.0, f64::max);
        errors.sort_by(f64::total_cmp);
        out.median_error_m = errors[errors.len() / 2];
        out.mean_surface_distance_m = surface_sum / cells as f64;
    }
    out
}
