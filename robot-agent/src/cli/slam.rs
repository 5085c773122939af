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
    /// Sequence folder (clouds/NNN.pcd, poses.txt, optional stamps.txt, odom.txt, meta.toml
    /// with the lidar extrinsic, walkers.txt).
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

/// Walker scoring: how much of the walkers ends up in the map, and whether it stays there.
///
/// A map point is a walker point when, traced back to the world through the scan that inserted
/// it ([`slam::Provenance`]), it lies in a walker's body during that scan's sweep (the ground
/// under the feet excluded). At a checkpoint, a walker point is "left" when it is still in the
/// map though it was seen at least [`WALKER_GRACE_S`] ago, no walker is there now, and the
/// sensor has had a clear view of the spot for the last [`WALKER_VIEW_S`]: at every look a laser
/// of the (true) sensor passed within [`WALKER_SEEN_M`] of it with nothing in between, per a ray
/// cast in the scenario's world with the recorded walkers. Points no laser could look at (behind
/// a walker walking toward the sensor, or in the gap between two lasers) are reported apart.
struct WalkerScore {
    world: sim::World,
    /// Recorded walker states (`walkers.txt`): per time, every walker.
    track: Vec<(f64, Vec<sim::WalkerState>)>,
    /// Map points inserted from walker returns, over the run.
    inserted: usize,
    /// Walker points left in the map at the last checkpoint.
    left_final: usize,
    /// The most there ever were at a checkpoint, and when.
    left_max: (usize, f64),
    /// Walker points the sensor could not look at, at the last checkpoint (not counted as left).
    unseen_final: usize,
    next_check_s: f64,
}

/// Age a walker point must reach before it counts as left, seconds.
const WALKER_GRACE_S: f64 = 3.0;
/// How long the sensor must have had a clear view of a spot before a point there counts, s.
const WALKER_VIEW_S: f64 = 1.5;
/// A laser passing this close to a spot looks at it (a person there would have been hit), m.
const WALKER_SEEN_M: f64 = 0.1;
/// Margin around a walker's body (sweep motion, range noise, pose error), metres.
const WALKER_MARGIN_M: f64 = 0.1;
/// Points lower than this above a walker's ground are ground under its feet, not the walker.
const WALKER_MIN_HEIGHT_M: f64 = 0.2;
/// Checkpoint period of the leftover count, seconds.
const WALKER_CHECK_S: f64 = 10.0;
/// Sweep duration assumed for a scan's points (they are seen over [stamp, stamp + this]).
const SWEEP_S: f64 = 0.1;

fn read_walkers(dir: &Path) -> anyhow::Result<Vec<(f64, Vec<sim::WalkerState>)>> {
    let p = dir.join("walkers.txt");
    let text = std::fs::read_to_string(&p).with_context(|| {
        format!(
            "reading {} (--scenario scores the walkers recorded by `robot-agent sim --record`)",
            p.display()
        )
    })?;
    let mut track: Vec<(f64, Vec<sim::WalkerState>)> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("{} line {}", p.display(), n + 1))?;
        let [t, id, x, y, z, r, h] = v[..] else {
            bail!("{} line {}: want 7 numbers", p.display(), n + 1);
        };
        let w = sim::WalkerState {
            id: id as usize,
            x_m: x,
            y_m: y,
            z_m: z,
            radius_m: r,
            height_m: h,
        };
        match track.last_mut() {
            Some((lt, ws)) if (*lt - t).abs() < 1e-9 => ws.push(w),
            _ => track.push((t, vec![w])),
        }
    }
    Ok(track)
}

impl WalkerScore {
    fn new(scenario: &Path, dir: &Path) -> anyhow::Result<Self> {
        let sc = sim::Scenario::load(scenario)?;
        Ok(Self {
            world: sim::World::new(&sc),
            track: read_walkers(dir)?,
            inserted: 0,
            left_final: 0,
            left_max: (0, 0.0),
            unseen_final: 0,
            next_check_s: WALKER_CHECK_S,
        })
    }

    /// Walkers at `t_s`, interpolated between recorded states (same walkers in each record).
    fn walkers_at(&self, t_s: f64) -> Vec<sim::WalkerState> {
        let i = self.track.partition_point(|(t, _)| *t < t_s);
        match (
            i.checked_sub(1).and_then(|j| self.track.get(j)),
            self.track.get(i),
        ) {
            (Some((ta, a)), Some((tb, b))) if a.len() == b.len() && tb > ta => {
                let f = (t_s - ta) / (tb - ta);
                a.iter()
                    .zip(b)
                    .map(|(p, q)| sim::WalkerState {
                        x_m: p.x_m + f * (q.x_m - p.x_m),
                        y_m: p.y_m + f * (q.y_m - p.y_m),
                        z_m: p.z_m + f * (q.z_m - p.z_m),
                        ..*p
                    })
                    .collect()
            }
            (_, Some((_, b))) => b.clone(),
            (Some((_, a)), None) => a.clone(),
            (None, None) => Vec::new(),
        }
    }

    fn bodies(&self, t_s: f64, extra_m: f64) -> Vec<slam::Cylinder> {
        self.walkers_at(t_s)
            .iter()
            .map(|w| slam::Cylinder {
                x_m: w.x_m,
                y_m: w.y_m,
                z_min_m: w.z_m + WALKER_MIN_HEIGHT_M,
                z_max_m: w.z_m + w.height_m + WALKER_MARGIN_M + extra_m,
                radius_m: w.radius_m + WALKER_MARGIN_M + extra_m,
            })
            .collect()
    }

    /// Walker bodies over a scan's sweep.
    fn swept(&self, t_s: f64) -> Vec<slam::Cylinder> {
        [t_s, t_s + SWEEP_S]
            .iter()
            .flat_map(|t| self.bodies(*t, 0.0))
            .collect()
    }

    /// Counts the map points inserted by the scan stamped `t_s` that came from walkers.
    fn count_inserted(&mut self, map: &slam::map::Map, prov: &slam::Provenance, t_s: f64) {
        let bodies = self.swept(t_s);
        let pts = &map.cloud().points;
        let stamps = map.stamps();
        self.inserted += (0..pts.len())
            .rev()
            .take_while(|i| stamps[*i] == t_s)
            .filter_map(|i| prov.world(&pts[i], t_s))
            .filter(|w| bodies.iter().any(|c| c.contains(w)))
            .count();
    }

    /// True when a laser of the sensor at `lidar` (true pose, time `t_s`) passed within
    /// [`WALKER_SEEN_M`] of `w` with nothing in between.
    fn looked_at(&self, lidar: &Isometry3<f64>, w: &nalgebra::Vector3<f64>, t_s: f64) -> bool {
        let q = lidar.inverse() * nalgebra::Point3::from(*w);
        let r = q.coords.norm();
        if r < 0.5 {
            return false;
        }
        let el = (q.z / r).asin();
        let az = q.y.atan2(q.x);
        let walkers = self.bodies(t_s, 0.0);
        sim::sensors::VLP16_ELEVATIONS_DEG.iter().any(|e| {
            let e = e.to_radians();
            if (e - el).abs() * r > WALKER_SEEN_M {
                return false;
            }
            let d = lidar.rotation
                * nalgebra::Vector3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin());
            let o = nalgebra::Point3::from(lidar.translation.vector);
            let end = o + d * (r - 0.3);
            self.static_clear(&o, &d, r - 0.3, t_s)
                && !walkers.iter().any(|c| blocks(c, &o.coords, &end.coords))
        })
    }

    /// True when nothing static lies along `d` from `o` within `range_m` (the world's own walkers
    /// follow their scripts, not the recorded positions, and are stepped through).
    fn static_clear(
        &self,
        o: &nalgebra::Point3<f64>,
        d: &nalgebra::Vector3<f64>,
        range_m: f64,
        t_s: f64,
    ) -> bool {
        let mut start = 0.0;
        while start < range_m {
            let from = o + d * start;
            match self.world.raycast(&from, d, range_m - start, t_s) {
                None => return true,
                Some(h) if matches!(h.kind, sim::HitKind::Walker(_)) => start += h.range_m + 0.6,
                Some(_) => return false,
            }
        }
        true
    }

    /// Walker points left at `now_s`, and those the sensor could not look at; `lidar_at` is
    /// the true sensor pose at a time.
    fn left(
        &self,
        map: &slam::map::Map,
        prov: &slam::Provenance,
        now_s: f64,
        lidar_at: impl Fn(f64) -> Isometry3<f64>,
    ) -> (usize, usize) {
        let now: Vec<_> = [now_s - SWEEP_S, now_s, now_s + SWEEP_S]
            .iter()
            .flat_map(|t| self.bodies(*t, 0.2))
            .collect();
        let views: Vec<(f64, Isometry3<f64>)> = (0..=(WALKER_VIEW_S / 0.5).round() as usize)
            .map(|j| now_s - 0.5 * j as f64)
            .map(|t| (t, lidar_at(t)))
            .collect();
        // Walker bodies per insertion stamp: map points come in batches of one scan each.
        let mut at: std::collections::HashMap<u64, Vec<slam::Cylinder>> = Default::default();
        let (mut left, mut unseen) = (0, 0);
        for (p, t) in map.cloud().points.iter().zip(map.stamps()) {
            if *t > now_s - WALKER_GRACE_S {
                continue;
            }
            let Some(w) = prov.world(p, *t) else { continue };
            let then = at.entry(t.to_bits()).or_insert_with(|| self.swept(*t));
            if !then.iter().any(|c| c.contains(&w)) || now.iter().any(|c| c.contains(&w)) {
                continue;
            }
            if views.iter().all(|(t, lidar)| self.looked_at(lidar, &w, *t)) {
                left += 1;
            } else {
                unseen += 1;
            }
        }
        (left, unseen)
    }

    fn check(
        &mut self,
        map: &slam::map::Map,
        prov: &slam::Provenance,
        now_s: f64,
        last: bool,
        lidar_at: impl Fn(f64) -> Isometry3<f64>,
    ) {
        if !last && now_s < self.next_check_s {
            return;
        }
        self.next_check_s = now_s + WALKER_CHECK_S;
        let (n, unseen) = self.left(map, prov, now_s, lidar_at);
        self.left_final = n;
        self.unseen_final = unseen;
        if n > self.left_max.0 {
            self.left_max = (n, now_s);
        }
    }
}

/// True when the body `c` stands on the line of sight from `s` to `w`.
fn blocks(c: &slam::Cylinder, s: &nalgebra::Vector3<f64>, w: &nalgebra::Vector3<f64>) -> bool {
    let d = w - s;
    let len2 = d.x * d.x + d.y * d.y;
    if len2 < 1e-9 {
        return false;
    }
    // Closest approach of the horizontal projection to the axis.
    let u = (((c.x_m - s.x) * d.x + (c.y_m - s.y) * d.y) / len2).clamp(0.0, 1.0);
    let (x, y, z) = (s.x + u * d.x, s.y + u * d.y, s.z + u * d.z);
    (x - c.x_m).hypot(y - c.y_m) <= c.radius_m
        && z >= c.z_min_m - WALKER_MIN_HEIGHT_M
        && z <= c.z_max_m
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
        None => print_summary(&errors, ms, a.json),
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
