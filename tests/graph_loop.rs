//! The pose graph's map rebuild reaches the station (issue 18): a live simulated robot
//! (`robot-agent sim --follow-drive`, real time) drives `config/scenarios/outage-line.toml`
//! with `[graph] enabled`, RTK is denied over the middle 30 m of its 60 m lane, and when RTK
//! returns the graph corrects the outage stretch and the terrain map is rebuilt. The test
//! watches the station's merged map: a tile more than the lidar's range (30 m) from the robot
//! can only get a new version from the rebuild, and the station must hold the rebuilt cells.
//!
//! The 355 m loop of `config/scenarios/loop.toml` takes ~8 minutes in real time; its accuracy is
//! measured with `robot-agent map eval --scenario config/scenarios/loop.toml --graph on|off`
//! (README). Here the rebuild is forced on any correction (`map_rebuild_min_move_m = 0`): this
//! short outage drifts only centimetres, and what is tested is that rebuilt tiles reach the
//! station.

mod station_support;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::grid::{Lattice, TileIndex};
use station_support::*;
use support::workspace_root;

/// Start-up, the 76 m drive at 1 m/s (slower when the loaded machine cannot keep real time),
/// the rebuild and its publication.
const RUN: Duration = Duration::from_secs(360);
/// A tile this far from the robot is beyond the lidar's 30 m, with 5 m for the robot's moves
/// between two looks at the station, metres.
const FAR_M: f64 = 35.0;

/// config/*.toml copied into `dir` with the pose graph on and every correction rebuilding.
fn config_with_graph(dir: &Path) -> PathBuf {
    let out = dir.join("config");
    std::fs::create_dir_all(&out).unwrap();
    for e in std::fs::read_dir(workspace_root().join("config")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            std::fs::copy(&p, out.join(p.file_name().unwrap())).unwrap();
        }
    }
    let slam = out.join("slam.toml");
    let text = std::fs::read_to_string(&slam).unwrap();
    let mut v: toml::Table = toml::from_str(&text).unwrap();
    let g = v["graph"].as_table_mut().expect("[graph] in slam.toml");
    g.insert("enabled".into(), true.into());
    g.insert("map_rebuild_min_move_m".into(), 0.0.into());
    std::fs::write(&slam, toml::to_string(&v).unwrap()).unwrap();
    out
}

/// Distance from `(x, y)` to the nearest point of tile `t`, metres.
fn tile_distance(l: &Lattice, t: TileIndex, (x, y): (f64, f64)) -> f64 {
    let n = i64::from(l.tile_cells);
    let s = f64::from(l.cell_size_m);
    let (c0x, c0y) = l.cell_center_m(i64::from(t.tx) * n, i64::from(t.ty) * n);
    let (x0, y0) = (c0x - 0.5 * s, c0y - 0.5 * s);
    let side = n as f64 * s;
    let dx = x.clamp(x0, x0 + side) - x;
    let dy = y.clamp(y0, y0 + side) - y;
    dx.hypot(dy)
}

#[test]
fn tiles_rebuilt_after_rtk_returns_reach_the_station() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config_with_graph(dir.path());
    let ports = Ports::new();
    let db = dir.path().join("s.db");
    let station = Station::start(ports, &db);
    let scenario = workspace_root().join("config/scenarios/outage-line.toml");
    let mut robot = Robot::start_with(
        "loop-1",
        &scenario,
        &ports.endpoint(),
        "0,0,0",
        1,
        dir.path(),
        &[
            "--follow-drive".into(),
            "--config-dir".into(),
            cfg.display().to_string(),
        ],
    );
    let t0 = Instant::now();
    let mut datum: Option<String> = None;
    let mut lattice: Option<Lattice> = None;
    let obs = Observer::connect(&ports.endpoint());
    let mut prev: Option<(std::collections::BTreeMap<TileIndex, u64>, (f64, f64))> = None;
    let mut far_updates = BTreeSet::new();
    let mut done_at: Option<Instant> = None;
    while t0.elapsed() < RUN {
        robot.assert_running();
        std::thread::sleep(Duration::from_millis(300));
        let log = std::fs::read_to_string(&robot.log).unwrap_or_default();
        if done_at.is_none() && log.contains("drive done") && log.contains("map rebuilt at") {
            done_at = Some(Instant::now());
        }
        if done_at.is_some_and(|t| t.elapsed() > Duration::from_secs(5)) {
            break;
        }
        if datum.is_none() {
            let d = get_json(ports.http, "/api/datums");
            datum = d
                .as_array()
                .and_then(|a| a.first()?["datum_id"].as_str().map(String::from));
            continue;
        }
        if lattice.is_none() {
            lattice = obs.robot_tiles("loop-1").values().next().map(|t| t.lattice);
            continue;
        }
        let (Some(d), Some(l)) = (datum.as_deref(), lattice.as_ref()) else {
            continue;
        };
        let Some(pose) = robot_entry(ports.http, "loop-1")
            .and_then(|r| Some((r["pose"]["x_m"].as_f64()?, r["pose"]["y_m"].as_f64()?)))
        else {
            continue;
        };
        let index = station_tile_index(ports.http, d);
        if let Some((before, at)) = &prev {
            for (k, v) in &index {
                let newer = before.get(k).is_some_and(|b| b < v);
                if newer && tile_distance(l, *k, *at) > FAR_M && tile_distance(l, *k, pose) > FAR_M
                {
                    far_updates.insert(*k);
                }
            }
        }
        prev = Some((index, pose));
    }
    let log = std::fs::read_to_string(&robot.log).unwrap_or_default();
    let rebuild = log
        .lines()
        .find(|l| l.contains("map rebuilt at"))
        .unwrap_or_else(|| {
            panic!(
                "no map rebuild in the robot's log:\n{}",
                tail(&robot.log, 30)
            )
        });
    assert!(
        log.contains("drive done"),
        "the drive did not end in {RUN:?}"
    );
    println!(
        "{}; {} tiles beyond {FAR_M} m of the robot got new versions at the station; {:.0} s",
        rebuild.trim(),
        far_updates.len(),
        t0.elapsed().as_secs_f64()
    );
    assert!(
        !far_updates.is_empty(),
        "no tile beyond the lidar's range was re-published after the rebuild"
    );
    // The station holds the rebuilt cells of those tiles: each at least as new as the robot's.
    let want = obs.robot_tiles("loop-1");
    let far: Vec<_> = want
        .values()
        .filter(|t| far_updates.contains(&t.index))
        .collect();
    assert_eq!(far.len(), far_updates.len(), "the robot serves those tiles");
    let robot_cells = cells_by_coordinate(far.iter().copied());
    let ok = wait_for(Duration::from_secs(10), || {
        let merged = cells_by_coordinate(&stored_tiles(&db, datum.as_deref().unwrap()));
        robot_cells
            .iter()
            .all(|(k, c)| merged.get(k).is_some_and(|m| m.stamp_s >= c.stamp_s))
    });
    assert!(
        ok,
        "the station lacks rebuilt cells of the far tiles ({} cells)",
        robot_cells.len()
    );
    drop(station);
}
