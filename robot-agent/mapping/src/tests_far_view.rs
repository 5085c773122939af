//! The far-view rule (docs/algorithms.md §4.3) on hand-made sweeps: a close view is kept against
//! a far glimpse of a known step's face, and something that appears after the close view is still
//! picked up from afar.

use crate::synth::lattice_points;
use crate::{Class, Config, Evidence, Mapper, RobotPose};

/// Ground at z = 0 with a 10 cm strip for y in [0, 1) m, over x in [-2, 2), y in [-2, 2) m,
/// sampled every `step_m` (points offset half a step so none lies on a cell edge).
fn strip_points(step_m: f64) -> Vec<[f32; 3]> {
    let n = (4.0 / step_m).round() as usize;
    let first = -2.0 + 0.5 * step_m;
    lattice_points([first, first], step_m, [n, n], |_, y| {
        if (0.0..1.0).contains(&y) {
            0.1
        } else {
            0.0
        }
    })
}

fn robot_at(x_m: f64, y_m: f64) -> RobotPose {
    RobotPose {
        x_m,
        y_m,
        z_m: 0.0,
        yaw_rad: std::f64::consts::FRAC_PI_2,
    }
}

/// A mapper that has seen the strip from 2.5 m (every 5 cm), at t = 0 s.
fn seen_close() -> Mapper {
    let mut m = Mapper::new(Config::default()).unwrap();
    m.update_points(
        strip_points(0.05),
        &robot_at(0.0, -2.5),
        0.0,
        Evidence::Scan,
    )
    .unwrap();
    m
}

/// A few returns off the strip's face, 9 cm up, landing just in front of it (y = -2 cm).
fn add_face_glimpse(pts: &mut Vec<[f32; 3]>) {
    for x in [0.03, 0.08, 0.13, 0.18] {
        pts.push([x, -0.02, 0.09]);
    }
}

/// Seen from 2.5 m, then from 13 m with a few returns off the strip's face landing in the cells
/// in front of it (what a few centimetres of pose or beam offset do at that range): the close
/// view of those cells is kept, because the face stands no higher than the strip the cells'
/// neighbours already hold.
#[test]
fn a_far_glimpse_of_a_known_faces_returns_does_not_replace_a_close_view() {
    let mut m = seen_close();
    let front = m.lattice().cell_of(0.1, -0.1);
    let (_, top) = m.height_range(front.0, front.1).unwrap();
    assert!(top < 0.02, "the close view's front cell top {top}");

    let mut far = strip_points(0.1);
    add_face_glimpse(&mut far);
    let rep = m
        .update_points(far, &robot_at(0.0, -13.0), 5.0, Evidence::Scan)
        .unwrap();
    assert!(rep.far_skipped > 0, "{rep:?}");
    let (_, top) = m.height_range(front.0, front.1).unwrap();
    assert!(
        top < 0.02,
        "the far glimpse of the face replaced the close view: {}",
        m.describe(front.0, front.1)
    );
}

/// The same far glimpse at the end of a steady drive away (one sweep per second, each its own
/// evidence epoch, from 2.5 m out to 13 m): the close view is still the yardstick, not the
/// epochs the drive left behind, each a metre farther than the one before.
#[test]
fn a_close_view_does_not_creep_out_with_the_robot_driving_away() {
    let mut m = Mapper::new(Config::default()).unwrap();
    let front = m.lattice().cell_of(0.1, -0.1);
    for k in 0..=10 {
        let y = -2.5 - f64::from(k) * 1.05;
        let mut pts = strip_points(if k == 0 { 0.05 } else { 0.1 });
        if k >= 8 {
            add_face_glimpse(&mut pts);
        }
        m.update_points(pts, &robot_at(0.0, y), f64::from(k), Evidence::Scan)
            .unwrap();
    }
    let (_, top) = m.height_range(front.0, front.1).unwrap();
    assert!(
        top < 0.02,
        "the close view crept out and the far glimpse replaced it: {}",
        m.describe(front.0, front.1)
    );
}

/// Seen empty from 2.5 m, then from 11 m (still within the processing distance, far beyond the
/// close view): a 0.6 m tall thing (a person, a bag) that appears a metre in front of the strip
/// after the close view stands above anything its neighbourhood held, so it is news and becomes
/// an obstacle although it is only seen from afar.
#[test]
fn something_appearing_after_the_close_view_is_picked_up_from_afar() {
    let mut m = seen_close();
    let cell = m.lattice().cell_of(1.1, -1.1);
    assert_eq!(m.class(cell.0, cell.1), Class::Traversable);

    // The same ground from afar: nothing new, the close view stays.
    let rep = m
        .update_points(
            strip_points(0.1),
            &robot_at(0.0, -11.0),
            4.0,
            Evidence::Scan,
        )
        .unwrap();
    assert!(rep.far_skipped > 0, "{rep:?}");
    assert_eq!(m.class(cell.0, cell.1), Class::Traversable);

    // Then something stands in the cell, seen in two sweeps (a single sweep's high points are
    // held back as possible strays).
    let mut thing = strip_points(0.1);
    for k in 0..11 {
        for (dx, dy) in [(0.03, 0.03), (0.1, 0.03), (0.17, 0.03), (0.1, 0.1)] {
            thing.push([(1.0 + dx) as f32, (-1.2 + dy) as f32, 0.1 + 0.05 * k as f32]);
        }
    }
    for t in [5.0, 5.1] {
        m.update_points(thing.clone(), &robot_at(0.0, -11.0), t, Evidence::Scan)
            .unwrap();
    }
    assert!(
        m.class(cell.0, cell.1).is_obstacle(),
        "not picked up from afar: {}",
        m.describe(cell.0, cell.1)
    );
}

/// The column x in [0.4, 0.8) m of the patch the far-then-close tests use.
fn in_column(x: f64) -> bool {
    (0.4..0.8).contains(&x)
}

/// A mapper that saw the patch every 10 cm from 22-26 m at t = 0 s with the column at
/// `column_z_m` and the rest at 0, then every 5 cm from 4-8 m at t = 5 s all flat at 0; and the
/// second update's report.
fn column_seen_far_then_flat_close(column_z_m: f64) -> (Mapper, crate::UpdateReport) {
    let mut m = Mapper::new(Config::default()).unwrap();
    let far = lattice_points([-1.95, -1.95], 0.1, [40, 40], |x, _| {
        if in_column(x) {
            column_z_m
        } else {
            0.0
        }
    });
    m.update_points(far, &robot_at(0.0, -24.0), 0.0, Evidence::Scan)
        .unwrap();
    let flat = lattice_points([-1.975, -1.975], 0.05, [80, 80], |_, _| 0.0);
    let rep = m
        .update_points(flat, &robot_at(0.0, -6.0), 5.0, Evidence::Scan)
        .unwrap();
    (m, rep)
}

/// Obstacle cells over the patch, and the lowest return in the column's cells, after a first
/// view from 22-26 m that puts the column 10 cm low (that range's attitude error), then a view
/// from 4-8 m 5 s later that shows it all flat; and how many far epochs gave way.
fn after_far_then_close_view() -> (usize, f32, usize) {
    let (m, rep) = column_seen_far_then_flat_close(-0.1);
    let mut obstacles = 0;
    let mut lowest = f32::INFINITY;
    let (c0, c1) = (
        m.lattice().cell_of(-1.9, -1.9),
        m.lattice().cell_of(1.9, 1.9),
    );
    for cy in c0.1..=c1.1 {
        for cx in c0.0..=c1.0 {
            obstacles += usize::from(m.class(cx, cy) == Class::Obstacle);
            let x = (cx as f64 + 0.5) * m.lattice().cell_size_f64();
            if in_column(x) {
                lowest = lowest.min(m.height_range(cx, cy).unwrap().0);
            }
        }
    }
    (obstacles, lowest, rep.far_superseded)
}

/// The far-view rule's mirror: an epoch seen only from afar gives way to a much closer one once
/// that holds enough returns, instead of setting the cell's ground beside neighbours seen from
/// close by (the lowest return is the ground).
#[test]
fn a_close_view_replaces_an_older_epoch_seen_only_from_afar() {
    let (obstacles, lowest, superseded) = after_far_then_close_view();
    assert!(
        lowest > -0.02,
        "the column's lowest return {lowest:.3} m is the far view's"
    );
    assert_eq!(obstacles, 0, "obstacle cells on flat ground");
    assert!(superseded > 0, "no far epoch counted as given way");
}

/// A far epoch that stands apart from the close view by more than a far view's attitude error
/// explains (20 cm at 24 m: an object's top, beside which a grazing close view sees only ground)
/// is not dropped for the closer view.
#[test]
fn a_far_epoch_apart_beyond_attitude_error_is_kept_against_a_closer_view() {
    let (m, _) = column_seen_far_then_flat_close(0.2);
    let (cx, cy) = m.lattice().cell_of(0.6, 0.0);
    let (_, top) = m.height_range(cx, cy).unwrap();
    assert!(top > 0.15, "the column's top {top:.3} m was dropped");
}
