//! Digests of everything the mapper holds after the bench's drive (`benches/update.rs`), for
//! proving a change exact: run it before and after, the lines must be identical.
//!
//! `cargo run --release -p terranav-mapping --example park_digest`
//!
//! One line per way of feeding the mapper (sweeps with their origin, incremental and full
//! reclassification; bare points; map clouds; sweeps with frame corrections in between; the
//! KITTI car profile), each with three digests: of every update's report, of the published
//! tiles ([`common::grid::map_digest`]), and of every held cell's class, evidence statistics
//! and [`Mapper::describe`] line (the mapper's inner state as far as it shows).

use mapping::{Config, Evidence, Mapper};
use nalgebra::{Isometry3, Vector3};
use std::fmt::Write as _;

#[path = "../benches/support/park_drive.rs"]
mod park_drive;

/// FNV-1a, 64 bits: stable across builds and platforms, unlike the standard library's hasher.
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ u64::from(x)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn f64(&mut self, v: f64) {
        self.bytes(&v.to_bits().to_le_bytes());
    }
}

/// How the drive's sweeps are fed to the mapper.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Feed {
    /// `update_sweep`: points with the sensor origin (free space marched).
    Sweep,
    /// `update_points` as scans: no origin, no free space.
    Points,
    /// `update_points` as map clouds: each cell's points replace what it held.
    Cloud,
    /// `update_sweep` with a frame correction (`follow_frame`) every 50 sweeps.
    SweepFollow,
}

fn run(name: &str, cfg: Config, full: bool, feed: Feed, sweeps: &[park_drive::Sweep]) -> String {
    let mut m = Mapper::new(cfg).expect("config");
    m.set_full_reclassification(full);
    let mut reports = Fnv::new();
    let mut moved = 0usize;
    for (k, s) in sweeps.iter().enumerate() {
        let t = 0.1 * (k + 1) as f64;
        let pts = s.points.clone();
        let rep = match feed {
            Feed::Sweep | Feed::SweepFollow => m.update_sweep(pts, s.origin, &s.robot, t),
            Feed::Points => m.update_points(pts, &s.robot, t, Evidence::Scan),
            Feed::Cloud => m.update_points(pts, &s.robot, t, Evidence::MapCloud),
        }
        .expect("update");
        reports.bytes(format!("{rep:?}").as_bytes());
        if feed == Feed::SweepFollow && k % 50 == 49 {
            // A small tilt and lift of the frame, as a GNSS correction would bring.
            let delta = Isometry3::new(
                Vector3::new(0.0, 0.0, 0.02),
                Vector3::new(0.003, -0.002, 0.0),
            );
            moved += m.follow_frame(&delta, 30.0);
        }
    }
    let tiles = common::grid::map_digest(&m.tiles());
    let mut cells = Fnv::new();
    let mut held = 0usize;
    if let Some(((x0, y0), (x1, y1))) = m.bounds() {
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                cells.bytes(&[m.class(cx, cy) as u8]);
                for st in [m.height_stats(cx, cy), m.newest_height_stats(cx, cy)] {
                    cells.bytes(&st.n.to_le_bytes());
                    for v in [st.mean_m, st.var_m2, st.max_m, st.min_m] {
                        cells.f64(v);
                    }
                }
                if let Some(h) = m.height_m(cx, cy) {
                    cells.f64(h);
                }
                cells.bytes(m.describe(cx, cy).as_bytes());
                held += 1;
            }
        }
    }
    let mut view = Fnv::new();
    for c in &m.planner_view().cells {
        view.bytes(format!("{c:?}").as_bytes());
    }
    let mut line = String::new();
    write!(
        line,
        "{name:<22} reports {:016x} tiles {} cells {:016x} ({held}) view {:016x}",
        reports.0,
        &tiles[..16],
        cells.0,
        view.0
    )
    .unwrap();
    if feed == Feed::SweepFollow {
        write!(line, " moved {moved}").unwrap();
    }
    line
}

fn main() {
    let sweeps = park_drive::sweeps();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let car: Config = toml::from_str(
        &std::fs::read_to_string(root.join("config/mapper-car.toml")).expect("mapper-car.toml"),
    )
    .expect("car config");
    let runs = [
        ("sweep incremental", Config::default(), false, Feed::Sweep),
        ("sweep full", Config::default(), true, Feed::Sweep),
        ("points incremental", Config::default(), false, Feed::Points),
        ("cloud incremental", Config::default(), false, Feed::Cloud),
        (
            "sweep follow_frame",
            Config::default(),
            false,
            Feed::SweepFollow,
        ),
        ("sweep car profile", car, false, Feed::Sweep),
    ];
    for (name, cfg, full, feed) in runs {
        println!("{}", run(name, cfg, full, feed, &sweeps));
    }
}
