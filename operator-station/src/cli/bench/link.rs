//! `operator-station bench link`: what secure links cost. Pose latency and tile throughput
//! through a real [`Station`], over plain TCP, then QUIC and TLS, both with mutual authentication
//! and both sides' access rules (a fresh fleet PKI in a temporary folder), alternating in the same
//! run, so the ratios say what a secure link adds and not how fast this machine is.
//!
//! Each simulated robot is its own Zenoh session (its own link, certificate and rules, as on a
//! real fleet). Latency: `put` of a pose to the station's pose event (the station forwards at most
//! ~10 Hz per robot, so robots publish at 10 Hz each). Tiles: one robot puts robot-like tiles as
//! fast as reliable delivery allows; received = every tile reached the station's session (the
//! link alone), merged = the merge thread emitted every changed tile.

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::grid::{encode_tile, TileIndex};
use common::keys::{self, RobotId, Topic};
use common::msg;
use common::security::{self, CertFiles, FleetDir};
use serde_json::json;

use super::{free_endpoint, rate, robot_like_tile, send_poses, stats, SentPoses};
use crate::station::{self, Station, StationOptions};

/// Plain TCP, or one of the two links that carry the fleet's mutual TLS authentication.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Link {
    Tcp,
    Quic,
    Tls,
}

impl Link {
    fn name(self) -> &'static str {
        match self {
            Link::Tcp => "tcp",
            Link::Quic => "quic",
            Link::Tls => "tls",
        }
    }

    fn secure(self) -> bool {
        self != Link::Tcp
    }
}

fn zerr(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("zenoh: {e}")
}

fn set(c: &mut zenoh::Config, k: &str, v: &str) -> anyhow::Result<()> {
    c.insert_json5(k, v).map_err(zerr)
}

/// What one round measured.
struct Round {
    latency_us: Vec<f64>,
    received_tiles_per_s: f64,
    merged_tiles_per_s: f64,
}

/// Runs `rounds` rounds of TCP, QUIC and TLS; `robots` sessions, `samples` timed poses and `tiles` tiles
/// per round and link.
pub async fn run(
    robots: usize,
    samples: usize,
    tiles: usize,
    rounds: usize,
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        robots > 0 && samples > 0 && tiles > 0 && rounds > 0,
        "nothing to measure"
    );
    let dir = std::env::temp_dir().join(format!("terranav-bench-link-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let pki_dir = dir.join("pki");
    crate::pki::init(&pki_dir, &[])?;
    let ids: Vec<RobotId> = (0..robots)
        .map(|i| RobotId::new(format!("bench-{i}")))
        .collect::<Result<_, _>>()?;
    for id in &ids {
        crate::pki::issue(&pki_dir, id, &[], 1)?;
    }
    let mut all: HashMap<Link, Vec<Round>> = HashMap::new();
    let result = async {
        for r in 0..rounds {
            for link in [Link::Tcp, Link::Quic, Link::Tls] {
                let db = dir.join(format!("{}-{r}.sqlite", link.name()));
                let round = one_round(link, &pki_dir, &ids, samples, tiles, &db).await?;
                eprintln!(
                    "link {} round {r}: pose latency median {:.0} us ({} samples), tiles received \
                     {:.0}/s, merged {:.0}/s",
                    link.name(),
                    median(&round.latency_us),
                    round.latency_us.len(),
                    round.received_tiles_per_s,
                    round.merged_tiles_per_s
                );
                all.entry(link).or_default().push(round);
            }
        }
        anyhow::Ok(())
    }
    .await;
    let _ = std::fs::remove_dir_all(&dir);
    result?;
    let summary = |link: Link| {
        let rs = &all[&link];
        let lat: Vec<f64> = rs
            .iter()
            .flat_map(|r| r.latency_us.iter().copied())
            .collect();
        let best = |f: fn(&Round) -> f64| rs.iter().map(f).fold(0.0, f64::max);
        (
            stats(lat),
            best(|r| r.received_tiles_per_s),
            best(|r| r.merged_tiles_per_s),
        )
    };
    let (lt, rx_t, mg_t) = summary(Link::Tcp);
    let ratio = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(x), Some(y)) if y > 0.0 => json!(x / y),
        _ => json!(null),
    };
    let mut out = json!({
        "robots": robots, "samples_per_round": samples, "tiles_per_round": tiles, "rounds": rounds,
        "tcp": {"latency": lt, "received_tiles_per_s": rx_t, "merged_tiles_per_s": mg_t},
    });
    for link in [Link::Quic, Link::Tls] {
        let (ls, rx_s, mg_s) = summary(link);
        let vs = json!({
            "latency_median": ratio(ls["median_us"].as_f64(), lt["median_us"].as_f64()),
            "latency_p99": ratio(ls["p99_us"].as_f64(), lt["p99_us"].as_f64()),
            "received_tiles_per_s": ratio(Some(rx_s), Some(rx_t)),
            "merged_tiles_per_s": ratio(Some(mg_s), Some(mg_t)),
        });
        eprintln!(
            "link: {}/TCP pose latency median {:.2}x, p99 {:.2}x; tiles received {:.2}x, merged \
             {:.2}x",
            link.name().to_uppercase(),
            vs["latency_median"].as_f64().unwrap_or(f64::NAN),
            vs["latency_p99"].as_f64().unwrap_or(f64::NAN),
            vs["received_tiles_per_s"].as_f64().unwrap_or(f64::NAN),
            vs["merged_tiles_per_s"].as_f64().unwrap_or(f64::NAN),
        );
        out[link.name()] =
            json!({"latency": ls, "received_tiles_per_s": rx_s, "merged_tiles_per_s": mg_s});
        out[format!("{}_vs_tcp", link.name())] = vs;
    }
    Ok(out)
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The station's config on `link`.
fn station_config(link: Link, pki: &Path, ep: &str) -> anyhow::Result<zenoh::Config> {
    let mut c = station::zenoh_config(None, None, &[ep.to_string()], &[])?;
    if link.secure() {
        crate::security::apply(&mut c, pki, false)?;
    }
    Ok(c)
}

/// A robot's config on `link`: its certificate and its own rules, as `robot-agent --pki`.
fn robot_config(link: Link, pki: &Path, id: &RobotId, ep: &str) -> anyhow::Result<zenoh::Config> {
    let mut c = station::zenoh_config(None, None, &[], &[ep.to_string()])?;
    if link.secure() {
        set(&mut c, "listen/endpoints", "[]")?;
        let files = CertFiles::robot(&FleetDir::new(pki).robot_dir(id));
        for (k, v) in security::tls_settings(&files) {
            set(&mut c, k, &v)?;
        }
        set(
            &mut c,
            "access_control",
            &security::robot_acl(id).to_string(),
        )?;
    }
    Ok(c)
}

async fn one_round(
    link: Link,
    pki: &Path,
    ids: &[RobotId],
    samples: usize,
    tiles: usize,
    db: &Path,
) -> anyhow::Result<Round> {
    let port = free_endpoint()?;
    let ep = port.replacen("tcp/", &format!("{}/", link.name()), 1);
    let st = Station::start(StationOptions {
        zenoh: station_config(link, pki, &ep)?,
        db: db.to_path_buf(),
        alerts: crate::alerts::AlertConfig::default(),
    })
    .await?;
    let mut sessions = Vec::new();
    for id in ids {
        sessions.push(
            zenoh::open(robot_config(link, pki, id, &ep)?)
                .await
                .map_err(zerr)?,
        );
    }
    // The link alone: a subscriber on the station's own session counts tiles as they arrive.
    let received = Arc::new(AtomicUsize::new(0));
    let rx_done: Arc<Mutex<Option<Instant>>> = Arc::default();
    let (rc, rd) = (received.clone(), rx_done.clone());
    let _tile_sub = st
        .inner
        .session()
        .declare_subscriber(keys::robot_tiles(&ids[0]))
        .callback(move |_| {
            if rc.fetch_add(1, Ordering::Relaxed) + 1 == tiles {
                *rd.lock().unwrap_or_else(|p| p.into_inner()) = Some(Instant::now());
            }
        })
        .await
        .map_err(zerr)?;
    let mut events = st.inner.events.subscribe();
    let sent: SentPoses = Arc::default();
    let lat: Arc<Mutex<Vec<f64>>> = Arc::default();
    let merged = Arc::new(AtomicUsize::new(0));
    let mg_done: Arc<Mutex<Option<Instant>>> = Arc::default();
    let (s2, l2, m2, md) = (sent.clone(), lat.clone(), merged.clone(), mg_done.clone());
    let listener = tokio::spawn(async move {
        while let Ok(ev) = events.recv().await {
            let now = Instant::now();
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&ev) else {
                continue;
            };
            match v["type"].as_str() {
                Some("pose") => {
                    let key = (
                        v["robot"].as_str().unwrap_or("").to_string(),
                        v["pose"]["seq"].as_u64().unwrap_or(u64::MAX) as u32,
                    );
                    if let Some(t) = s2.lock().unwrap_or_else(|p| p.into_inner()).get(&key) {
                        l2.lock()
                            .unwrap_or_else(|p| p.into_inner())
                            .push(now.duration_since(*t).as_secs_f64() * 1e6);
                    }
                }
                Some("tile") if m2.fetch_add(1, Ordering::Relaxed) + 1 == tiles => {
                    *md.lock().unwrap_or_else(|p| p.into_inner()) = Some(now);
                }
                _ => {}
            }
        }
    });
    // Links up, rules exchanged, subscriptions propagated; then every robot's session.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    for (s, id) in sessions.iter().zip(ids) {
        let sess = msg::Session {
            session_id: format!("{id}-bench"),
            robot: id.to_string(),
            start_unix_ms: station::now_unix_ms(),
            frame: msg::MapFrame::EnuAtDatum,
            datum: Some(msg::Datum {
                lat_deg: 48.2,
                lon_deg: 16.37,
                h_m: 171.0,
            }),
            cell_size_m: 0.2,
            tile_cells: 64,
            source: "bench".into(),
            agent_version: station::VERSION.into(),
        };
        s.put(keys::key(id, Topic::Session), msg::encode(&sess))
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .await
            .map_err(zerr)?;
    }
    tokio::time::sleep(Duration::from_millis(500)).await;

    // Poses: each robot at 10 Hz, interleaved, as on a fleet.
    let period = Duration::from_secs_f64(0.1 / ids.len() as f64);
    let robots: Vec<(zenoh::Session, RobotId)> =
        sessions.iter().cloned().zip(ids.iter().cloned()).collect();
    let s4 = sent.clone();
    send_poses(&robots, period, ids.len() * 3, samples, |id, seq, timed| {
        if timed {
            s4.lock()
                .unwrap_or_else(|p| p.into_inner())
                .insert((id.to_string(), seq), Instant::now());
        }
    })
    .await?;
    tokio::time::sleep(Duration::from_millis(300)).await;

    // Tiles: every put a newer observation of one of 400 tiles, so each changes its merged tile.
    let encoded: Vec<(TileIndex, Vec<u8>)> = (0..tiles)
        .map(|i| {
            let idx = TileIndex {
                tx: (i % 20) as i32,
                ty: ((i / 20) % 20) as i32,
            };
            let round = (i / 400) as u32;
            let t = robot_like_tile(
                idx,
                u64::from(round) + 1,
                1_790_000_000 + round * common::grid::WIRE_STAMP_STEP_S,
                i as u64,
            );
            (idx, encode_tile(&t))
        })
        .collect();
    let t0 = Instant::now();
    for (idx, bytes) in encoded {
        sessions[0]
            .put(
                keys::key(
                    &ids[0],
                    Topic::Tile {
                        tx: idx.tx,
                        ty: idx.ty,
                    },
                ),
                bytes,
            )
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .await
            .map_err(zerr)?;
    }
    let deadline = Instant::now() + Duration::from_secs(120);
    while merged.load(Ordering::Relaxed) < tiles && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let took = |m: &Arc<Mutex<Option<Instant>>>, n: &AtomicUsize| {
        let done = *m.lock().unwrap_or_else(|p| p.into_inner());
        match done {
            Some(t) => rate(tiles, t.duration_since(t0)),
            // Not all arrived in time: the rate of those that did.
            None => rate(n.load(Ordering::Relaxed), t0.elapsed()),
        }
    };
    let received_tiles_per_s = took(&rx_done, &received);
    let merged_tiles_per_s = took(&mg_done, &merged);
    listener.abort();
    drop(_tile_sub);
    for s in sessions {
        let _ = s.close().await;
    }
    st.stop().await;
    let latency_us = std::mem::take(&mut *lat.lock().unwrap_or_else(|p| p.into_inner()));
    anyhow::ensure!(
        !latency_us.is_empty(),
        "no pose reached the station over {}",
        link.name()
    );
    Ok(Round {
        latency_us,
        received_tiles_per_s,
        merged_tiles_per_s,
    })
}
