//! `robot-agent slam`: evaluate ICP SLAM on a recorded sequence, register a scan pair.

use anyhow::{bail, Context};
use nalgebra::Isometry3;
use sensing::{sequence, Point, Scan};
use slam::{Config, Slam, TrajectoryErrors};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `robot-agent slam`.
#[derive(Debug, clap::Args)]
pub struct SlamArgs {
    #[command(subcommand)]
    command: SlamCommand,
}

#[derive(Debug, clap::Subcommand)]
enum SlamCommand {
    /// Run SLAM on a folder laid out like ../shared/data/lidar/kitti-seq and score it against
    /// its poses.txt. Last line: `frames N path_m P ate_m A rpe_m R rpe_deg D drift_pct F
    /// ms_per_frame T`.
    Eval(EvalArgs),
    /// Register SOURCE to TARGET (PLY or PCD) and print `target<-source` as a 4x4 matrix.
    Register(RegisterArgs),
}

#[derive(Debug, clap::Args)]
struct EvalArgs {
    /// Sequence folder (clouds/NNN.pcd, poses.txt, optional stamps.txt and odom.txt).
    dir: PathBuf,
    /// SLAM configuration (TOML, e.g. config/slam.toml); defaults when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the summary as one JSON object instead of the text line.
    #[arg(long)]
    json: bool,
    /// Use only the first N frames.
    #[arg(long)]
    frames: Option<usize>,
    /// Write the estimated poses (KITTI format, lidar frame) to this file.
    #[arg(long)]
    write_poses: Option<PathBuf>,
    /// Do not run SLAM: score this KITTI pose file (e.g. another tool's output) instead.
    #[arg(long)]
    score_poses: Option<PathBuf>,
    /// Print per-frame diagnostics as JSON lines on stderr.
    #[arg(long)]
    verbose: bool,
}

#[derive(Debug, clap::Args)]
struct RegisterArgs {
    /// Source cloud (PLY or PCD).
    source: PathBuf,
    /// Target cloud (PLY or PCD).
    target: PathBuf,
    /// Initial guess of target<-source: "x y z roll pitch yaw" (metres, radians).
    #[arg(long, allow_hyphen_values = true)]
    init: Option<String>,
    /// SLAM configuration (TOML) whose filters and ICP sections are used; for dense scan pairs
    /// config/slam-pair.toml (the robot's real-time defaults when absent).
    #[arg(long)]
    config: Option<PathBuf>,
}

/// Runs `robot-agent slam`.
pub fn run(args: SlamArgs) -> anyhow::Result<()> {
    match args.command {
        SlamCommand::Eval(a) => eval(a),
        SlamCommand::Register(a) => register(a),
    }
}

fn load_config(path: Option<&Path>) -> anyhow::Result<Config> {
    let Some(p) = path else {
        return Ok(Config::default());
    };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))
}

fn read_cloud(path: &Path) -> anyhow::Result<Vec<Point>> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "ply" => {
            sensing::ply::read_ply(path).with_context(|| format!("reading {}", path.display()))
        }
        "pcd" => {
            sensing::pcd::read_pcd(path).with_context(|| format!("reading {}", path.display()))
        }
        _ => bail!("{}: expected a .ply or .pcd file", path.display()),
    }
}

fn print_summary(e: &TrajectoryErrors, ms_per_frame: f64, json: bool) -> anyhow::Result<()> {
    if json {
        let mut v = serde_json::to_value(e)?;
        v["ms_per_frame"] = serde_json::json!(ms_per_frame);
        println!("{v}");
    } else {
        println!(
            "frames {} path_m {:.3} ate_m {:.4} rpe_m {:.4} rpe_deg {:.4} drift_pct {:.3} ms_per_frame {:.2}",
            e.frames, e.path_m, e.ate_m, e.rpe_m, e.rpe_deg, e.drift_pct, ms_per_frame
        );
    }
    Ok(())
}

fn eval(a: EvalArgs) -> anyhow::Result<()> {
    let gt = sequence::read_poses(&a.dir)?;
    if let Some(p) = &a.score_poses {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
        let mut est = sequence::parse_poses(&text, &p.display().to_string())?;
        if let Some(n) = a.frames {
            est.truncate(n);
        }
        return print_summary(&slam::trajectory_errors(&est, &gt), f64::NAN, a.json);
    }
    let cfg = load_config(a.config.as_deref())?;
    let mut files = sequence::cloud_files(&a.dir)?;
    if let Some(n) = a.frames {
        files.truncate(n);
    }
    let stamps = sequence::read_stamps(&a.dir)?;
    let mut slam = Slam::new(cfg);
    if let Some(odom) = sequence::read_odometry(&a.dir)? {
        for s in odom {
            slam.push_odometry(s);
        }
    }
    let bar = indicatif::ProgressBar::new(files.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("slam {bar:40} {pos}/{len} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut est: Vec<Isometry3<f64>> = Vec::with_capacity(files.len());
    let mut total_s = 0.0;
    let mut failures = 0usize;
    for (i, f) in files.iter().enumerate() {
        let points =
            sensing::pcd::read_pcd(f).with_context(|| format!("reading {}", f.display()))?;
        // KITTI has no stamps file: its scans are 10 Hz.
        let stamp_s = stamps
            .as_ref()
            .and_then(|s| s.get(i).copied())
            .unwrap_or(i as f64 * 0.1);
        let mut scan = Scan { stamp_s, points };
        scan.retain_finite();
        let t0 = Instant::now();
        let out = slam.process(&scan);
        total_s += t0.elapsed().as_secs_f64();
        match out {
            Ok(o) => {
                if o.diagnostics.fell_back_to_prior {
                    failures += 1;
                }
                if a.verbose {
                    bar.suspend(|| {
                        eprintln!("{}", serde_json::json!({"frame": i, "diag": o.diagnostics}))
                    });
                }
                est.push(o.pose_map_lidar);
            }
            Err(e) => {
                // Keep the trajectory aligned with the ground truth: repeat the last pose.
                failures += 1;
                bar.suspend(|| eprintln!("frame {i}: {e}"));
                est.push(est.last().copied().unwrap_or_else(Isometry3::identity));
            }
        }
        bar.set_message(format!(
            "{:.1} ms/frame, {} map points",
            1e3 * total_s / (i + 1) as f64,
            slam.map().len()
        ));
        bar.inc(1);
    }
    bar.finish_and_clear();
    if failures > 0 {
        eprintln!("{failures} scans fell back to the prior");
    }
    if let Some(p) = &a.write_poses {
        let text: String = est
            .iter()
            .map(|e| sequence::format_pose(e) + "\n")
            .collect();
        std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))?;
    }
    let ms = 1e3 * total_s / files.len().max(1) as f64;
    print_summary(&slam::trajectory_errors(&est, &gt), ms, a.json)
}

fn register(a: RegisterArgs) -> anyhow::Result<()> {
    let cfg = load_config(a.config.as_deref())?;
    let source = read_cloud(&a.source)?;
    let target = read_cloud(&a.target)?;
    let init = match &a.init {
        None => Isometry3::identity(),
        Some(s) => {
            let v: Vec<f64> = s
                .split_whitespace()
                .map(str::parse)
                .collect::<Result<_, _>>()
                .context("--init wants six numbers")?;
            let [x, y, z, r, p, yaw] = v[..] else {
                bail!("--init wants six numbers, got {}", v.len())
            };
            slam::se3::from_xyz_rpy([x, y, z], [r, p, yaw])
        }
    };
    let r = slam::register_pair(&source, &target, &init, &cfg);
    eprintln!(
        "status {:?} iterations {} residual_rms_m {:.4} inlier_ratio {:.3} degenerate {}",
        r.status, r.iterations, r.residual_rms_m, r.inlier_ratio, r.degenerate
    );
    let m = r.pose.to_homogeneous();
    for i in 0..4 {
        println!(
            "{:.9} {:.9} {:.9} {:.9}",
            m[(i, 0)],
            m[(i, 1)],
            m[(i, 2)],
            m[(i, 3)]
        );
    }
    if !r.status.is_ok() {
        bail!("registration failed: {:?}", r.status);
    }
    Ok(())
}
