//! `robot-agent map`: evaluate the traversability mapper in the simulator, replay recorded
//! sequences (KITTI layout) through it, and render the grid.

use anyhow::{bail, Context};
use common::grid::encode_tile;
use mapping::render::render_png;
use mapping::{Config, Mapper, RobotPose};
use sensing::{pcd, sequence, Scan};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `robot-agent map`.
#[derive(Debug, clap::Args)]
pub struct MapArgs {
    #[command(subcommand)]
    command: MapCommand,
}

#[derive(Debug, clap::Subcommand)]
enum MapCommand {
    /// Drive a scenario in the simulator and score the grid against the world's truth labels.
    /// Last line: `cells N accuracy A obstacle_recall R false_obstacle_rate F curb5_10_recall C
    /// ms_per_update T`.
    Eval(EvalArgs),
    /// Drive a scenario in the simulator and draw the grid as a PNG.
    Render(RenderArgs),
    /// Build the grid from a recorded folder (clouds/NNN.pcd + poses.txt) and draw it.
    Replay(ReplayArgs),
}

#[derive(Debug, clap::Args)]
struct EvalArgs {
    /// Scenario TOML (config/scenarios/*.toml).
    #[arg(long)]
    scenario: PathBuf,
    /// Map with the simulator's true poses instead of SLAM.
    #[arg(long)]
    use_truth_poses: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
    /// Mapper configuration (TOML); defaults (config/mapper.toml values) when absent.
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct RenderArgs {
    /// Scenario TOML.
    #[arg(long)]
    scenario: PathBuf,
    /// Output PNG.
    #[arg(long)]
    png: PathBuf,
    /// Mapper configuration (TOML).
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Sequence folder laid out like ../shared/data/lidar/kitti-seq.
    dir: PathBuf,
    /// Use the folder's poses.txt (the default).
    #[arg(long, conflicts_with = "slam")]
    truth_poses: bool,
    /// Estimate the poses with the `slam` crate instead of reading poses.txt.
    #[arg(long)]
    slam: bool,
    /// SLAM configuration (TOML) for --slam.
    #[arg(long)]
    slam_config: Option<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    png: PathBuf,
    /// LiDAR height above the ground, metres (overrides the config's sensor_height_m).
    #[arg(long)]
    sensor_height: Option<f64>,
    /// Mapper configuration (TOML), e.g. config/mapper-car.toml for KITTI.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Use only the first N scans.
    #[arg(long)]
    frames: Option<usize>,
    /// Pixels per cell in the PNG.
    #[arg(long, default_value_t = 3)]
    px: u32,
    /// Scan period, seconds, when the folder has no stamps.txt.
    #[arg(long, default_value_t = 0.1)]
    period: f64,
}

/// Runs `robot-agent map`.
pub fn run(args: MapArgs) -> anyhow::Result<()> {
    match args.command {
        MapCommand::Eval(a) => eval(a),
        MapCommand::Render(a) => render(a),
        MapCommand::Replay(a) => replay(a),
    }
}

fn load_config(path: Option<&Path>) -> anyhow::Result<Config> {
    let Some(p) = path else {
        return Ok(Config::default());
    };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    let cfg: Config = toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?;
    cfg.validate()?;
    Ok(cfg)
}

fn eval(a: EvalArgs) -> anyhow::Result<()> {
    let _ = (
        &a.scenario,
        a.use_truth_poses,
        a.json,
        load_config(a.config.as_deref())?,
    );
    bail!(
        "map eval: the simulator crate does not expose its driving API yet (sim::Simulation::new, \
         step, sim::drive::PathDriver); the mapper side is ready, see `map replay` for real data"
    )
}

fn render(a: RenderArgs) -> anyhow::Result<()> {
    let _ = (&a.scenario, &a.png, load_config(a.config.as_deref())?);
    bail!("map render: the simulator crate does not expose its driving API yet; use `map replay DIR --png OUT` on a recorded folder")
}

fn replay(a: ReplayArgs) -> anyhow::Result<()> {
    let mut cfg = load_config(a.config.as_deref())?;
    if let Some(h) = a.sensor_height {
        cfg.sensor_height_m = h;
    }
    cfg.validate()?;
    let files = sequence::cloud_files(&a.dir)?;
    let n = a.frames.unwrap_or(files.len()).min(files.len());
    let stamps = sequence::read_stamps(&a.dir)?;
    let truth = if a.slam {
        None
    } else {
        Some(sequence::read_poses(&a.dir)?)
    };
    if let Some(t) = &truth {
        if t.len() < n {
            bail!("{} has {} poses for {} scans", a.dir.display(), t.len(), n);
        }
    }
    let mut slam = if a.slam {
        let scfg = match &a.slam_config {
            Some(p) => toml::from_str::<slam::Config>(
                &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            )
            .with_context(|| format!("parsing {}", p.display()))?,
            None => slam::Config::default(),
        };
        Some(slam::Slam::new(scfg))
    } else {
        None
    };
    let mut mapper = Mapper::new(cfg.clone())?;
    let (mut ms_total, mut ms_max, mut tiles_out, mut bytes_out) = (0.0f64, 0.0f64, 0usize, 0usize);
    let mut path = Vec::new();
    for (i, f) in files.iter().take(n).enumerate() {
        let t_s = stamps
            .as_ref()
            .and_then(|s| s.get(i).copied())
            .unwrap_or(i as f64 * a.period);
        let mut scan = Scan {
            stamp_s: t_s,
            points: pcd::read_pcd(f).with_context(|| format!("reading {}", f.display()))?,
        };
        let bad = scan.retain_finite();
        if bad > 0 {
            tracing::debug!(scan = i, bad, "non-finite points dropped");
        }
        let pose = match (&truth, &mut slam) {
            (Some(t), _) => t[i],
            (None, Some(s)) => {
                s.process(&scan)
                    .with_context(|| format!("slam on scan {i}"))?
                    .pose_map_lidar
            }
            (None, None) => unreachable!("either poses or slam"),
        };
        let robot = RobotPose::from_sensor_pose(&pose, cfg.sensor_height_m);
        path.push((robot.x_m, robot.y_m));
        let t0 = Instant::now();
        let rep = mapper.update_scan(&scan, &pose, &robot, t_s)?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        ms_total += ms;
        ms_max = ms_max.max(ms);
        tiles_out += rep.tiles.len();
        bytes_out += rep
            .tiles
            .iter()
            .map(|t| encode_tile(t).len())
            .sum::<usize>();
        tracing::debug!(
            scan = i,
            ms,
            dirty = rep.dirty_cells,
            classified = rep.classified_cells,
            tiles = rep.tiles.len(),
            "update"
        );
    }
    let file =
        std::fs::File::create(&a.png).with_context(|| format!("creating {}", a.png.display()))?;
    let (w, h) = render_png(&mapper, None, a.px, &path, std::io::BufWriter::new(file))?;
    let tiles = mapper.tiles();
    let (mut trav, mut obst, mut infl) = (0usize, 0usize, 0usize);
    for t in &tiles {
        for c in &t.cells {
            match c.state {
                common::grid::CellState::Traversable => trav += 1,
                common::grid::CellState::Obstacle => obst += 1,
                common::grid::CellState::Inflated => infl += 1,
                _ => {}
            }
        }
    }
    let sizes: Vec<usize> = tiles.iter().map(|t| encode_tile(t).len()).collect();
    let mean_b = sizes.iter().sum::<usize>() as f64 / sizes.len().max(1) as f64;
    println!("png {} ({w}x{h})", a.png.display());
    println!(
        "scans {n} traversable {trav} obstacle {obst} inflated {infl} tiles {} mean_tile_bytes {mean_b:.0} tiles_out {tiles_out} bytes_out {bytes_out} ms_per_update {:.2} ms_max {:.2}",
        tiles.len(),
        ms_total / n.max(1) as f64,
        ms_max
    );
    Ok(())
}
