//! Recorded sequences laid out like `../shared/data/lidar/kitti-seq`: `clouds/NNN.pcd` (one scan
//! each, sensor frame) and `poses.txt` (line N: 3x4 row-major pose of scan N's sensor frame in the
//! frame of scan 0, or in the map frame for simulator recordings). Simulator recordings add
//! `odom.txt` (`t_s x_m y_m yaw_rad v_mps omega_rps` per line), `nmea.log` (`t_s sentence`),
//! `stamps.txt` (scan start times, seconds) and `meta.toml`.

use crate::cloud::OdomSample;
use common::geom::Pose2;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use std::path::{Path, PathBuf};

/// Why a sequence folder could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SequenceError {
    /// A file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// A line of a text file is malformed.
    #[error("{path} line {line}: {msg}")]
    Parse {
        /// File path.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        msg: String,
    },
    /// The folder has no `clouds/*.pcd`.
    #[error("{0} has no clouds/*.pcd")]
    Empty(String),
}

fn read_text(path: &Path) -> Result<String, SequenceError> {
    std::fs::read_to_string(path).map_err(|source| SequenceError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// The scan files of a sequence folder in scan order: numerically by file stem (`999.pcd` before
/// `1000.pcd`, which a plain name sort would put after `100.pcd`), then by name.
pub fn cloud_files(dir: impl AsRef<Path>) -> Result<Vec<PathBuf>, SequenceError> {
    let d = dir.as_ref().join("clouds");
    let rd = std::fs::read_dir(&d).map_err(|source| SequenceError::Io {
        path: d.display().to_string(),
        source,
    })?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
        .collect();
    v.sort_by_cached_key(|p| {
        let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        (stem.parse::<u64>().ok(), p.clone())
    });
    if v.is_empty() {
        return Err(SequenceError::Empty(dir.as_ref().display().to_string()));
    }
    Ok(v)
}

/// Parses KITTI-style poses (12 numbers per line, 3x4 row-major).
pub fn parse_poses(text: &str, path: &str) -> Result<Vec<Isometry3<f64>>, SequenceError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Result<Vec<f64>, _> = line.split_whitespace().map(str::parse::<f64>).collect();
        let v = v.map_err(|e| SequenceError::Parse {
            path: path.into(),
            line: i + 1,
            msg: e.to_string(),
        })?;
        if v.len() != 12 {
            return Err(SequenceError::Parse {
                path: path.into(),
                line: i + 1,
                msg: format!("{} numbers, want 12", v.len()),
            });
        }
        let m = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
        // Re-orthonormalise: text poses carry rounding that would otherwise leak into ATE.
        let rot = Rotation3::from_matrix(&m);
        out.push(Isometry3::from_parts(
            Translation3::new(v[3], v[7], v[11]),
            UnitQuaternion::from_rotation_matrix(&rot),
        ));
    }
    Ok(out)
}

/// Reads `poses.txt` of a sequence folder.
pub fn read_poses(dir: impl AsRef<Path>) -> Result<Vec<Isometry3<f64>>, SequenceError> {
    let p = dir.as_ref().join("poses.txt");
    parse_poses(&read_text(&p)?, &p.display().to_string())
}

/// Formats a pose as one KITTI line.
pub fn format_pose(p: &Isometry3<f64>) -> String {
    let r = p.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = p.translation.vector;
    format!(
        "{:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        t.x,
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        t.y,
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
        t.z
    )
}

/// Reads `odom.txt` if the folder has one.
pub fn read_odometry(dir: impl AsRef<Path>) -> Result<Option<Vec<OdomSample>>, SequenceError> {
    let p = dir.as_ref().join("odom.txt");
    if !p.exists() {
        return Ok(None);
    }
    let path = p.display().to_string();
    let mut out = Vec::new();
    for (i, line) in read_text(&p)?.lines().enumerate() {
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Result<Vec<f64>, _> = line.split_whitespace().map(str::parse::<f64>).collect();
        let v = v.map_err(|e| SequenceError::Parse {
            path: path.clone(),
            line: i + 1,
            msg: e.to_string(),
        })?;
        if v.len() != 6 {
            return Err(SequenceError::Parse {
                path: path.clone(),
                line: i + 1,
                msg: "want 6 numbers".into(),
            });
        }
        out.push(OdomSample {
            t_s: v[0],
            pose_odom: Pose2::new(v[1], v[2], v[3]),
            v_mps: v[4],
            omega_rps: v[5],
        });
    }
    Ok(Some(out))
}

/// Formats one odometry sample as a line of `odom.txt`.
pub fn format_odometry(o: &OdomSample) -> String {
    format!(
        "{:.6} {:.6} {:.6} {:.9} {:.6} {:.6}",
        o.t_s, o.pose_odom.x_m, o.pose_odom.y_m, o.pose_odom.yaw_rad, o.v_mps, o.omega_rps
    )
}

/// Reads `stamps.txt` (scan start times) if present.
pub fn read_stamps(dir: impl AsRef<Path>) -> Result<Option<Vec<f64>>, SequenceError> {
    let p = dir.as_ref().join("stamps.txt");
    if !p.exists() {
        return Ok(None);
    }
    let path = p.display().to_string();
    read_text(&p)?
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            l.trim().parse::<f64>().map_err(|e| SequenceError::Parse {
                path: path.clone(),
                line: i + 1,
                msg: e.to_string(),
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_lines_round_trip() {
        let p = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 0.25),
            UnitQuaternion::from_euler_angles(0.01, -0.02, 1.2),
        );
        let q = parse_poses(&format_pose(&p), "x").unwrap();
        assert!((q[0].translation.vector - p.translation.vector).norm() < 1e-8);
        assert!(q[0].rotation.angle_to(&p.rotation) < 1e-8);
        assert!(parse_poses("1 2 3", "x").is_err());
        assert!(parse_poses("1 2 3 4 5 6 7 8 9 10 11 x", "x").is_err());
    }

    #[test]
    fn cloud_files_are_in_numeric_order() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("clouds")).unwrap();
        for n in [1000, 999, 100, 1, 101] {
            std::fs::write(dir.path().join(format!("clouds/{n:03}.pcd")), "").unwrap();
        }
        let names: Vec<String> = cloud_files(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            ["001.pcd", "100.pcd", "101.pcd", "999.pcd", "1000.pcd"]
        );
    }

    #[test]
    fn reads_the_kitti_sequence() {
        let Some(root) = common::shared_data::locate(
            env!("CARGO_MANIFEST_DIR"),
            "lidar/kitti-seq",
            "reads_the_kitti_sequence",
        ) else {
            return;
        };
        let poses = read_poses(&root).unwrap();
        let files = cloud_files(&root).unwrap();
        assert_eq!(poses.len(), files.len());
        let pts = crate::pcd::read_pcd(&files[0]).unwrap();
        assert!(pts.len() > 100_000, "{}", pts.len());
        let path_m: f64 = poses
            .windows(2)
            .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
            .sum();
        assert!((20.0..40.0).contains(&path_m), "{path_m}");
    }
}
