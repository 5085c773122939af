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
