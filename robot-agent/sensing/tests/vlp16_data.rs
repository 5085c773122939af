//! Decoding the real VLP-16 recordings in `../shared/data/lidar/vlp16/`.

use sensing::pcd::read_pcd_full;
use sensing::velodyne::source::decode_file;
use sensing::velodyne::{
    ring_by_elevation, AzimuthInterpolation, LidarScan, VelodyneConfig, LASER_ELEVATION_DEG,
};
use std::path::PathBuf;

fn data_dir(test: &str) -> Option<PathBuf> {
    // robot-agent/sensing -> workspace root -> ../shared/data
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/lidar/vlp16");
    if d.is_dir() {
        Some(d)
    } else {
        println!("skipping {test}: ../shared/data is absent");
        None
    }
}

fn bag_path(d: &std::path::Path) -> PathBuf {
    d.join("packets_1673400471837873222.db3")
}

/// Reference points: xyz, intensity, return_type, channel (elevation rank), azimuth, distance.
struct RefPoint {
    xyz: [f32; 3],
    intensity: f32,
    return_type: u8,
    channel: u16,
    azimuth_rad: f32,
    distance_m: f32,
}

fn reference(d: &std::path::Path) -> Vec<RefPoint> {
    let c = read_pcd_full(d.join("decoded_1673400472138016708.pcd")).unwrap();
    let col = |n: &str| c.field_names.iter().position(|f| f == n).unwrap();
    let (rt, ch, az, di) = (
        col("return_type"),
        col("channel"),
        col("azimuth"),
        col("distance"),
    );
    c.points
        .iter()
        .zip(&c.values)
        .map(|(p, v)| RefPoint {
            xyz: [p.x, p.y, p.z],
            intensity: p.intensity,
            return_type: v[rt] as u8,
            channel: v[ch] as u16,
            azimuth_rad: v[az] as f32,
            distance_m: v[di] as f32,
        })
        .collect()
}

fn max_error_m(scan: &LidarScan, r: &[RefPoint]) -> f64 {
    scan.returns
        .iter()
        .zip(r)
        .map(|(a, b)| {
            let p = a.point;
            (((p.x - b.xyz[0]) as f64).powi(2)
                + ((p.y - b.xyz[1]) as f64).powi(2)
                + ((p.z - b.xyz[2]) as f64).powi(2))
            .sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn bag_reproduces_the_reference_decoding() {
    let Some(d) = data_dir("bag_reproduces_the_reference_decoding") else {
        return;
    };
    let r = reference(&d);
    assert_eq!(r.len(), 14_831);
    let (scans, stats, fstats) =
        decode_file(bag_path(&d), VelodyneConfig::nebula_reference()).unwrap();
    assert_eq!((stats.packets_ok, stats.malformed()), (603, 0));
    assert_eq!((fstats.bag_messages, fstats.bad_cdr_messages), (4, 0));
    for s in &scans {
        println!(
            "scan {}: {} points, {} packets, coverage {:.2} deg, complete {}",
            s.index,
            s.returns.len(),
            s.packets,
            s.coverage_deg,
            s.complete
        );
    }
    // The scan matching the reference: same count, and every point within 1 cm.
    let matching: Vec<usize> = scans
        .iter()
        .filter(|s| s.returns.len() == r.len() && max_error_m(s, &r) < 0.01)
        .map(|s| s.index)
        .collect();
    assert_eq!(
        matching,
        [3],
        "the rotation completed in the bag's 4th message"
    );
    let s = &scans[3];
    let err = max_error_m(s, &r);
    println!(
        "reference scan 3: {} points, max position error {:.6} m",
        s.returns.len(),
        err
    );
    assert!(err < 0.002, "{err}");
    for (a, b) in s.returns.iter().zip(&r) {
        assert_eq!(ring_by_elevation(a.point.ring), b.channel);
        assert_eq!(a.point.intensity, b.intensity);
        assert_eq!(a.return_type.nebula_code(), b.return_type);
        assert!((a.distance_m - b.distance_m).abs() < 1e-5);
        assert!(
            (a.azimuth_rad - b.azimuth_rad).abs() < 2e-4,
            "{} {}",
            a.azimuth_rad,
            b.azimuth_rad
        );
        assert!(
            (a.elevation_rad - LASER_ELEVATION_DEG[a.point.ring as usize].to_radians()).abs()
                < 1e-6
        );
    }
    assert!(s.complete && s.packets == 151);
}

#[test]
fn exact_interpolation_differs_from_the_reference_only_where_nebula_simplifies() {
    let Some(d) =
        data_dir("exact_interpolation_differs_from_the_reference_only_where_nebula_simplifies")
    else {
        return;
    };
    let r = reference(&d);
    let cfg = VelodyneConfig {
        interpolation: AzimuthInterpolation::Exact,
        ..VelodyneConfig::nebula_reference()
    };
    let (scans, _, _) = decode_file(bag_path(&d), cfg).unwrap();
    let s = &scans[3];
    let within_1cm = s
        .returns
        .iter()
        .zip(&r)
        .filter(|(a, b)| {
            let p = a.point;
            ((p.x - b.xyz[0]).powi(2) + (p.y - b.xyz[1]).powi(2) + (p.z - b.xyz[2]).powi(2)).sqrt()
                < 0.01
        })
        .count();
    println!(
        "exact interpolation: {} points (reference {}), {} within 1 cm, max error {:.4} m",
        s.returns.len(),
        r.len(),
        within_1cm,
        max_error_m(s, &r)
    );
}
