//! Runs SLAM on a sequence folder and prints the error summary (a dependency-light twin of
//! `robot-agent slam eval`, handy while the binary's other crates are being rebuilt).
//!
//! `cargo run --release -p terranav-slam --example seq_eval -- DIR [CONFIG.toml] [FRAMES]`

use sensing::{sequence, Scan};
use slam::{Config, Slam};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args
        .get(1)
        .ok_or("usage: seq_eval DIR [CONFIG.toml] [FRAMES]")?;
    let cfg: Config = match args.get(2).filter(|s| !s.is_empty() && *s != "-") {
        Some(p) => toml::from_str(&std::fs::read_to_string(p)?)?,
        None => Config::default(),
    };
    let mut files = sequence::cloud_files(dir)?;
    if let Some(n) = args.get(3) {
        files.truncate(n.parse()?);
    }
    let gt = sequence::read_poses(dir)?;
    let verbose = std::env::var_os("SLAM_VERBOSE").is_some();
    let mut slam = Slam::new(cfg);
    let mut est = Vec::new();
    let mut total_s = 0.0;
    for (i, f) in files.iter().enumerate() {
        let scan = Scan {
            stamp_s: i as f64 * 0.1,
            points: sensing::pcd::read_pcd(f)?,
        };
        let t0 = Instant::now();
        let out = slam.process(&scan)?;
        total_s += t0.elapsed().as_secs_f64();
        if verbose {
            let d = &out.diagnostics;
            eprintln!(
                "{i} it {} res {:.3} inl {:.2} eig {:.1e} deg {} n {} map {} +{} -{}",
                d.iterations,
                d.residual_rms_m,
                d.inlier_ratio,
                d.eig_ratio,
                d.degenerate,
                d.reading_points,
                d.map_points,
                d.map_update.added,
                d.map_update.removed_dynamic
            );
        }
        est.push(out.pose_map_lidar);
    }
    let e = slam::trajectory_errors(&est, &gt);
    println!(
        "frames {} path_m {:.3} ate_m {:.4} rpe_m {:.4} rpe_deg {:.4} drift_pct {:.3} ms_per_frame {:.2}",
        e.frames, e.path_m, e.ate_m, e.rpe_m, e.rpe_deg, e.drift_pct,
        1e3 * total_s / files.len().max(1) as f64
    );
    Ok(())
}
