//! WGS-84 conversions against `../shared/data/geodesy/vectors.tsv` (gpsd, GeographicLib and
//! IOGP 373-7-2 reference values), plus round-trip property tests over the whole globe.

use std::path::PathBuf;

use common::geo::wgs84::{
    ecef_to_geodetic, enu_to_lla, geodetic_to_ecef, lla_to_enu, LocalFrame, A_M, B_M,
};
use common::msg::Datum;
use nalgebra::Vector3;
use proptest::prelude::*;

fn data_dir(what: &str) -> Option<PathBuf> {
    common::shared_data::locate(env!("CARGO_MANIFEST_DIR"), "", what)
}

fn nums(s: &str) -> Vec<f64> {
    s.split_whitespace()
        .map(|t| t.parse().unwrap_or_else(|e| panic!("{t:?}: {e}")))
        .collect()
}

fn datum(v: &[f64]) -> Datum {
    Datum {
        lat_deg: v[0],
        lon_deg: v[1],
        h_m: v[2],
    }
}

#[test]
fn reference_vectors_reproduce_within_tolerance() {
    let Some(dir) = data_dir("reference_vectors_reproduce_within_tolerance") else {
        return;
    };
    let text = std::fs::read_to_string(dir.join("geodesy/vectors.tsv")).expect("read vectors");
    let mut checked = 0;
    for line in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
    {
        let cols: Vec<&str> = line.split('\t').collect();
        assert!(cols.len() >= 4, "{line}");
        let (kind, inputs, expected, tol) = (cols[0], cols[1], nums(cols[2]), nums(cols[3])[0]);
        let got: Vector3<f64> = match kind {
            "lla2ecef" => geodetic_to_ecef(&datum(&nums(inputs))),
            "ecef2enu" => {
                let (r, p) = inputs.split_once('|').expect("reference | point");
                let (r, p) = (nums(r), nums(p));
                LocalFrame::from_ecef(&Vector3::new(r[0], r[1], r[2]))
                    .ecef_to_enu(&Vector3::new(p[0], p[1], p[2]))
            }
            "lla2enu" => {
                let (r, p) = inputs.split_once('|').expect("reference | point");
                lla_to_enu(&datum(&nums(r)), &datum(&nums(p)))
            }
            other => panic!("unknown kind {other}"),
        };
        let err = (got - Vector3::new(expected[0], expected[1], expected[2])).amax();
        println!("{kind} {inputs}: max error {err:.2e} m (tolerance {tol})");
        assert!(err <= tol, "{line}: got {got:?}, error {err}");
        // The inverse must come back to the input too.
        if kind == "lla2ecef" {
            let back = ecef_to_geodetic(&got);
            let input = datum(&nums(inputs));
            assert!((back.lat_deg - input.lat_deg).abs() < 1e-11, "{back:?}");
            assert!((back.lon_deg - input.lon_deg).abs() < 1e-11, "{back:?}");
            assert!((back.h_m - input.h_m).abs() < 1e-6, "{back:?}");
        }
        checked += 1;
    }
    assert_eq!(checked, 7, "every vector of the file was checked");
}

#[test]
fn poles_and_axes_invert_exactly() {
    for (ecef, lat, h) in [
        (Vector3::new(0.0, 0.0, B_M + 100.0), 90.0, 100.0),
        (Vector3::new(0.0, 0.0, -B_M), -90.0, 0.0),
        (Vector3::new(A_M - 5.0, 0.0, 0.0), 0.0, -5.0),
        (Vector3::new(0.0, -A_M, 0.0), 0.0, 0.0),
    ] {
        let p = ecef_to_geodetic(&ecef);
        assert!((p.lat_deg - lat).abs() < 1e-12, "{p:?}");
        assert!((p.h_m - h).abs() < 1e-6, "{p:?}");
    }
}

/// Angular error in degrees with longitude scaled by cos(lat), so that a pole's arbitrary
/// longitude does not count.
fn horizontal_err_deg(a: &Datum, b: &Datum) -> f64 {
    let dlon = (a.lon_deg - b.lon_deg + 540.0).rem_euclid(360.0) - 180.0;
    let dlat = a.lat_deg - b.lat_deg;
    dlat.abs().max((dlon * a.lat_deg.to_radians().cos()).abs())
}

fn any_datum() -> impl Strategy<Value = Datum> {
    (
        prop_oneof![-90.0..=90.0f64, Just(90.0), Just(-90.0), Just(0.0)],
        -180.0..180.0f64,
        prop_oneof![-500.0..9_000.0f64, -10_000.0..1.0e7f64],
    )
        .prop_map(|(lat_deg, lon_deg, h_m)| Datum {
            lat_deg,
            lon_deg,
            h_m,
        })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 4000,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn lla_ecef_lla_round_trips(p in any_datum()) {
        let back = ecef_to_geodetic(&geodetic_to_ecef(&p));
        prop_assert!(horizontal_err_deg(&p, &back) < 1e-9, "{:?} -> {:?}", p, back);
        prop_assert!((p.h_m - back.h_m).abs() < 1e-3, "{:?} -> {:?}", p, back);
    }

    #[test]
    fn enu_lla_enu_round_trips(
        reference in any_datum().prop_filter("terrestrial datum", |d| d.h_m < 9_000.0),
        e in -50_000.0..50_000.0f64,
        n in -50_000.0..50_000.0f64,
        u in -1_000.0..1_000.0f64,
    ) {
        let enu = Vector3::new(e, n, u);
        let p = enu_to_lla(&reference, &enu);
        let again = lla_to_enu(&reference, &p);
        prop_assert!((again - enu).amax() < 1e-3, "{:?} {:?} -> {:?}", reference, enu, again);
        // And the geodetic side: lla -> enu -> lla.
        let frame = LocalFrame::new(reference);
        let back = frame.enu_to_lla(&frame.lla_to_enu(&p));
        prop_assert!(horizontal_err_deg(&p, &back) < 1e-9);
        prop_assert!((p.h_m - back.h_m).abs() < 1e-3);
    }

    #[test]
    fn enu_distances_match_ecef_distances(
        reference in any_datum().prop_filter("terrestrial datum", |d| d.h_m < 9_000.0),
        dlat in -0.01..0.01f64, dlon in -0.01..0.01f64, dh in -100.0..100.0f64,
    ) {
        // The ENU rotation is orthonormal: it keeps lengths.
        let p = Datum {
            lat_deg: (reference.lat_deg + dlat).clamp(-90.0, 90.0),
            lon_deg: reference.lon_deg + dlon,
            h_m: reference.h_m + dh,
        };
        let enu = lla_to_enu(&reference, &p);
        let chord = (geodetic_to_ecef(&p) - geodetic_to_ecef(&reference)).norm();
        prop_assert!((enu.norm() - chord).abs() < 1e-6);
    }
}

#[test]
fn worst_round_trip_error_on_a_grid() {
    // A deterministic sweep (1 deg lat x 7 deg lon x 6 heights), reported for the README.
    let (mut worst_deg, mut worst_m) = (0.0f64, 0.0f64);
    for lat in -90..=90 {
        for lon in (-180..180).step_by(7) {
            for h in [-430.0, 0.0, 250.5, 8_848.0, 400_000.0, 20_200_000.0] {
                let p = Datum {
                    lat_deg: f64::from(lat) + 0.123_456_789,
                    lon_deg: f64::from(lon) + 0.987_654_321,
                    h_m: h,
                };
                let p = Datum {
                    lat_deg: p.lat_deg.min(90.0),
                    ..p
                };
                let back = ecef_to_geodetic(&geodetic_to_ecef(&p));
                worst_deg = worst_deg.max(horizontal_err_deg(&p, &back));
                worst_m = worst_m.max((p.h_m - back.h_m).abs());
            }
        }
    }
    println!("lla->ecef->lla worst: {worst_deg:.2e} deg, {worst_m:.2e} m");
    assert!(worst_deg < 1e-9 && worst_m < 1e-3);
}
