//! The map of a whole site in the browser (issue 20): a station whose database holds a synthetic
//! 1 km² merged map (78 x 78 = 6 084 merged tiles of 12.8 m, 0.2 m cells, written straight into
//! the station's SQLite store) and a past session with a pose track; Debian's chromium driven by
//! `node web/tests/pyramid.mjs` opens the UI and measures the time to the first full view of the
//! site and the tile requests it takes (printed, never asserted on time), checks that zooming in
//! reaches full resolution (pyramid level 0), and scrubs the session's track in time with the map
//! as it was: the tile history has the site's west half mapped 60 s into the session and the
//! east half at 450 s, so at half time (300 s) only the west half may be drawn.
//!
//! Skips with a notice only when `/usr/bin/chromium` or `web/node_modules` is missing; CI installs
//! both.

mod browser_support;
mod station_support;

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use browser_support::{browser_unavailable, run_ui_script};
use common::grid::{encode_tile, Cell, CellState, Lattice, Tile, TileIndex};
use operator_station::store::{DatumRow, HistoryStamp, SessionRow, StoreOp, StoreWriter};
use station_support::{Ports, Station};
use support::workspace_root;

/// Upper bound for the whole node script; its own steps time out well before this.
const UI_TEST_LIMIT: Duration = Duration::from_secs(150);
/// Merged tiles per side: 78 x 12.8 m = 998 m.
const SIDE_TILES: i32 = 78;
/// Start of the synthetic session, Unix ms.
const SESSION_START_MS: u64 = 1_790_000_000_000;
/// When the tile history has the west half (tx < 0) and the east half of the site, Unix ms.
const WEST_MAPPED_MS: u64 = SESSION_START_MS + 60_000;
const EAST_MAPPED_MS: u64 = SESSION_START_MS + 450_000;
/// The history period the rows are written with (the station's default).
const HISTORY_PERIOD_S: u32 = 60;

/// Cell (c, r) of tile (tx, ty): ground everywhere, walls every 100 m, scattered trees (a cell
/// obstacle ringed by inflated cells), and nothing known in a few pockets.
fn cell_at(tx: i32, ty: i32, c: u16, r: u16) -> CellState {
    let x = tx * 64 + i32::from(c);
    let y = ty * 64 + i32::from(r);
    let h = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663)).rem_euclid(4096);
    if x.rem_euclid(500) == 0 || y.rem_euclid(500) == 0 || h == 0 {
        CellState::Obstacle
    } else if h < 6 {
        CellState::Inflated
    } else if (x / 700 + y / 900).rem_euclid(11) == 0 {
        CellState::Unknown
    } else {
        CellState::Traversable
    }
}

fn synthetic_tile(tx: i32, ty: i32) -> Tile {
    let mut t = Tile::new(TileIndex { tx, ty }, Lattice::default());
    t.version = 1;
    for r in 0..64u16 {
        for c in 0..64u16 {
            *t.get_mut(c, r) = Cell {
                state: cell_at(tx, ty, c, r),
                cost: 0,
                height_cm: 0,
                hits: 3,
                stamp_s: 1000,
                rev: 0,
            };
        }
    }
    t
}

/// The station database: datum `d0`, the site's tiles, one session with a 10-minute track.
fn write_site(db: &Path) -> anyhow::Result<usize> {
    let w = StoreWriter::start(db)?;
    let tx = w.sender();
    tx.send(StoreOp::Datum(DatumRow {
        datum_id: "d0".into(),
        lat_deg: Some(50.08),
        lon_deg: Some(14.42),
        h_m: Some(240.0),
        cell_size_m: 0.2,
        tile_cells: 64,
    }))?;
    let half = SIDE_TILES / 2;
    let mut n = 0;
    for ty in -half..SIDE_TILES - half {
        for txi in -half..SIDE_TILES - half {
            let t = synthetic_tile(txi, ty);
            let data = encode_tile(&t);
            let mapped_ms = if txi < 0 {
                WEST_MAPPED_MS
            } else {
                EAST_MAPPED_MS
            };
            tx.send(StoreOp::Tile {
                datum_id: "d0".into(),
                tx: txi,
                ty,
                version: 1,
                data,
                history: Some(HistoryStamp {
                    bucket: operator_station::history::bucket(mapped_ms, HISTORY_PERIOD_S),
                    t_unix_ms: mapped_ms,
                }),
            })?;
            n += 1;
        }
    }
    let session_id = "husky-1-past".to_string();
    tx.send(StoreOp::Session {
        row: SessionRow {
            session_id: session_id.clone(),
            robot: "husky-1".into(),
            start_unix_ms: SESSION_START_MS,
            last_unix_ms: SESSION_START_MS + 600_000,
            datum_id: "d0".into(),
            source: "test".into(),
        },
        json: "{}".into(),
    })?;
    // A loop around the site's middle, one point a second.
    for i in 0..600u64 {
        let a = i as f64 / 600.0 * std::f64::consts::TAU;
        tx.send(StoreOp::Track {
            session_id: session_id.clone(),
            t_unix_ms: SESSION_START_MS + i * 1000,
            x: 200.0 * a.cos(),
            y: 150.0 * a.sin(),
            yaw: a + std::f64::consts::FRAC_PI_2,
        })?;
    }
    w.finish();
    Ok(n)
}

#[test]
fn a_site_sized_map_shows_at_once_through_the_zoom_pyramid() -> anyhow::Result<()> {
    let root = workspace_root();
    if let Some(why) = browser_unavailable(&root) {
        println!("skipping browser pyramid test: {why}");
        return Ok(());
    }
    let artifacts = root.join("artifacts/ui-pyramid");
    std::fs::create_dir_all(&artifacts)?;
    let dir = tempfile::tempdir()?;
    let db = dir.path().join("station.db");
    let t = Instant::now();
    let tiles = write_site(&db)?;
    println!(
        "wrote {tiles} merged tiles in {:.1} s",
        t.elapsed().as_secs_f64()
    );

    let station = Station::start(Ports::new(), &db);
    println!(
        "station answered HTTP after {:.2} s and had restored the map after {:.2} s",
        station.answered_after.0.as_secs_f64(),
        station.answered_after.1.as_secs_f64()
    );
    let url = format!("http://127.0.0.1:{}/", station.ports.http);
    run_ui_script(
        &root,
        "pyramid.mjs",
        &[url, "--tiles".into(), tiles.to_string()],
        &artifacts,
        UI_TEST_LIMIT,
    )
    .with_context(|| format!("station log:\n{}", station.log_text()))?;
    Ok(())
}
