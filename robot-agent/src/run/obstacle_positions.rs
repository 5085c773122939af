//! Where the map put the world's upright obstacles (poles and tree trunks) against where they
//! are: the measure of issue 18's loop scenario (`robot-agent map eval`, `obstacle_positions`).
//!
//! For each true pole or trunk, the mapped obstacle cells (class before inflation) whose centres
//! lie within `SEARCH_M` of its surface and nearer to it than to any other solid of the world
//! (another pole or trunk, a wall, a box, a car) are its cells; the error is the distance from their centroid to the true centre. A thin post seen
//! from one side has its cells on that side, so even a perfect map has an error of up to about
//! the radius plus half a cell: the truth-pose run gives that floor. An object with no cell is
//! counted as not found (not seen, or drifted further than the search reach).
//!
//! Most of those cells are not the object's: the step rule marks both sides of a step, so a
//! trunk of three cells comes with a ring of ground cells around it, and the ring is only as
//! complete as the ground around the trunk was seen (a side seen by few sweeps stays unknown
//! and the centroid moves away from it). The body score ([`ObstaclePositions::body`]) takes
//! only the raised cells: obstacle cells whose mean height stands more than the step rule's
//! `h_max` above their lowest observed 8-neighbour, which is where the object's returns are.

use mapping::{Class, Mapper};
use serde::Serialize;
use sim::world::{Shape, Solid, SolidKind};

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
    /// The same scores over the raised cells only (the objects' own returns, without the
    /// ground ring the step rule marks around them).
    pub body: BodyPositions,
}

/// Centroid errors over each object's raised obstacle cells (see the module docs).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct BodyPositions {
    /// Objects with a raised cell within the search reach.
    pub found: usize,
    /// Mean centroid error over the found ones, metres.
    pub mean_error_m: f64,
    /// Median centroid error, metres.
    pub median_error_m: f64,
    /// Largest centroid error, metres.
    pub max_error_m: f64,
    /// Per found object: x, y (truth, metres), centroid error (metres), cells.
    pub per_object: Vec<(f64, f64, f64, usize)>,
}

/// Mean, median and largest of some errors (zeros when there are none).
fn summary(errors: &mut [f64]) -> (f64, f64, f64) {
    if errors.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    errors.sort_by(f64::total_cmp);
    (mean, errors[errors.len() / 2], errors[errors.len() - 1])
}

/// The cell stands more than `h_max_m` above its lowest observed 8-neighbour.
fn raised(mapper: &Mapper, cx: i64, cy: i64, h_max_m: f64) -> bool {
    let Some(h) = mapper.height_m(cx, cy) else {
        return false;
    };
    (-1..=1)
        .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
        .filter(|&d| d != (0, 0))
        .filter_map(|(dx, dy)| mapper.height_m(cx + dx, cy + dy))
        .any(|n| h - n > h_max_m)
}

/// One pole or trunk and the map's cells that are taken for it.
struct ObjectCells {
    /// True centre, metres.
    centre: (f64, f64),
    /// Sum of x, y and surface distance over its obstacle cells, and their count.
    all: (f64, f64, f64, usize),
    /// Sum of x, y over its raised cells, and their count.
    raised: (f64, f64, usize),
}

impl ObjectCells {
    fn centroid(&self) -> Option<(f64, f64)> {
        let (sx, sy, _, n) = self.all;
        (n > 0).then(|| (sx / n as f64, sy / n as f64))
    }

    fn raised_centroid(&self) -> Option<(f64, f64)> {
        let (sx, sy, n) = self.raised;
        (n > 0).then(|| (sx / n as f64, sy / n as f64))
    }
}

/// The world's poles and trunks with the mapper's cells for each (see the module docs).
fn object_cells(mapper: &Mapper, world: &sim::World) -> Vec<ObjectCells> {
    // Canopies hang above the robot: their cells are the trunks' or the ground's.
    let solids: Vec<&Solid> = world
        .solids()
        .iter()
        .filter(|s| s.kind != SolidKind::Canopy)
        .collect();
    let lattice = mapper.lattice();
    let h_max_m = mapper.config().h_max_m();
    let mut out = Vec::new();
    for (k, s) in solids.iter().enumerate() {
        let (SolidKind::Pole | SolidKind::Trunk, Shape::Cylinder { cx: ox, cy: oy, r }) =
            (s.kind, s.shape)
        else {
            continue;
        };
        let mut o = ObjectCells {
            centre: (ox, oy),
            all: (0.0, 0.0, 0.0, 0),
            raised: (0.0, 0.0, 0),
        };
        let reach = r + SEARCH_M;
        let (c0x, c0y) = lattice.cell_of(ox - reach, oy - reach);
        let (c1x, c1y) = lattice.cell_of(ox + reach, oy + reach);
        for cy in c0y..=c1y {
            for cx in c0x..=c1x {
                if !matches!(mapper.class(cx, cy), Class::Obstacle) {
                    continue;
                }
                let (x, y) = lattice.cell_center_m(cx, cy);
                let d = ((x - ox).hypot(y - oy) - r).max(0.0);
                if d > SEARCH_M {
                    continue;
                }
                let nearest = solids
                    .iter()
                    .enumerate()
                    .all(|(j, o)| j == k || o.footprint_distance(x, y) >= d);
                if nearest {
                    let a = &mut o.all;
                    a.0 += x;
                    a.1 += y;
                    a.2 += d;
                    a.3 += 1;
                    if raised(mapper, cx, cy, h_max_m) {
                        let b = &mut o.raised;
                        b.0 += x;
                        b.1 += y;
                        b.2 += 1;
                    }
                }
            }
        }
        out.push(o);
    }
    out
}

/// Scores the mapper's obstacle cells against the world's poles and trunks.
pub fn score(mapper: &Mapper, world: &sim::World) -> ObstaclePositions {
    let objects = object_cells(mapper, world);
    let mut out = ObstaclePositions {
        objects: objects.len(),
        ..Default::default()
    };
    let mut errors = Vec::new();
    let mut surface_sum = 0.0;
    let mut cells = 0usize;
    for o in &objects {
        let Some((x, y)) = o.centroid() else {
            continue;
        };
        let (ox, oy) = o.centre;
        let e = (x - ox).hypot(y - oy);
        errors.push(e);
        surface_sum += o.all.2;
        cells += o.all.3;
        out.per_object.push((ox, oy, e, o.all.3));
    }
    out.found = errors.len();
    if !errors.is_empty() {
        (out.mean_error_m, out.median_error_m, out.max_error_m) = summary(&mut errors);
        out.mean_surface_distance_m = surface_sum / cells as f64;
    }
    let mut errors = Vec::new();
    for o in &objects {
        if let Some((x, y)) = o.raised_centroid() {
            let (ox, oy) = o.centre;
            let e = (x - ox).hypot(y - oy);
            errors.push(e);
            out.body.per_object.push((ox, oy, e, o.raised.2));
        }
    }
    out.body.found = errors.len();
    (
        out.body.mean_error_m,
        out.body.median_error_m,
        out.body.max_error_m,
    ) = summary(&mut errors);
    out
}

/// How far each pole or trunk lies from where a reference map of the same sweeps puts it.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct ObstacleShifts {
    /// Over all obstacle cells.
    #[serde(flatten)]
    pub all: Shifts,
    /// The same over the raised cells only.
    pub body: Shifts,
}

/// Distances between two maps' centroids of the same objects' cells.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Shifts {
    /// Objects with cells in both maps.
    pub compared: usize,
    /// Mean shift, metres.
    pub mean_shift_m: f64,
    /// Median shift, metres.
    pub median_shift_m: f64,
    /// Largest shift, metres.
    pub max_shift_m: f64,
    /// Per compared object: x, y (truth, metres), shift (metres).
    pub per_object: Vec<(f64, f64, f64)>,
}

impl Shifts {
    /// The shifts of the objects both centroids are given for (`centroids` yields the true
    /// centre and the two maps' centroids).
    fn of(
        centroids: impl Iterator<Item = ((f64, f64), Option<(f64, f64)>, Option<(f64, f64)>)>,
    ) -> Self {
        let per_object: Vec<(f64, f64, f64)> = centroids
            .filter_map(|((ox, oy), p, q)| {
                let (p, q) = (p?, q?);
                Some((ox, oy, (p.0 - q.0).hypot(p.1 - q.1)))
            })
            .collect();
        let mut d: Vec<f64> = per_object.iter().map(|o| o.2).collect();
        let (mean_shift_m, median_shift_m, max_shift_m) = summary(&mut d);
        Self {
            compared: per_object.len(),
            mean_shift_m,
            median_shift_m,
            max_shift_m,
            per_object,
        }
    }
}

/// Per pole and trunk, the distance between where `mapper` and `reference` put its cells.
///
/// With `reference` the same sweeps mapped at the true poses (`map eval --truth-twin`), the
/// sensor, the views and the mapping are the same on both sides: what differs is the pose each
/// sweep was mapped at, so this is the localisation's share of [`score`]'s error, without the
/// floor a one-sided view puts under a centroid's distance from the true centre.
pub fn shifts(mapper: &Mapper, reference: &Mapper, world: &sim::World) -> ObstacleShifts {
    let ours = object_cells(mapper, world);
    let theirs = object_cells(reference, world);
    let pairs = || ours.iter().zip(&theirs);
    ObstacleShifts {
        all: Shifts::of(pairs().map(|(a, b)| (a.centre, a.centroid(), b.centroid()))),
        body: Shifts::of(
            pairs().map(|(a, b)| (a.centre, a.raised_centroid(), b.raised_centroid())),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapping::synth::{cast_scan, LidarSpec, Rng};
    use mapping::{Config, RobotPose};

    /// Flat ground with a trunk of radius 0.2 m at (6, 0) and, with `with_box`, a 1 m box
    /// 0.4 m east of the trunk's surface.
    fn world(x: f64, y: f64, with_box: bool) -> f64 {
        if (x - 6.0).hypot(y) < 0.2 {
            2.0
        } else if with_box && (6.6..=8.0).contains(&x) && y.abs() <= 1.0 {
            1.0
        } else {
            0.0
        }
    }

    /// The trunk mapped from sweeps taken along y = 4 m from x = 2 to 10 m.
    fn mapped(with_box: bool) -> Mapper {
        mapped_off(with_box, 0.0)
    }

    /// As [`mapped`], every sweep mapped `dx_m` east of where it was taken (a pose error).
    fn mapped_off(with_box: bool, dx_m: f64) -> Mapper {
        let spec = LidarSpec {
            az_step_deg: 0.2,
            max_range_m: 20.0,
            ..LidarSpec::vlp16()
        };
        let mut m = Mapper::new(Config::default()).unwrap();
        let mut rng = Rng::new(5);
        let height = |x: f64, y: f64| world(x, y, with_box);
        for i in 0..17 {
            let x = 2.0 + 0.5 * f64::from(i);
            let pts = cast_scan(&height, [x, 4.0, 0.7], &spec, &mut rng)
                .into_iter()
                .map(|p| [p[0] + dx_m as f32, p[1], p[2]])
                .collect();
            let x = x + dx_m;
            let robot = RobotPose {
                x_m: x,
                y_m: 4.0,
                z_m: 0.0,
                yaw_rad: 0.0,
            };
            m.update_sweep(pts, [x, 4.0, 0.7], &robot, 1.0 + 0.1 * f64::from(i))
                .unwrap();
        }
        m
    }

    /// The world of the trunk at `x_m` (and the box when `with_box`) as the scorer sees it.
    fn truth(x_m: f64, with_box: bool) -> sim::World {
        let mut text = format!(
            "name = \"trunk\"\n[datum]\nlat_deg = 50.0\nlon_deg = 14.0\nh_m = 200.0\n\
             [extent]\nx_min_m = -20.0\nx_max_m = 20.0\ny_min_m = -20.0\ny_max_m = 20.0\n\
             [[pole]]\nx_m = {x_m}\ny_m = 0.0\nradius_m = 0.2\nheight_m = 2.0\n"
        );
        if with_box {
            text.push_str(
                "[[box]]\nrect = { center_m = [7.3, 0.0], size_m = [1.4, 2.0], yaw_deg = 0 }\nheight_m = 1.0\n",
            );
        }
        sim::World::new(&sim::Scenario::from_toml_str(&text, "test").unwrap())
    }

    #[test]
    fn the_body_score_finds_a_trunk_where_its_ring_is_one_sided() {
        let map = mapped(false);
        let o = score(&map, &truth(6.0, false));
        assert_eq!((o.objects, o.found, o.body.found), (1, 1, 1), "{o:?}");
        // Seen from one side, the body's cells are the trunk's near half: within the radius
        // and half a cell of the centre.
        assert!(o.body.max_error_m <= 0.2 + 0.1 + 1e-9, "{o:?}");
        assert!(
            o.body.per_object[0].3 < o.per_object[0].3,
            "fewer cells: {o:?}"
        );
        // Moved by 0.5 m, the map's trunk scores the move, whichever cells are counted.
        let moved = score(&map, &truth(6.5, false));
        assert!(moved.body.max_error_m > 0.3, "{moved:?}");
        assert!(moved.max_error_m > 0.3, "{moved:?}");
    }

    #[test]
    fn cells_nearer_another_solid_are_not_the_trunks() {
        let map = mapped(true);
        // A scorer blind to the box takes the box's west face for the trunk's.
        let blind = score(&map, &truth(6.0, false));
        let o = score(&map, &truth(6.0, true));
        assert!(o.per_object[0].3 < blind.per_object[0].3, "{o:?} {blind:?}");
        assert!(o.max_error_m < blind.max_error_m, "{o:?} {blind:?}");
        assert!(o.body.max_error_m <= 0.2 + 0.1 + 1e-9, "{o:?}");
    }

    #[test]
    fn shifts_against_a_map_of_the_same_sweeps_are_the_pose_error() {
        let world = truth(6.0, false);
        let right = mapped(false);
        let same = shifts(&right, &right, &world);
        assert_eq!((same.all.compared, same.body.compared), (1, 1), "{same:?}");
        assert_eq!((same.all.max_shift_m, same.body.max_shift_m), (0.0, 0.0));
        // Every sweep 0.4 m (two cells) east: the trunk's cells move with them, and the shift
        // says so while the centroid's distance from the centre mixes it with the view.
        let off = mapped_off(false, 0.4);
        let s = shifts(&off, &right, &world);
        assert!((s.body.max_shift_m - 0.4).abs() <= 0.1, "{s:?}");
        assert!((s.all.max_shift_m - 0.4).abs() <= 0.1, "{s:?}");
    }
}
