//! `robot-agent slam`: evaluate ICP SLAM on a recorded sequence, register a scan pair.

use anyhow::{bail, Context};
use nalgebra::Isometry3;
use sensing::{sequence, Point, Scan};
use slam::{Config, Slam, TrajectoryErrors};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod walkers;
use walkers::{WalkerScore, WALKER_GRACE_S};

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
    /// Register SOURCE to TARGET (PLY or PCD) and print `target<-source` as a 4x4 matrix
    /// (diagnostics and the time of the registration, file loading excluded, on stderr).
    Register(RegisterArgs),
}

#[derive(Debug, clap::Args)]
struct EvalArgs {
    /// Sequence folder (clouds/NNN.pcd, poses.txt, optional stamps.txt, odom.txt, meta.toml
    /// with the lidar extrinsic, walkers.txt).
    dir: PathBuf,
    /// SLAM configuration (TOML, e.g. config/slam.toml); defaults when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the summary as one JSON object instead of the text line.
    #[arg(long)]
    json: bool,
    /// Use only the first N frames (of the sequence, before `--every`).
    #[arg(long)]
    frames: Option<usize>,
    /// Use every N-th frame only (a sparser, faster-moving view of the same drive: 10 Hz KITTI
    /// with `--every 5` is 2 Hz); ground truth and stamps are thinned alike.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Write the estimated poses (KITTI format, lidar frame) to this file.
    #[arg(long)]
    write_poses: Option<PathBuf>,
    /// Do not run SLAM: score this KITTI pose file (e.g. another tool's output) instead.
    #[arg(long)]
    score_poses: Option<PathBuf>,
    /// Print per-frame diagnostics as JSON lines on stderr.
    #[arg(long)]
    verbose: bool,
    /// Simulator recordings: score dynamic-point removal against the walkers recorded in
    /// DIR/walkers.txt, in this scenario's world (map points seen on a walker that are still in
    /// the map after it walked on, where the sensor could see). Prints a `walkers ...` line
    /// before the summary; JSON gets a `walkers` object.
    #[arg(long)]
    scenario: Option<PathBuf>,
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

/// `base_link <- lidar` from a recording's `meta.toml` (`[lidar_extrinsic]`), if it has one.
fn recording_extrinsic(dir: &Path) -> anyhow::Result<Option<([f64; 3], [f64; 3])>> {
    #[derive(serde::Deserialize)]
    struct Mount {
        xyz_m: [f64; 3],
        rpy_rad: [f64; 3],
    }
    #[derive(serde::Deserialize)]
    struct Meta {
        lidar_extrinsic: Option<Mount>,
    }
    let p = dir.join("meta.toml");
    if !p.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
    let meta: Meta = toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?;
    Ok(meta.lidar_extrinsic.map(|m| (m.xyz_m, m.rpy_rad)))
}

/// Progress while `slam eval` runs: a bar on a terminal, a plain line every 10% otherwise (logs
/// of CI runs and tests get a heartbeat, not carriage-return noise).
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    len: usize,
    next_line: usize,
}

impl Progress {
    fn new(len: usize) -> Self {
        use std::io::IsTerminal;
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::new(len as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "slam {bar:40} {pos}/{len} [{elapsed_precise} < {eta}] {msg}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        Self {
            bar,
            len,
            next_line: len.div_ceil(10).max(1),
        }
    }

    fn println(&self, line: &str) {
        match &self.bar {
            Some(b) => b.suspend(|| eprintln!("{line}")),
            None => eprintln!("{line}"),
        }
    }

    fn step(&mut self, done: usize, ms_per_frame: f64, map_points: usize) {
        match &self.bar {
            Some(b) => {
                b.set_message(format!(
                    "{ms_per_frame:.1} ms/frame, {map_points} map points"
                ));
                b.set_position(done as u64);
            }
            None if done >= self.next_line || done == self.len => {
                eprintln!(
                    "slam {done}/{} frames, {ms_per_frame:.1} ms/frame, {map_points} map points",
                    self.len
                );
                self.next_line = done + self.len.div_ceil(10).max(1);
            }
            None => {}
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Every `every`-th item of `v`, from the first.
fn thin<T: Clone>(v: &[T], every: usize) -> Vec<T> {
    v.iter().step_by(every.max(1)).cloned().collect()
}

fn eval(a: EvalArgs) -> anyhow::Result<()> {
    let every = usize::try_from(a.every).unwrap_or(usize::MAX);
    let mut gt = sequence::read_poses(&a.dir)?;
    if let Some(n) = a.frames {
        gt.truncate(n);
    }
    let gt = thin(&gt, every);
    if let Some(p) = &a.score_poses {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
        let mut est = sequence::parse_poses(&text, &p.display().to_string())?;
        if let Some(n) = a.frames {
            est.truncate(n);
        }
        return print_summary(&slam::trajectory_errors(&est, &gt), f64::NAN, a.json);
    }
    let mut cfg = load_config(a.config.as_deref())?;
    // A recording knows how its sensor was mounted; the odometry prior and the robot box need it.
    if let Some((xyz, rpy)) = recording_extrinsic(&a.dir)? {
        cfg.sensor.lidar_xyz_m = xyz;
        cfg.sensor.lidar_rpy_rad = rpy;
    }
    let mut files = sequence::cloud_files(&a.dir)?;
    if let Some(n) = a.frames {
        files.truncate(n);
    }
    // KITTI has no stamps file: its scans are 10 Hz.
    let stamps: Vec<f64> = match sequence::read_stamps(&a.dir)? {
        Some(s) => (0..files.len())
            .map(|i| s.get(i).copied().unwrap_or(i as f64 * 0.1))
            .collect(),
        None => (0..files.len()).map(|i| i as f64 * 0.1).collect(),
    };
    let files = thin(&files, every);
    let stamps = thin(&stamps, every);
    let mut walkers = a
        .scenario
        .as_deref()
        .map(|sc| WalkerScore::new(sc, &a.dir))
        .transpose()?;
    if walkers.is_some() {
        anyhow::ensure!(
            gt.len() >= files.len(),
            "--scenario needs a true pose per scan ({} poses, {} scans)",
            gt.len(),
            files.len()
        );
    }
    let mut slam = Slam::new(cfg);
    if let Some(odom) = sequence::read_odometry(&a.dir)? {
        for s in odom {
            slam.push_odometry(s);
        }
    }
    let mut prov = slam::Provenance::default();
    let mut progress = Progress::new(files.len());
    let mut est: Vec<Isometry3<f64>> = Vec::with_capacity(files.len());
    let mut total_s = 0.0;
    let mut failures = 0usize;
    let mut recovered = 0usize;
    for (i, f) in files.iter().enumerate() {
        let points =
            sensing::pcd::read_pcd(f).with_context(|| format!("reading {}", f.display()))?;
        let mut scan = Scan {
            stamp_s: stamps[i],
            points,
        };
        scan.retain_finite();
        let t0 = Instant::now();
        let out = slam.process(&scan);
        total_s += t0.elapsed().as_secs_f64();
        let mut map_updated = false;
        match out {
            Ok(o) => {
                if o.diagnostics.fell_back_to_prior {
                    failures += 1;
                }
                if o.diagnostics.recovered {
                    recovered += 1;
                }
                if a.verbose {
                    progress.println(
                        &serde_json::json!({"frame": i, "diag": o.diagnostics}).to_string(),
                    );
                }
                map_updated = o.diagnostics.map_updated;
                est.push(o.pose_map_lidar);
            }
            Err(e) => {
                // Keep the trajectory aligned with the ground truth: repeat the last pose.
                failures += 1;
                progress.println(&format!("frame {i}: {e}"));
                est.push(est.last().copied().unwrap_or_else(Isometry3::identity));
            }
        }
        if let Some(w) = &mut walkers {
            prov.push(stamps[i], &est[i], &gt[i]);
            if map_updated {
                w.count_inserted(slam.map(), &prov, stamps[i]);
            }
            let lidar_at = |t: f64| gt[stamps[..=i].partition_point(|s| *s < t).min(i)];
            w.check(slam.map(), &prov, stamps[i], i + 1 == files.len(), lidar_at);
        }
        progress.step(i + 1, 1e3 * total_s / (i + 1) as f64, slam.map().len());
    }
    progress.finish();
    if failures > 0 {
        eprintln!("{failures} scans fell back to the prior");
    }
    if recovered > 0 {
        eprintln!("{recovered} scans recovered by a wider search");
    }
    if let Some(p) = &a.write_poses {
        let text: String = est
            .iter()
            .map(|e| sequence::format_pose(e) + "\n")
            .collect();
        std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))?;
    }
    let ms = 1e3 * total_s / files.len().max(1) as f64;
    let errors = slam::trajectory_errors(&est, &gt);
    match &walkers {
        None if a.json => {
            let mut v = serde_json::to_value(errors)?;
            v["ms_per_frame"] = serde_json::json!(ms);
            v["fell_back"] = serde_json::json!(failures);
            v["recovered"] = serde_json::json!(recovered);
            println!("{v}");
            Ok(())
        }
        None => print_summary(&errors, ms, false),
        Some(w) => {
            let wj = serde_json::json!({
                "count": w.world.walker_count(),
                "points_inserted": w.inserted,
                "left_final": w.left_final,
                "left_max": w.left_max.0,
                "left_max_t_s": w.left_max.1,
                "unseen_final": w.unseen_final,
                "grace_s": WALKER_GRACE_S,
            });
            if a.json {
                let mut v = serde_json::to_value(errors)?;
                v["ms_per_frame"] = serde_json::json!(ms);
                v["fell_back"] = serde_json::json!(failures);
                v["recovered"] = serde_json::json!(recovered);
                v["walkers"] = wj;
                println!("{v}");
                Ok(())
            } else {
                println!(
                    "walkers {} points_inserted {} left_final {} left_max {} (at {:.1} s) unseen_final {} grace_s {}",
                    w.world.walker_count(),
                    w.inserted,
                    w.left_final,
                    w.left_max.0,
                    w.left_max.1,
                    w.unseen_final,
                    WALKER_GRACE_S
                );
                print_summary(&errors, ms, false)
            }
        }
    }
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
    let t0 = Instant::now();
    let r = slam::register_pair(&source, &target, &init, &cfg);
    let ms = 1e3 * t0.elapsed().as_secs_f64();
    eprintln!(
        "status {:?} iterations {} residual_rms_m {:.4} inlier_ratio {:.3} degenerate {} ms {ms:.2}",
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
