//! A stored session as MCAP, with the channels and schemas of a robot's own recording where the
//! station has the data: the session record, the decimated track as poses, transforms, fixes and
//! a line, the paths it followed, the goals it was sent, the routes it taught, and the merged map
//! of its datum as one `foxglove.Grid` and as the tiles themselves. What the station never had
//! (sensor data, commands to the base, status history) is not invented.

use crate::merge::MergedMap;
use common::msg::{Datum, Path as WirePath, Route, Session};
use record::foxglove::{self, level};
use record::schemas::{foxglove as fx, terranav};
use record::Recorder;
use rusqlite::Connection;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::Path;

/// What an export wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SessionExport {
    /// The session.
    pub session_id: String,
    /// The file.
    pub mcap: String,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// Stored rows left out because they did not parse (paths, goals, routes), or a GNSS goal
    /// of a session without a datum.
    pub skipped_rows: u64,
}

fn ns(t_unix_ms: u64) -> u64 {
    t_unix_ms.saturating_mul(1_000_000)
}

/// Exports `session_id` from the station database `c` to `out`.
pub fn export_session(
    c: &Connection,
    session_id: &str,
    out: &Path,
) -> anyhow::Result<SessionExport> {
    let row = crate::store::session(c, session_id)?
        .ok_or_else(|| anyhow::anyhow!("unknown session {session_id}"))?;
    let json_text: String = c.query_row(
        "SELECT json FROM sessions WHERE session_id = ?1",
        [session_id],
        |r| r.get(0),
    )?;
    let session: Session = serde_json::from_str(&json_text)?;
    let datum: Option<Datum> = crate::store::datums(c)?
        .into_iter()
        .find(|d| d.datum_id == row.datum_id)
        .and_then(|d| {
            Some(Datum {
                lat_deg: d.lat_deg?,
                lon_deg: d.lon_deg?,
                h_m: d.h_m.unwrap_or(0.0),
            })
        });

    let mut opts = record::Options::new(out);
    opts.profile = record::PROFILE.into();
    // An export writes as fast as it reads: the queue must never drop.
    opts.queue_messages = 1 << 20;
    opts.queue_bytes = usize::MAX / 2;
    let mut rec = Recorder::start(opts)?;
    let ch_session = rec.channel("/session", &terranav::session());
    let ch_tf = rec.channel("/tf", &fx::frame_transform());
    let ch_pose = rec.channel("/localisation/pose", &fx::pose_in_frame());
    let ch_fix = rec.channel("/localisation/fix", &fx::location_fix());
    let ch_track = rec.channel("/track", &fx::scene_update());
    let ch_path = rec.channel("/planning/path", &fx::scene_update());
    let ch_goal = rec.channel("/mission/goal", &fx::scene_update());
    let ch_route = rec.channel("/mission/route", &fx::scene_update());
    let ch_grid = rec.channel("/map/grid", &fx::grid());
    let ch_tiles = rec.channel("/map/tiles", &terranav::tile());
    let ch_log = rec.channel("/log", &fx::log());
    let mut meta = BTreeMap::new();
    meta.insert("robot".to_string(), row.robot.clone());
    meta.insert("session_id".to_string(), row.session_id.clone());
    meta.insert("start_unix_ms".to_string(), row.start_unix_ms.to_string());
    meta.insert("datum_id".to_string(), row.datum_id.clone());
    meta.insert(
        "exported_by".to_string(),
        "operator-station export session".into(),
    );
    rec.metadata("terranav.station_session", meta);

    let put = |rec: &mut Recorder, ch, t_ms: u64, v: serde_json::Value| {
        rec.write(ch, ns(t_ms), 0, move || foxglove::bytes(&v));
    };
    let mut skipped_rows = 0u64;
    let t_start = row.start_unix_ms;
    put(
        &mut rec,
        ch_session,
        t_start,
        json!({"timestamp": foxglove::time(ns(t_start)), "session": session}),
    );
    put(
        &mut rec,
        ch_log,
        t_start,
        foxglove::log(
            ns(t_start),
            level::INFO,
            "station",
            "exported from the station's store: poses are the decimated track, the map is the merged map of the datum at export time",
        ),
    );
    let track = crate::store::track(c, session_id)?;
    for &(t, x, y, yaw) in &track {
        let q = foxglove::quaternion_ypr(yaw, 0.0, 0.0);
        put(
            &mut rec,
            ch_tf,
            t,
            foxglove::frame_transform(ns(t), "map", "base_link", [x, y, 0.0], q),
        );
        put(
            &mut rec,
            ch_pose,
            t,
            foxglove::pose_in_frame(ns(t), "map", [x, y, 0.0], q),
        );
        if let Some(d) = &datum {
            let g = common::geo::enu_to_lla(d, &nalgebra::Vector3::new(x, y, 0.0));
            put(
                &mut rec,
                ch_fix,
                t,
                foxglove::location_fix(ns(t), "base_link", g.lat_deg, g.lon_deg, g.h_m),
            );
        }
    }
    let t_end = track
        .last()
        .map_or(row.last_unix_ms, |p| p.0)
        .max(row.last_unix_ms);
    let line: Vec<[f64; 3]> = track.iter().map(|p| [p.1, p.2, 0.0]).collect();
    put(
        &mut rec,
        ch_track,
        t_end,
        foxglove::scene_line(
            ns(t_end),
            "map",
            "track",
            &line,
            foxglove::color(0.9, 0.9, 0.2, 1.0),
            0.08,
        ),
    );
    for (t, _, text) in crate::store::paths(c, session_id)? {
        let Ok(p) = serde_json::from_str::<WirePath>(&text) else {
            tracing::warn!("export: a stored path of {session_id} at {t} does not parse; left out");
            skipped_rows += 1;
            continue;
        };
        let pts: Vec<[f64; 3]> = p
            .points_m
            .iter()
            .map(|q| [f64::from(q.0), f64::from(q.1), 0.0])
            .collect();
        put(
            &mut rec,
            ch_path,
            t,
            foxglove::scene_line(
                ns(t),
                "map",
                "path",
                &pts,
                foxglove::color(0.1, 0.5, 1.0, 1.0),
                0.08,
            ),
        );
    }
    for (t, goal_id, text) in crate::store::goals(c, &row.robot, t_start, t_end)? {
        let Ok(g) = serde_json::from_str::<common::msg::GoalCmd>(&text) else {
            tracing::warn!("export: stored goal {goal_id} at {t} does not parse; left out");
            skipped_rows += 1;
            continue;
        };
        let xy = match g.target {
            common::msg::GoalTarget::Map { x_m, y_m } => Some((x_m, y_m)),
            common::msg::GoalTarget::Gnss {
                lat_deg,
                lon_deg,
                h_m,
            } => datum.map(|d| {
                let e = common::geo::lla_to_enu(
                    &d,
                    &Datum {
                        lat_deg,
                        lon_deg,
                        h_m: h_m.unwrap_or(d.h_m),
                    },
                );
                (e.x, e.y)
            }),
        };
        if let Some((x, y)) = xy {
            put(
                &mut rec,
                ch_goal,
                t,
                foxglove::scene_marker(
                    ns(t),
                    "map",
                    "goal",
                    [x, y, 0.0],
                    foxglove::color(1.0, 0.55, 0.0, 1.0),
                    &format!("goal {goal_id}"),
                ),
            );
        } else {
            skipped_rows += 1;
        }
    }
    for text in crate::store::session_routes(c, session_id)? {
        let Ok(r) = serde_json::from_str::<Route>(&text) else {
            tracing::warn!("export: a stored route of {session_id} does not parse; left out");
            skipped_rows += 1;
            continue;
        };
        let pts: Vec<[f64; 3]> = r.points.iter().map(|p| [p.x_m, p.y_m, 0.0]).collect();
        let t = r.points.last().map_or(t_end, |p| p.t_unix_ms);
        put(
            &mut rec,
            ch_route,
            t,
            foxglove::scene_line(
                ns(t),
                "map",
                &format!("route {}", r.name),
                &pts,
                foxglove::color(0.6, 0.3, 0.9, 1.0),
                0.1,
            ),
        );
    }
    let mut map = MergedMap::default();
    for (d, _, _, v, data) in crate::store::tiles(c, Some(&row.datum_id))? {
        let mut t = common::grid::decode_tile(&data)
            .map_err(|e| anyhow::anyhow!("stored tile of {d}: {e}"))?;
        t.version = v;
        let encoded = data.clone();
        let msg = foxglove::tile_message(ns(t_end), &t, &encoded);
        put(&mut rec, ch_tiles, t_end, msg);
        map.restore(&d, t);
    }
    if let Some(dm) = map.datums.get(&row.datum_id) {
        let tiles: Vec<common::grid::Tile> = dm
            .tiles
            .iter()
            .map(|(i, m)| common::grid::Tile {
                index: *i,
                lattice: dm.lattice,
                version: m.version,
                cells: m.cells.clone(),
            })
            .collect();
        if let Some(g) = foxglove::tiles_grid(ns(t_end), "map", tiles.iter()) {
            put(&mut rec, ch_grid, t_end, g);
        }
    }
    let f = rec.finish();
    if let Some(e) = f.stats.error {
        anyhow::bail!("writing {}: {e}", out.display());
    }
    Ok(SessionExport {
        session_id: session_id.to_string(),
        mcap: out.display().to_string(),
        messages: f.messages,
        skipped_rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{DatumRow, RouteRow, SessionRow, StoreOp, StoreWriter};
    use common::grid::{Cell, CellState, Lattice, Tile, TileIndex};
    use common::msg::{GoalCmd, GoalTarget, MapFrame, RoutePoint};
    use record::{Item, Reader};

    #[test]
    fn a_stored_session_exports_with_its_track_plans_goals_routes_and_map() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("s.db");
        let w = StoreWriter::start(&db).unwrap();
        let tx = w.sender();
        let datum = Datum {
            lat_deg: 47.0,
            lon_deg: 8.0,
            h_m: 400.0,
        };
        tx.send(StoreOp::Datum(DatumRow {
            datum_id: "d0".into(),
            lat_deg: Some(datum.lat_deg),
            lon_deg: Some(datum.lon_deg),
            h_m: Some(datum.h_m),
            cell_size_m: 0.2,
            tile_cells: 64,
        }))
        .unwrap();
        let t0 = 1_700_000_000_000u64;
        let session = Session {
            session_id: "r1-1".into(),
            robot: "r1".into(),
            start_unix_ms: t0,
            frame: MapFrame::EnuAtDatum,
            datum: Some(datum),
            cell_size_m: 0.2,
            tile_cells: 64,
            source: "sim:park".into(),
            agent_version: "test".into(),
        };
        tx.send(StoreOp::Session {
            row: SessionRow {
                session_id: "r1-1".into(),
                robot: "r1".into(),
                start_unix_ms: t0,
                last_unix_ms: t0 + 10_000,
                datum_id: "d0".into(),
                source: "sim:park".into(),
            },
            json: serde_json::to_string(&session).unwrap(),
        })
        .unwrap();
        for i in 0..20u64 {
            tx.send(StoreOp::Track {
                session_id: "r1-1".into(),
                t_unix_ms: t0 + 500 * i,
                x: i as f64 * 0.5,
                y: 0.0,
                yaw: 0.0,
            })
            .unwrap();
        }
        let path = WirePath {
            t_unix_ms: t0 + 1000,
            goal_id: 1,
            points_m: vec![(0.0, 0.0), (9.0, 0.0)],
        };
        for json in [
            serde_json::to_string(&path).unwrap(),
            "{not json".to_string(),
        ] {
            tx.send(StoreOp::Path {
                session_id: "r1-1".into(),
                robot: "r1".into(),
                t_unix_ms: t0 + 1000,
                goal_id: 1,
                json,
            })
            .unwrap();
        }
        let goal = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Map { x_m: 9.0, y_m: 0.0 },
            tolerance_m: 0.5,
        };
        tx.send(StoreOp::Goal {
            robot: "r1".into(),
            t_unix_ms: t0 + 900,
            goal_id: 1,
            json: serde_json::to_string(&goal).unwrap(),
        })
        .unwrap();
        let point = |x: f64, t: u64| RoutePoint {
            x_m: x,
            y_m: 0.0,
            lat_deg: None,
            lon_deg: None,
            h_m: None,
            yaw_rad: 0.0,
            t_unix_ms: t,
        };
        let route = Route {
            route_id: "rt1".into(),
            name: "home".into(),
            robot: "r1".into(),
            session_id: "r1-1".into(),
            datum: Some(datum),
            points: vec![point(0.0, t0), point(5.0, t0 + 5000)],
        };
        tx.send(StoreOp::Route {
            row: RouteRow {
                route_id: "rt1".into(),
                name: "home".into(),
                robot: "r1".into(),
                session_id: "r1-1".into(),
                datum_id: Some("d0".into()),
                points: 2,
                length_m: 5.0,
            },
            json: serde_json::to_string(&route).unwrap(),
        })
        .unwrap();
        let lattice = Lattice {
            cell_size_m: 0.2,
            tile_cells: 64,
        };
        for tx_i in 0..2 {
            let mut t = Tile::new(TileIndex { tx: tx_i, ty: 0 }, lattice);
            t.cells[5] = Cell {
                state: CellState::Traversable,
                cost: 3,
                height_cm: 12,
                hits: 4,
                stamp_s: 1,
                rev: 0,
            };
            tx.send(StoreOp::Tile {
                datum_id: "d0".into(),
                tx: tx_i,
                ty: 0,
                version: 1,
                data: common::grid::encode_tile(&t),
                history: None,
            })
            .unwrap();
        }
        w.finish();

        let c = crate::store::open(&db).unwrap();
        let out = dir.path().join("r1.mcap");
        let e = export_session(&c, "r1-1", &out).unwrap();
        assert_eq!(e.skipped_rows, 1, "the unparsable path is counted");
        let want = [
            ("/session", 1),
            ("/tf", 20),
            ("/localisation/pose", 20),
            ("/localisation/fix", 20),
            ("/track", 1),
            ("/planning/path", 1),
            ("/mission/goal", 1),
            ("/mission/route", 1),
            ("/map/tiles", 2),
            ("/map/grid", 1),
            ("/log", 1),
        ];
        for (topic, n) in want {
            assert_eq!(e.messages.get(topic), Some(&n), "{topic}: {:?}", e.messages);
        }
        // Read back: every message is JSON of its channel's schema, the grid covers both tiles.
        let mut r = Reader::open(&out).unwrap();
        let mut n = 0;
        for item in r.by_ref() {
            if let Item::Message(m) = item.unwrap() {
                let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
                if m.channel.topic == "/map/grid" {
                    assert_eq!(m.channel.schema_name, "foxglove.Grid");
                    assert_eq!(v["column_count"], 128, "{}", v["column_count"]);
                }
                if m.channel.topic == "/localisation/fix" {
                    assert!((v["latitude"].as_f64().unwrap() - 47.0).abs() < 1e-3);
                }
                n += 1;
            }
        }
        assert!(r.finished());
        assert_eq!(n, want.iter().map(|w| w.1).sum::<u64>());
        assert!(export_session(&c, "nope", &dir.path().join("x.mcap")).is_err());
    }
}
