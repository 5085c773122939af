//! `robot-agent map`: evaluate the traversability mapper in the simulator, replay recorded
//! sequences (KITTI layout) through it, and render the grid.

use crate::run::map_eval;
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
    /// Scenario TOML (config/scenarios/*.toml); its `[drive]` polyline is driven.
    #[arg(long)]
    scenario: PathBuf,
    /// Map with the simulator's true poses instead of SLAM.
    #[arg(long)]
    use_truth_poses: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
    /// Run the pose graph (`on`) or not (`off`) whatever `[graph] enabled` in
    /// config/slam.toml says.
    #[arg(long, value_name = "on|off", value_parser = parse_on_off)]
    graph: Option<bool>,
    /// Mapper configuration (TOML); config/mapper.toml when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Stop after this much simulated time, seconds.
    #[arg(long, default_value_t = 1200.0)]
    max_duration: f64,
    /// Also draw the final grid into this PNG.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Draw the wrong cells into this PNG: missed solids red, missed steps orange, missed
    /// slopes yellow, missed holes magenta, false obstacles blue, false drop-offs cyan, correct
    /// observed cells grey.
    #[arg(long)]
    errors_png: Option<PathBuf>,
    /// Print the mapper's evidence and verdicts around these map points (`X,Y`, repeatable):
    /// why a cell is what it is.
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    probe: Vec<String>,
    /// Trace the cell at these map points (`X,Y`, repeatable) through the drive: a line on
    /// stderr whenever its evidence, verdict or class changes, with the time and the pose.
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    trace: Vec<String>,
    /// Write every published tile, exact, into this folder (created): a corpus for tile codec
    /// work (`cargo test --release -p common -- --ignored corpus`).
    #[arg(long, value_name = "DIR")]
    tiles_out: Option<PathBuf>,
    /// With the pose graph on: also map its kept sweeps again at the poses the final map has
    /// them at and score that map (`rebuild_check` in the JSON): what a rebuild loses when
    /// nothing moved.
    #[arg(long)]
    rebuild_check: bool,
    /// Also map every sweep at its true pose into a second map, and report how far each pole
    /// and trunk lies from where that map puts it (`obstacle_shifts` in the JSON): the
    /// robot's localisation's share of the position error, without the one-sided-view floor
    /// of the distance to the true centre. Costs a second map update per sweep.
    #[arg(long, conflicts_with = "use_truth_poses")]
    truth_twin: bool,
    /// After the drive, stand still for at most this long while a map rebuild after a pose
    /// graph correction is under way, so the map scored is the corrected one, seconds (0: score
    /// the map as the drive ends).
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    settle_max: f64,
}

#[derive(Debug, clap::Args)]
struct RenderArgs {
    /// Scenario TOML; its `[drive]` polyline is driven and mapped.
    #[arg(long)]
    scenario: PathBuf,
    /// Output PNG.
    #[arg(long)]
    png: PathBuf,
    /// Mapper configuration (TOML); config/mapper.toml when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Map with the simulator's true poses instead of SLAM.
    #[arg(long)]
    use_truth_poses: bool,
    /// Pixels per cell.
    #[arg(long, default_value_t = 3)]
    px: u32,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
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

fn eval_options(
    scenario: &Path,
    config: Option<&Path>,
    use_truth_poses: bool,
    seed: u64,
) -> anyhow::Result<(sim::Scenario, map_eval::MapEvalOptions)> {
    let scenario = sim::Scenario::load(scenario)?;
    let dir = crate::config::default_config_dir();
    let agent = crate::config::load_agent_config(&dir)
        .with_context(|| format!("loading {}", dir.display()))?;
    let agent = match config {
        Some(f) => agent.with_mapper(load_config(Some(f))?),
        None => agent,
    };
    let opts = map_eval::MapEvalOptions {
        seed,
        use_truth_poses,
        agent,
        ..Default::default()
    };
    Ok((scenario, opts))
}

fn run_eval(
    scenario: &sim::Scenario,
    opts: &map_eval::MapEvalOptions,
) -> anyhow::Result<(map_eval::MapEvalReport, Mapper)> {
    let bar = indicatif::ProgressBar::new(100);
    bar.set_style(
        indicatif::ProgressStyle::with_template("map eval {bar:40} {pos}% {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let r = map_eval::run(scenario, opts, |p| {
        bar.set_position((p.done * 100.0) as u64);
        bar.set_message(format!("{:.0} s simulated", p.t_s));
    });
    bar.finish_and_clear();
    r
}

fn draw(mapper: &Mapper, png: &Path, px: u32) -> anyhow::Result<(u32, u32)> {
    let file = std::fs::File::create(png).with_context(|| format!("creating {}", png.display()))?;
    Ok(render_png(
        mapper,
        None,
        px,
        &[],
        std::io::BufWriter::new(file),
    )?)
}

/// The wrong cells over the observed ones, 3 px per cell, north up.
fn draw_errors(mapper: &Mapper, r: &map_eval::MapEvalReport, png: &Path) -> anyhow::Result<()> {
    use map_eval::ErrorKind as K;
    let ((x0, y0), (x1, y1)) = mapper.bounds().context("the map is empty")?;
    let (w, h) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
    let px = 3usize;
    let mut img = vec![24u8; w * h * px * px * 3];
    let mut put = |cx: i64, cy: i64, rgb: [u8; 3]| {
        let (i, j) = ((cx - x0) as usize, (y1 - cy) as usize);
        for dy in 0..px {
            for dx in 0..px {
                let o = ((j * px + dy) * w * px + i * px + dx) * 3;
                img[o..o + 3].copy_from_slice(&rgb);
            }
        }
    };
    for cy in y0..=y1 {
        for cx in x0..=x1 {
            match mapper.class(cx, cy) {
                mapping::Class::Traversable => put(cx, cy, [70, 70, 70]),
                mapping::Class::Obstacle | mapping::Class::NegativeObstacle => {
                    put(cx, cy, [130, 130, 130])
                }
                _ => {}
            }
        }
    }
    for &(cx, cy, k) in &r.error_cells {
        let rgb = match k {
            K::MissedSolid => [230, 30, 30],
            K::MissedStep => [255, 150, 0],
            K::MissedSlope => [240, 240, 0],
            K::MissedHole => [230, 0, 230],
            K::FalseObstacle => [40, 110, 255],
            K::FalseNegativeObstacle => [0, 230, 230],
        };
        put(cx, cy, rgb);
    }
    let file = std::fs::File::create(png).with_context(|| format!("creating {}", png.display()))?;
    let mut enc = png::Encoder::new(
        std::io::BufWriter::new(file),
        (w * px) as u32,
        (h * px) as u32,
    );
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()?.write_image_data(&img)?;
    print_error_clusters(mapper, &r.error_cells);
    Ok(())
}

/// Prints the largest groups of wrong cells (8-connected, same kind) with where they are, so a
/// user can `--probe` them: the picture says what went wrong, this says where to look.
fn print_error_clusters(mapper: &Mapper, cells: &[(i64, i64, map_eval::ErrorKind)]) {
    use std::collections::HashMap;
    let kind_of: HashMap<(i64, i64), map_eval::ErrorKind> =
        cells.iter().map(|&(x, y, k)| ((x, y), k)).collect();
    let mut seen = std::collections::HashSet::new();
    let mut groups: Vec<(map_eval::ErrorKind, Vec<(i64, i64)>)> = Vec::new();
    for &(x, y, k) in cells {
        if !seen.insert((x, y)) {
            continue;
        }
        let mut members = vec![(x, y)];
        let mut i = 0;
        while i < members.len() {
            let (cx, cy) = members[i];
            i += 1;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let n = (cx + dx, cy + dy);
                    if kind_of.get(&n) == Some(&k) && seen.insert(n) {
                        members.push(n);
                    }
                }
            }
        }
        groups.push((k, members));
    }
    groups.sort_by_key(|g| std::cmp::Reverse(g.1.len()));
    let lattice = mapper.lattice();
    eprintln!("largest groups of wrong cells, at most 12 of each kind (kind, cells, centre x,y m, extent m):");
    let mut shown: HashMap<map_eval::ErrorKind, usize> = HashMap::new();
    for (k, m) in &groups {
        let c = shown.entry(*k).or_default();
        *c += 1;
        if *c > 12 {
            continue;
        }
        let pts: Vec<(f64, f64)> = m
            .iter()
            .map(|&(x, y)| lattice.cell_center_m(x, y))
            .collect();
        let n = pts.len() as f64;
        let (mx, my) = pts
            .iter()
            .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
        let (x0, x1) = pts
            .iter()
            .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.0), a.1.max(p.0)));
        let (y0, y1) = pts
            .iter()
            .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
        eprintln!(
            "  {k:?} {} at {mx:.1},{my:.1} ({:.1} x {:.1})",
            m.len(),
            x1 - x0,
            y1 - y0
        );
    }
}

/// Prints a 7 x 7 block of cells around a map point: class, verdict, evidence, truth.
fn probe(
    mapper: &Mapper,
    scenario: &sim::Scenario,
    opts: &map_eval::MapEvalOptions,
    at: &str,
) -> anyhow::Result<()> {
    let (px, py) = parse_xy("--probe", at)?;
    let lattice = mapper.lattice();
    let (cx, cy) = lattice.cell_of(px, py);
    let world = sim::World::new(scenario);
    let truth = world.truth_labels(
        &lattice,
        cx - 3,
        cy - 3,
        7,
        7,
        &sim::LabelParams::from_profile(&opts.agent.profile),
    );
    eprintln!("probe ({px}, {py}) = cell ({cx}, {cy}); rows north to south");
    for y in (cy - 3..=cy + 3).rev() {
        for x in cx - 3..=cx + 3 {
            let st = mapper.height_stats(x, y);
            let t = truth.get(x, y).copied().unwrap_or_default();
            eprintln!(
                "  ({x:4},{y:4}) {:<13} {:<13} n {:3} mean {:7.3} sd {:.3} max {:7.3} | truth {:?} reasons {} step {:.3} h {:.3}",
                format!("{:?}", mapper.class(x, y)),
                format!("{:?}", mapper.explain(x, y)),
                st.n,
                st.mean_m,
                st.var_m2.sqrt(),
                st.max_m,
                t.state,
                t.reasons,
                t.step_m,
                t.height_m
            );
        }
        eprintln!();
    }
    eprintln!("  centre: {}", mapper.describe(cx, cy));
    eprintln!();
    Ok(())
}

/// A map point `X,Y` given to option `opt`.
fn parse_xy(opt: &str, at: &str) -> anyhow::Result<(f64, f64)> {
    let v: Vec<f64> = at
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{opt} {at:?}: want X,Y"))?;
    anyhow::ensure!(v.len() == 2, "{opt} {at:?}: want X,Y");
    Ok((v[0], v[1]))
}

/// `on` / `off` (also `true` / `false`).
pub(super) fn parse_on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" | "true" => Ok(true),
        "off" | "false" => Ok(false),
        _ => Err(format!("expected on or off, got {s:?}")),
    }
}

fn eval(a: EvalArgs) -> anyhow::Result<()> {
    let (scenario, mut opts) =
        eval_options(&a.scenario, a.config.as_deref(), a.use_truth_poses, a.seed)?;
    opts.max_duration_s = a.max_duration;
    opts.trace_cells = a
        .trace
        .iter()
        .map(|t| parse_xy("--trace", t))
        .collect::<anyhow::Result<_>>()?;
    if let Some(on) = a.graph {
        opts.agent.slam.graph.enabled = on;
    }
    opts.rebuild_check = a.rebuild_check;
    opts.truth_twin = a.truth_twin;
    opts.settle_max_s = a.settle_max;
    if let Some(dir) = &a.tiles_out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        opts.tiles_out = Some(dir.clone());
    }
    let (r, mapper) = run_eval(&scenario, &opts)?;
    if let Some(png) = &a.png {
        draw(&mapper, png, 3)?;
    }
    if let Some(png) = &a.errors_png {
        draw_errors(&mapper, &r, png)?;
    }
    for p in &a.probe {
        probe(&mapper, &scenario, &opts, p)?;
    }
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
    } else {
        eprintln!(
            "{}: {} scans over {:.0} m in {:.0} s; {} curb cells, {} undecided; walker cells {} ({} still obstacles); tiles {} ({:.0} B mean, {:.0} B/s); SLAM failures {} max error {:.3} m (z {:.3} m, tilt {:.2} deg max {:.3} mean); collisions {}",
            r.scenario, r.scans, r.path_m, r.duration_s, r.curb_cells, r.undecided_cells,
            r.walker_cells, r.walker_false_obstacles, r.tiles_published, r.mean_tile_bytes,
            r.tile_bytes_per_s, r.slam_failures, r.slam_max_error_m, r.slam_max_z_error_m,
            r.slam_max_tilt_error_deg, r.slam_mean_tilt_error_deg, r.collisions
        );
        eprintln!(
            "errors: {:?}; overhung {} cleared {} ceiling-wiped {} one-sided steps {}",
            r.errors, r.overhung_cells, r.cleared_cells, r.ceiling_wiped_cells, r.one_sided_steps
        );
        let o = &r.obstacle_positions;
        eprintln!(
            "poles and trunks: {} of {} found, centroid error mean {:.3} m median {:.3} m max {:.3} m, cells {:.3} m from the surface; raised cells only: {} found, mean {:.3} m median {:.3} m max {:.3} m; graph {:?}",
            o.found, o.objects, o.mean_error_m, o.median_error_m, o.max_error_m,
            o.mean_surface_distance_m, o.body.found, o.body.mean_error_m,
            o.body.median_error_m, o.body.max_error_m, r.graph
        );
        if let Some(s) = &r.obstacle_shifts {
            eprintln!(
                "against the same sweeps at their true poses: {} compared, shift mean {:.3} m median {:.3} m max {:.3} m; raised cells: {} compared, mean {:.3} m median {:.3} m max {:.3} m",
                s.all.compared, s.all.mean_shift_m, s.all.median_shift_m, s.all.max_shift_m, s.body.compared,
                s.body.mean_shift_m, s.body.median_shift_m, s.body.max_shift_m
            );
        }
        println!(
            "cells {} accuracy {:.4} obstacle_recall {:.4} false_obstacle_rate {:.4} curb5_10_recall {:.4} ms_per_update {:.2}",
            r.cells, r.accuracy, r.obstacle_recall, r.false_obstacle_rate, r.curb5_10_recall, r.ms_per_update
        );
    }
    Ok(())
}

fn render(a: RenderArgs) -> anyhow::Result<()> {
    let (scenario, opts) =
        eval_options(&a.scenario, a.config.as_deref(), a.use_truth_poses, a.seed)?;
    let (r, mapper) = run_eval(&scenario, &opts)?;
    let (w, h) = draw(&mapper, &a.png, a.px)?;
    println!(
        "{}",
        serde_json::json!({"scenario": r.scenario, "png": a.png.display().to_string(), "width_px": w, "height_px": h, "scans": r.scans})
    );
    Ok(())
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
    let mut publisher = crate::bus::tiles::TilePublisher::new(
        crate::bus::tiles::TilePolicy::default(),
        mapper.lattice(),
        0,
    );
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
        let published = publisher.publish(t_s, &rep.changed_tiles, |t| mapper.tile_cells(t), false);
        tiles_out += published.len();
        bytes_out += published
            .iter()
            .map(|t| encode_tile(t).len())
            .sum::<usize>();
        tracing::debug!(
            scan = i,
            ms,
            dirty = rep.dirty_cells,
            classified = rep.classified_cells,
            tiles = published.len(),
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
