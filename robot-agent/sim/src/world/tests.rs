use super::*;
use crate::scenario::{Rect, Scenario, WalkMode, WalkerSpec};

pub(crate) fn flat_with_wall() -> Scenario {
    Scenario::from_toml_str(
        r#"
name = "flat-wall"
[datum]
lat_deg = 48.0
lon_deg = 16.0
h_m = 200.0
[extent]
x_min_m = -20.0
x_max_m = 20.0
y_min_m = -20.0
y_max_m = 20.0
[terrain]
undulation_amplitude_m = 0.0
grass_amplitude_m = 0.0
[[wall]]
points = [[10.0, -15.0], [10.0, 15.0]]
thickness_m = 0.2
height_m = 3.0
"#,
        "test",
    )
    .unwrap()
}

#[test]
fn ground_and_wall_ranges_match_geometry() {
    let w = World::new(&flat_with_wall());
    let o = Point3::new(0.0, 0.0, 0.75);
    // Down at -15 deg: flat ground at z = 0 -> range = 0.75 / sin(15 deg).
    for az in [0.3f64, 1.0, 2.0, 3.0, -2.5] {
        let el = (-15f64).to_radians();
        let d = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
        let want = 0.75 / 15f64.to_radians().sin();
        assert!(
            (h.range_m - want).abs() < 1e-3,
            "az {az}: {} vs {want}",
            h.range_m
        );
        assert!(matches!(h.kind, HitKind::Ground { .. }));
    }
    // Horizontal towards the wall face at x = 9.9.
    for az in [-0.5f64, 0.0, 0.7] {
        let d = Vector3::new(az.cos(), az.sin(), 0.0);
        let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
        let want = 9.9 / az.cos();
        assert!((h.range_m - want).abs() < 1e-6, "{} vs {want}", h.range_m);
        assert!(matches!(h.kind, HitKind::Solid(_)));
    }
    // Up and away from the wall: nothing.
    assert!(w
        .raycast(&o, &Vector3::new(-1.0, 0.0, 0.1), 100.0, 0.0)
        .is_none());
    // Grazing rays (-1 deg) hit the flat ground at 0.75 / tan(1 deg) = 43 m, beyond the world edge.
    let d = Vector3::new(-(1f64.to_radians().cos()), 0.0, -(1f64.to_radians().sin()));
    assert!(w.raycast(&o, &d, 100.0, 0.0).is_none());
    let d = Vector3::new(0.0, -1.0, -(3f64.to_radians().tan()));
    let h = w.raycast(&o, &d, 100.0, 0.0).unwrap();
    assert!((h.range_m * 3f64.to_radians().sin() - 0.75).abs() < 1e-3);
}

#[test]
fn ground_raycast_matches_brute_force_on_rough_terrain() {
    let mut sc = flat_with_wall();
    sc.terrain.undulation_amplitude_m = 0.8;
    sc.terrain.undulation_wavelength_m = 6.0;
    sc.step.push(crate::scenario::StepSpec {
        rect: Some(Rect {
            center_m: [3.0, 2.0],
            size_m: [2.0, 4.0],
            yaw_deg: 20.0,
        }),
        points: None,
        width_m: 0.3,
        height_m: 0.15,
    });
    let w = World::new(&sc);
    let o = Point3::new(0.3, -0.2, 1.2);
    for k in 0..200 {
        let az = k as f64 * 0.0314;
        let el = -0.02 - (k % 16) as f64 * 0.02;
        let d = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let fast = w.ground.raycast(&o, &d, 60.0);
        // Brute force: tiny steps until below the surface.
        let mut t = 0.0;
        let mut slow = None;
        while t < 60.0 {
            let p = o + d * t;
            match w.ground_height(p.x, p.y) {
                Some(h) if p.z <= h => {
                    slow = Some(t);
                    break;
                }
                None => break,
                _ => {}
            }
            t += 0.002;
        }
        match (fast, slow) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 0.01, "ray {k}: {a} vs {b}"),
            (None, None) => {}
            other => panic!("ray {k}: {other:?}"),
        }
    }
}

#[test]
fn walkers_move_at_walking_speed() {
    let mut sc = flat_with_wall();
    sc.walker.push(WalkerSpec {
        points: vec![[0.0, 0.0], [10.0, 0.0]],
        speed_mps: 1.3,
        mode: WalkMode::PingPong,
        phase_m: 0.0,
        radius_m: 0.25,
        height_m: 1.75,
    });
    let w = World::new(&sc);
    let a = w.walkers_at(1.0)[0];
    let b = w.walkers_at(2.0)[0];
    assert!(((b.x_m - a.x_m).hypot(b.y_m - a.y_m) - 1.3).abs() < 1e-9);
    // Ping-pong: after 10 m it comes back.
    let c = w.walkers_at(12.0 / 1.3)[0];
    assert!((c.x_m - 8.0).abs() < 1e-9, "{}", c.x_m);
}

#[test]
fn obb_overlap() {
    let a = Obb {
        cx: 0.0,
        cy: 0.0,
        hx: 1.0,
        hy: 0.5,
        yaw: 0.0,
    };
    let mut b = Obb {
        cx: 1.6,
        cy: 0.0,
        hx: 0.5,
        hy: 0.5,
        yaw: std::f64::consts::FRAC_PI_4,
    };
    assert!(a.overlaps(&b));
    b.cx = 1.75;
    assert!(!a.overlaps(&b));
}
