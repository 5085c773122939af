//! Writes a simulated run as a sequence folder (layout of `sensing::sequence`): `clouds/NNN.pcd`
//! (sensor frame, swept: per-point `t` relative to the scan stamp), `poses.txt` (truth pose of the
//! LiDAR frame in the map frame at each scan's stamp = its first column), `stamps.txt`,
//! `odom.txt`, `nmea.log` (`t_s sentence`), `depth/NNN.pcd` when depth frames are recorded,
//! `walkers.txt` (truth: `t_s id x_m y_m z_m radius_m height_m` for every walker each time a scan
//! completes; walkers that wait for the robot fall behind their scripts, so tools scoring
//! dynamic-point removal need their real positions) and `meta.toml`. An I/O helper for tools and tests, not used by the simulation itself.

use crate::simulation::{Simulation, StepOutput};
use nalgebra::Isometry3;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An open recording.
pub struct Recorder {
    dir: PathBuf,
    scans: usize,
    depth_frames: usize,
    record_depth: bool,
    poses: BufWriter<File>,
    stamps: BufWriter<File>,
    odom: BufWriter<File>,
    nmea: BufWriter<File>,
    walkers: BufWriter<File>,
    collisions: u64,
}

fn create(p: &Path) -> std::io::Result<BufWriter<File>> {
    Ok(BufWriter::new(File::create(p)?))
}

impl Recorder {
    /// Creates the folder (and `clouds/`); `record_depth` also writes depth frames.
    pub fn create(dir: impl AsRef<Path>, record_depth: bool) -> std::io::Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        std::fs::create_dir_all(dir.join("clouds"))?;
        if record_depth {
            std::fs::create_dir_all(dir.join("depth"))?;
        }
        Ok(Self {
            scans: 0,
            depth_frames: 0,
            record_depth,
            poses: create(&dir.join("poses.txt"))?,
            stamps: create(&dir.join("stamps.txt"))?,
            odom: create(&dir.join("odom.txt"))?,
            nmea: create(&dir.join("nmea.log"))?,
            walkers: create(&dir.join("walkers.txt"))?,
            collisions: 0,
            dir,
        })
    }

    /// Scans written so far.
    pub fn scans(&self) -> usize {
        self.scans
    }

    /// Records one step's output (call right after `sim.step`).
    pub fn write_step(&mut self, sim: &Simulation, out: &StepOutput) -> std::io::Result<()> {
        if let Some(scan) = &out.scan {
            let base = sim
                .truth_pose_at(scan.stamp_s)
                .unwrap_or_else(|| sim.truth_pose());
            let lidar: Isometry3<f64> = base * sim.lidar_extrinsic();
            sensing::pcd::write_pcd(
                self.dir
                    .join("clouds")
                    .join(format!("{:03}.pcd", self.scans)),
                &scan.points,
            )?;
            writeln!(self.poses, "{}", sensing::sequence::format_pose(&lidar))?;
            writeln!(self.stamps, "{:.6}", scan.stamp_s)?;
            for w in sim.walkers() {
                writeln!(
                    self.walkers,
                    "{:.6} {} {:.4} {:.4} {:.4} {:.3} {:.3}",
                    sim.time_s(),
                    w.id,
                    w.x_m,
                    w.y_m,
                    w.z_m,
                    w.radius_m,
                    w.height_m
                )?;
            }
            self.scans += 1;
        }
        if let (true, Some(d)) = (self.record_depth, &out.depth) {
            sensing::pcd::write_pcd(
                self.dir
                    .join("depth")
                    .join(format!("{:03}.pcd", self.depth_frames)),
                &d.points,
            )?;
            self.depth_frames += 1;
        }
        if let Some(o) = &out.odom {
            writeln!(self.odom, "{}", sensing::sequence::format_odometry(o))?;
        }
        for g in &out.gnss {
            writeln!(self.nmea, "{:.3} {}", g.t_s, g.text)?;
        }
        self.collisions += out.collisions.len() as u64;
        Ok(())
    }

    /// Writes `meta.toml` and flushes everything.
    pub fn finish(mut self, sim: &Simulation) -> std::io::Result<()> {
        self.poses.flush()?;
        self.stamps.flush()?;
        self.odom.flush()?;
        self.nmea.flush()?;
        self.walkers.flush()?;
        let ex = sim.lidar_extrinsic();
        let (r, p, y) = ex.rotation.euler_angles();
        let t = ex.translation.vector;
        let dex = sim.depth_extrinsic();
        let (dr, dp, dy) = dex.rotation.euler_angles();
        let dt = dex.translation.vector;
        let d = sim.datum();
        let meta = format!(
            "# Simulated recording (robot-agent sim). Poses: LiDAR frame in the map frame (ENU at the datum)\n\
             # at each scan's stamp (its first column); scans are swept (per-point t), not de-skewed.\n\
             scenario = \"{}\"\nseed = {}\nscans = {}\ndepth_frames = {}\nduration_s = {:.3}\ncollisions = {}\n\
             pose_time = \"scan_start\"\n\n[datum]\nlat_deg = {:.9}\nlon_deg = {:.9}\nh_m = {:.3}\n\n\
             [lidar_extrinsic]  # base_link <- lidar\nxyz_m = [{:.4}, {:.4}, {:.4}]\nrpy_rad = [{:.6}, {:.6}, {:.6}]\n\n\
             [depth_extrinsic]  # base_link <- depth camera (x forward, y left, z up)\nxyz_m = [{:.4}, {:.4}, {:.4}]\nrpy_rad = [{:.6}, {:.6}, {:.6}]\n",
            sim.scenario_name(),
            sim.config().seed,
            self.scans,
            self.depth_frames,
            sim.time_s(),
            self.collisions,
            d.lat_deg,
            d.lon_deg,
            d.h_m,
            t.x,
            t.y,
            t.z,
            r,
            p,
            y,
            dt.x,
            dt.y,
            dt.z,
            dr,
            dp,
            dy
        );
        std::fs::write(self.dir.join("meta.toml"), meta)
    }
}
