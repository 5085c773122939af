//! Tests on the real recordings in `../shared/data/lidar` (skipped when the folder is absent).

use nalgebra::{Isometry3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};
use sensing::{sequence, Scan};
use slam::{se3, Config, Slam};
use std::path::PathBuf;

fn data_dir(name: &str) -> Option<PathBuf> {
    common::shared_data::locate(env!("CARGO_MANIFEST_DIR"), &format!("lidar/{name}"), name)
}

fn workspace_file(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(rel)
}

fn read_matrix(path: &std::path::Path) -> Isometry3<f64> {
    let text = std::fs::read_to_string(path).expect("reference transform");
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse().expect("number"))
        .collect();
    let m = Matrix4::from_row_slice(&v[..16]);
    let rot = Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

#[test]
fn registration_pair_from_1m_10deg_offsets() {
    let Some(dir) = data_dir("registration-pair") else {
        return;
    };
    let source = sensing::ply::read_ply(dir.join("source.ply")).expect("source.ply");
    let target = sensing::ply::read_ply(dir.join("target.ply")).expect("target.ply");
    let reference = read_matrix(&dir.join("T_target_source.txt"));
    let text = std::fs::read_to_string(workspace_file("config/slam-pair.toml")).expect("config");
    let cfg: Config = toml::from_str(&text).expect("config/slam-pair.toml parses");
    // 1 m and 10 deg off in several directions (about several axes).
    let ten = 10f64.to_radians();
    let offsets = [
        ([1.0, 0.0, 0.0], [0.0, 0.0, ten]),
        ([0.0, -1.0, 0.0], [0.0, 0.0, -ten]),
        (
            [0.6, 0.6, 0.53],
            [ten / 3f64.sqrt(), ten / 3f64.sqrt(), ten / 3f64.sqrt()],
        ),
    ];
    for (xyz, rpy) in offsets {
        let off = se3::from_xyz_rpy(xyz, rpy);
        assert!((se3::translation_norm(&off) - 1.0).abs() < 0.01);
        let init = reference * off;
        let r = slam::register_pair(&source, &target, &init, &cfg);
        let err = reference.inverse() * r.pose;
        let (t_m, r_deg) = (
            se3::translation_norm(&err),
            se3::rotation_angle(&err).to_degrees(),
        );
        println!("offset {xyz:?} {rpy:?}: error {t_m:.4} m {r_deg:.4} deg, {r:?}");
        assert!(r.status.is_ok(), "{r:?}");
        assert!(t_m < 0.03 && r_deg < 0.3, "error {t_m} m {r_deg} deg");
    }
}

#[test]
fn kitti_first_frames_within_bounds() {
    let Some(dir) = data_dir("kitti-seq") else {
        return;
    };
    let text = std::fs::read_to_string(workspace_file("config/slam-kitti.toml")).expect("config");
    let cfg: Config = toml::from_str(&text).expect("config/slam-kitti.toml parses");
    let gt = sequence::read_poses(&dir).expect("poses");
    let files = sequence::cloud_files(&dir).expect("clouds");
    let mut slam = Slam::new(cfg);
    let mut est = Vec::new();
    for (i, f) in files.iter().take(15).enumerate() {
        let scan = Scan {
            stamp_s: i as f64 * 0.1,
            points: sensing::pcd::read_pcd(f).expect("pcd"),
        };
        let out = slam.process(&scan).expect("scan processed");
        assert!(
            !out.diagnostics.fell_back_to_prior,
            "frame {i}: {:?}",
            out.diagnostics
        );
        assert!(!slam.map_cloud().is_empty());
        est.push(out.pose_map_lidar);
    }
    let e = slam::trajectory_errors(&est, &gt);
    println!("{e:?}");
    // 15 frames = ~13 m; KISS-ICP's full-sequence figures are ATE 0.152 m, drift 0.83 %.
    assert!(e.path_m > 10.0);
    assert!(e.ate_m < 0.1, "{e:?}");
    assert!(e.drift_pct < 0.8, "{e:?}");
    assert!(e.rpe_m < 0.03 && e.rpe_deg < 0.1, "{e:?}");
    // The lidar moved forward along +x of scan 0 (KITTI car driving).
    let last = est.last().map(|p| p.translation.vector).unwrap_or_default();
    assert!(last.dot(&Vector3::x()) > 10.0, "{last:?}");
}

/// The issue's bar on the whole sequence: ATE <= 0.15 m and drift <= 0.8 %, and at least as
/// accurate as KISS-ICP 1.3 there (ATE 0.152 m, RPE 0.020 m / 0.058 deg, drift 0.83 %).
/// Speed is compared side by side by scripts/bench-slam.sh, not here.
#[test]
fn kitti_sequence_within_the_issue_bounds() {
    let Some(dir) = data_dir("kitti-seq") else {
        return;
    };
    let text = std::fs::read_to_string(workspace_file("config/slam-kitti.toml")).expect("config");
    let cfg: Config = toml::from_str(&text).expect("config/slam-kitti.toml parses");
    let gt = sequence::read_poses(&dir).expect("poses");
    let files = sequence::cloud_files(&dir).expect("clouds");
    let mut slam = Slam::new(cfg);
    let est: Vec<_> = files
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let scan = Scan {
                stamp_s: i as f64 * 0.1,
                points: sensing::pcd::read_pcd(f).expect("pcd"),
            };
            let out = slam.process(&scan).expect("scan processed");
            assert!(!out.diagnostics.fell_back_to_prior, "frame {i}");
            out.pose_map_lidar
        })
        .collect();
    let e = slam::trajectory_errors(&est, &gt);
    println!("{e:?}");
    assert_eq!(e.frames, 30);
    assert!(e.ate_m <= 0.15 && e.drift_pct <= 0.8, "{e:?}");
    assert!(e.rpe_m <= 0.020 && e.rpe_deg <= 0.058, "{e:?}");
}

#[test]
fn config_file_matches_defaults() {
    let text =
        std::fs::read_to_string(workspace_file("config/slam.toml")).expect("config/slam.toml");
    let cfg: Config = toml::from_str(&text).expect("config/slam.toml parses");
    assert_eq!(cfg, Config::default());
}

/// The one default configuration (`config/slam.toml`, "auto" keys) on the 64-beam car: the voxel
/// grid and the match gate adapt to the sensor without `slam-kitti.toml`, and the result is at
/// least as accurate as KISS-ICP 1.3's default there (ATE 0.152 m, drift 0.83 %). Without the
/// adaptive voxel the default ran ~30k points a scan (~8x slower, see the README).
#[test]
fn kitti_sequence_with_the_default_config() {
    let Some(dir) = data_dir("kitti-seq") else {
        return;
    };
    let text =
        std::fs::read_to_string(workspace_file("config/slam.toml")).expect("config/slam.toml");
    let cfg: Config = toml::from_str(&text).expect("config/slam.toml parses");
    let gt = sequence::read_poses(&dir).expect("poses");
    let files = sequence::cloud_files(&dir).expect("clouds");
    let mut slam = Slam::new(cfg);
    let mut est = Vec::new();
    for (i, f) in files.iter().enumerate() {
        let scan = Scan {
            stamp_s: i as f64 * 0.1,
            points: sensing::pcd::read_pcd(f).expect("pcd"),
        };
        let out = slam.process(&scan).expect("scan processed");
        let d = &out.diagnostics;
        assert!(!d.fell_back_to_prior, "frame {i}: {d:?}");
        // The adaptive voxel kept the registration budget small.
        assert!(
            d.voxel_m > 0.5 && d.reading_points < 4000,
            "frame {i}: {d:?}"
        );
        est.push(out.pose_map_lidar);
    }
    let e = slam::trajectory_errors(&est, &gt);
    println!("{e:?}");
    assert_eq!(e.frames, 30);
    assert!(e.ate_m <= 0.152 && e.drift_pct <= 0.83, "{e:?}");
}
