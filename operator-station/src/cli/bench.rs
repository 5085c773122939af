//! `operator-station bench`: merge throughput and pose latency, each with a baseline measured in
//! the same run so the numbers say how much the station adds, not how fast this machine is.
//!
//! - merge: robot-like tiles (encoded as on the wire) through [`MergeWorker`] (decode, merge,
//!   re-encode of the merged tile, store sink), against decoding alone.
//! - latency: a real [`Station`] (Zenoh, fleet, store, events) on loopback TCP and a publisher
//!   session putting poses exactly as the robot bus does; time from `put` to the station's pose
//!   event (what the WebSocket forwards), against a bare Zenoh subscriber on the same publisher.
//! - link ([`link`]): pose latency and tile throughput through a station over TLS with mutual
//!   authentication and access rules, against plain TCP.
//! - fleet ([`fleet`]): N lightweight robots replaying a recorded `park` robot's tiles, with
//!   poses at 10 Hz, into one station: merge lag, pose latency, the station's CPU and memory.

pub mod fleet;
pub mod link;

use std::collections::HashMap;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant};

use anyhow::Context;
use common::grid::{decode_tile, encode_tile, Cell, CellState, Lattice, Tile, TileIndex};
use common::keys::{self, RobotId, Topic};
use common::msg::{self, FixState, Pose};
use serde_json::json;

use crate::merge::{MergeJob, MergeWorker, MergedMap};
use crate::station::{self, Station, StationOptions};

/// `bench` options.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[arg(value_enum, default_value = "all")]
    pub what: BenchWhat,
    /// Tiles through the merge.
    #[arg(long, default_value_t = 20_000)]
    pub tiles: usize,
    /// Poses timed.
    #[arg(long, default_value_t = 3000)]
    pub samples: usize,
    /// Simulated robots the poses round-robin over (the station forwards at most ~10 Hz per robot).
    #[arg(long, default_value_t = 25)]
    pub robots: usize,
    /// Total pose rate, Hz.
    #[arg(long, default_value_t = 200.0)]
    pub rate_hz: f64,
    /// link: robots (one Zenoh session and certificate each, 10 Hz poses each).
    #[arg(long, default_value_t = 5)]
    pub link_robots: usize,
    /// link: poses timed per round and transport.
    #[arg(long, default_value_t = 600)]
    pub link_samples: usize,
    /// link: tiles sent per round and transport.
    #[arg(long, default_value_t = 2000)]
    pub link_tiles: usize,
    /// link: rounds (each TCP then TLS).
    #[arg(long, default_value_t = 2)]
    pub link_rounds: usize,
    /// fleet: seconds of the `park` robot recorded (and replayed by every robot).
    #[arg(long, default_value_t = 40.0)]
    pub record_s: f64,
    /// fleet: the scenario the recorded robot drives in.
    #[arg(long, default_value = "config/scenarios/park.toml")]
    pub scenario: std::path::PathBuf,
    /// fleet-robots (internal): the station endpoint the robots connect to.
    #[arg(long, hide = true)]
    pub fleet_endpoint: Option<String>,
}

/// Benchmarks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchWhat {
    /// Merge, latency and link.
    All,
    /// Merge throughput.
    Merge,
    /// Pose latency.
    Latency,
    /// Pose latency and tile throughput over TLS against plain TCP.
    Link,
    /// N robots replaying recorded `park` tiles and poses into one station (not part of `all`).
    Fleet,
    /// The robots' side of `fleet`, run by it as a child process.
    #[value(hide = true)]
    FleetRobots,
}

/// Runs the benchmarks, printing a summary to stderr and one JSON line to stdout.
pub async fn run(a: BenchArgs) -> anyhow::Result<()> {
    match a.what {
        BenchWhat::Fleet => {
            println!("{}", fleet::run(&a).await?);
            return Ok(());
        }
        BenchWhat::FleetRobots => return fleet::robots_side(&a).await,
        _ => {}
    }
    let mut out = serde_json::Map::new();
    if matches!(a.what, BenchWhat::All | BenchWhat::Merge) {
        let n = a.tiles;
        let m = tokio::task::spawn_blocking(move || merge_bench(n)).await??;
        out.insert("merge".into(), m);
    }
    if matches!(a.what, BenchWhat::All | BenchWhat::Latency) {
        out.insert("latency".into(), latency_bench(&a).await?);
    }
    if matches!(a.what, BenchWhat::All | BenchWhat::Link) {
        out.insert(
            "link".into(),
            link::run(a.link_robots, a.link_samples, a.link_tiles, a.link_rounds).await?,
        );
    }
    println!("{}", serde_json::Value::Object(out));
    Ok(())
}

/// A tile as a robot's mapper makes it: a band of known ground with an obstacle blob, smooth
/// heights and costs, stamps of one scan, the rest unknown.
pub fn robot_like_tile(index: TileIndex, version: u64, stamp_s: u32, seed: u64) -> Tile {
    let mut t = Tile::new(index, Lattice::default());
    t.version = version;
    let n = t.lattice.tile_cells as i64;
    let s = seed as i64;
    let (ox, oy) = ((s * 17) % n, (s * 29) % n);
    // An obstacle blob inside the disc and the tile.
    let (bx, by) = ((ox + 4).min(n - 3), (oy + 3).min(n - 3));
    for r in 0..n {
        for c in 0..n {
            // Sensor reach: a disc around a point that moves with the seed.
            let (dx, dy) = (c - ox, r - oy);
            if dx * dx + dy * dy > (n * n) / 2 {
                continue;
            }
            let blob = (c - bx).pow(2) + (r - by).pow(2) < 9;
            let state = if blob {
                CellState::Obstacle
            } else if (c + r + s) % 23 == 0 {
                CellState::Inflated
            } else {
                CellState::Traversable
            };
            t.cells[(r * n + c) as usize] = Cell {
                state,
                cost: ((c + r) % 40) as u8,
                height_cm: (((c * 3 + r * 2 + s) % 50) - 25) as i16,
                hits: (1 + (c + s) % 20) as u8,
                stamp_s: stamp_s + (r % 2) as u32,
                rev: 0,
            };
        }
    }
    t
}

fn rate(n: usize, d: Duration) -> f64 {
    n as f64 / d.as_secs_f64().max(1e-9)
}

fn merge_bench(n: usize) -> anyhow::Result<serde_json::Value> {
    // 400 tile indices (20 x 20), each updated n / 400 times with newer stamps (one wire stamp
    // step apart), as robots do.
    let encoded: Vec<Vec<u8>> = (0..n)
        .map(|i| {
            let idx = TileIndex {
                tx: (i % 20) as i32,
                ty: ((i / 20) % 20) as i32,
            };
            let round = (i / 400) as u32;
            encode_tile(&robot_like_tile(
                idx,
                u64::from(round) + 1,
                1_790_000_000 + round * common::grid::WIRE_STAMP_STEP_S,
                i as u64,
            ))
        })
        .collect();
    let bytes: usize = encoded.iter().map(Vec::len).sum();

    // Baseline: decoding alone, the work no merge can avoid.
    let t0 = Instant::now();
    let mut decoded = Vec::with_capacity(n);
    for e in &encoded {
        decoded.push(decode_tile(e).context("decode")?);
    }
    let decode = t0.elapsed();

    // The merge step itself on decoded tiles.
    let mut map = MergedMap::default();
    let t0 = Instant::now();
    for t in &decoded {
        map.merge("d0", t)?;
    }
    let merge_only = t0.elapsed();

    // What the station runs: its merge thread, fed encoded payloads through its queue, decoding
    // on its pool, merging, re-encoding every changed merged tile and handing it to the store
    // sink; with one decoding thread and with one per core.
    let threads = crate::merge::default_threads();
    let (one, _) = merge_pipeline(&encoded, 1);
    let (pipeline, changed) = merge_pipeline(&encoded, threads);

    let (r_dec, r_merge, r_pipe, r_one) = (
        rate(n, decode),
        rate(n, merge_only),
        rate(n, pipeline),
        rate(n, one),
    );
    eprintln!(
        "merge: {n} tiles ({:.0} B each on the wire): station merge {r_pipe:.0} tiles/s with \
         {threads} decoding threads, {r_one:.0} tiles/s with 1 ({:.2}x); (decode + merge + \
         re-encode), merge step alone {r_merge:.0} tiles/s; baseline decode alone on one core \
         {r_dec:.0} tiles/s -> the pool runs at {:.2}x one core's decode speed",
        bytes as f64 / n as f64,
        r_pipe / r_one,
        r_pipe / r_dec
    );
    Ok(json!({
        "tiles": n, "mean_tile_bytes": bytes as f64 / n as f64, "changed_tiles": changed,
        "threads": threads, "pipeline_tiles_per_s": r_pipe,
        "pipeline_1_thread_tiles_per_s": r_one, "threads_vs_1": r_pipe / r_one,
        "merge_only_tiles_per_s": r_merge,
        "baseline_decode_tiles_per_s": r_dec, "pipeline_vs_decode": r_pipe / r_dec,
    }))
}

/// Time for `encoded` through a [`MergeWorker`] with `threads` decoding threads, and the number
/// of changed tiles it handed to the sink.
fn merge_pipeline(encoded: &[Vec<u8>], threads: usize) -> (Duration, usize) {
    let map = Arc::new(RwLock::new(MergedMap::default()));
    let changes = Arc::new(Mutex::new(0usize));
    let c2 = changes.clone();
    let worker = MergeWorker::with_threads(
        map,
        Box::new(move |_, enc: Vec<u8>| {
            std::hint::black_box(enc);
            *c2.lock().unwrap_or_else(|p| p.into_inner()) += 1;
        }),
        Arc::new(AtomicU64::new(0)),
        threads,
    );
    let jobs: Vec<MergeJob> = encoded
        .iter()
        .map(|e| MergeJob {
            datum_id: "d0".into(),
            robot: "bench".into(),
            key_index: None,
            encoded: e.clone(),
        })
        .collect();
    let q = worker.sender();
    let t0 = Instant::now();
    for j in jobs {
        q.send(j);
    }
    worker.finish();
    let took = t0.elapsed();
    let changed = *changes.lock().unwrap_or_else(|p| p.into_inner());
    (took, changed)
}

/// Median, p99 and max of latencies in microseconds.
fn stats(mut v: Vec<f64>) -> serde_json::Value {
    if v.is_empty() {
        return json!(null);
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    json!({"n": v.len(), "median_us": q(0.5), "p99_us": q(0.99), "max_us": v[v.len() - 1]})
}

fn free_endpoint() -> anyhow::Result<String> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    Ok(format!("tcp/127.0.0.1:{port}"))
}

async fn latency_bench(a: &BenchArgs) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        a.robots > 0 && a.samples > 0 && a.rate_hz > 0.0,
        "nothing to measure"
    );
    let dir = std::env::temp_dir().join(format!("terranav-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let station_ep = free_endpoint()?;
    let pub_ep = free_endpoint()?;
    let st = Station::start(StationOptions {
        zenoh: station::zenoh_config(None, None, std::slice::from_ref(&station_ep), &[])?,
        db: dir.join("bench.sqlite"),
        alerts: crate::alerts::AlertConfig::default(),
        map_history_s: 60,
    })
    .await?;
    let mut events = st.inner.events.subscribe();
    // The robot's side: a peer that connects to the station, like the robot bus.
    let publisher = zenoh::open(station::zenoh_config(
        None,
        None,
        std::slice::from_ref(&pub_ep),
        std::slice::from_ref(&station_ep),
    )?)
    .await
    .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    // Baseline: a bare subscriber one loopback hop from the same publisher.
    let bare = zenoh::open(station::zenoh_config(
        None,
        None,
        &[],
        std::slice::from_ref(&pub_ep),
    )?)
    .await
    .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;

    let sent: SentPoses = Arc::default();
    let bare_lat: Arc<Mutex<Vec<f64>>> = Arc::default();
    let (s2, b2) = (sent.clone(), bare_lat.clone());
    let _sub = bare
        .declare_subscriber(keys::all())
        .callback(move |sample| {
            let now = Instant::now();
            let Ok((rid, Topic::Pose)) = keys::parse(sample.key_expr().as_str()) else {
                return;
            };
            // Decode like the station does, so both sides pay for it.
            let Ok(p) = msg::decode::<Pose>(&sample.payload().to_bytes()) else {
                return;
            };
            if let Some(t) = s2
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .get(&(rid.to_string(), p.seq))
            {
                b2.lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(now.duration_since(*t).as_secs_f64() * 1e6);
            }
        })
        .await
        .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    let station_lat: Arc<Mutex<Vec<f64>>> = Arc::default();
    let (s3, l3) = (sent.clone(), station_lat.clone());
    let listener = tokio::spawn(async move {
        while let Ok(ev) = events.recv().await {
            let now = Instant::now();
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&ev) else {
                continue;
            };
            if v["type"] != "pose" {
                continue;
            }
            let k = v["robot"].as_str().unwrap_or("").to_string();
            let seq = v["pose"]["seq"].as_u64().unwrap_or(u64::MAX) as u32;
            if let Some(t) = s3.lock().unwrap_or_else(|p| p.into_inner()).get(&(k, seq)) {
                l3.lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(now.duration_since(*t).as_secs_f64() * 1e6);
            }
        }
    });
    // Let the links come up and the subscriptions propagate.
    tokio::time::sleep(Duration::from_millis(1500)).await;

    let ids: Vec<RobotId> = (0..a.robots)
        .map(|i| RobotId::new(format!("bench-{i}")))
        .collect::<Result<_, _>>()?;
    // Sessions first, so the station handles the poses as a real robot's (tracks to the store).
    for (k, id) in ids.iter().enumerate() {
        let s = msg::Session {
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
            source: format!("bench:{k}"),
            agent_version: station::VERSION.into(),
        };
        publisher
            .put(keys::key(id, Topic::Session), msg::encode(&s))
            .await
            .map_err(|e| anyhow::anyhow!("zenoh put: {e}"))?;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let period = Duration::from_secs_f64(1.0 / a.rate_hz);
    let robots: Vec<(zenoh::Session, RobotId)> = ids
        .iter()
        .map(|id| (publisher.clone(), id.clone()))
        .collect();
    let s4 = sent.clone();
    send_poses(
        &robots,
        period,
        a.robots * 3,
        a.samples,
        |id, seq, timed| {
            if timed {
                s4.lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .insert((id.to_string(), seq), Instant::now());
            }
        },
    )
    .await?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    listener.abort();
    let _ = bare.close().await;
    let _ = publisher.close().await;
    st.stop().await;
    let _ = std::fs::remove_dir_all(&dir);

    let take = |m: &Arc<Mutex<Vec<f64>>>| {
        std::mem::take(&mut *m.lock().unwrap_or_else(|p| p.into_inner()))
    };
    let (sv, bv) = (take(&station_lat), take(&bare_lat));
    let (ns, nb) = (sv.len(), bv.len());
    let (s, b) = (stats(sv), stats(bv));
    let ratio = |k: &str| match (s[k].as_f64(), b[k].as_f64()) {
        (Some(x), Some(y)) if y > 0.0 => json!(x / y),
        _ => json!(null),
    };
    eprintln!(
        "latency: pose put -> station event: median {} us, p99 {} us ({ns} of {} samples); \
         baseline bare zenoh subscriber: median {} us, p99 {} us ({nb}); station/baseline: \
         median {:.2}x, p99 {:.2}x",
        s["median_us"]
            .as_f64()
            .map_or("-".into(), |v| format!("{v:.0}")),
        s["p99_us"]
            .as_f64()
            .map_or("-".into(), |v| format!("{v:.0}")),
        a.samples,
        b["median_us"]
            .as_f64()
            .map_or("-".into(), |v| format!("{v:.0}")),
        b["p99_us"]
            .as_f64()
            .map_or("-".into(), |v| format!("{v:.0}")),
        ratio("median_us").as_f64().unwrap_or(f64::NAN),
        ratio("p99_us").as_f64().unwrap_or(f64::NAN),
    );
    Ok(json!({
        "samples": a.samples, "robots": a.robots, "rate_hz": a.rate_hz,
        "station": s, "baseline_bare_subscriber": b,
        "median_ratio": ratio("median_us"), "p99_ratio": ratio("p99_us"),
    }))
}

/// When each timed pose was put, by (robot, seq).
pub(crate) type SentPoses = Arc<Mutex<HashMap<(String, u32), Instant>>>;

/// The synthetic pose loop of every pose benchmark (latency, link, fleet): `warmup + samples`
/// poses round-robin over `robots` (a session and the robot it publishes as), one every
/// `period`, each robot's `seq` counting up, put as the robot bus puts poses (best effort:
/// dropped rather than queued when congested). `on_sent(robot, seq, timed)` runs just before
/// each put; the first `warmup` are not timed.
pub(crate) async fn send_poses(
    robots: &[(zenoh::Session, RobotId)],
    period: Duration,
    warmup: usize,
    samples: usize,
    mut on_sent: impl FnMut(&RobotId, u32, bool),
) -> anyhow::Result<()> {
    anyhow::ensure!(!robots.is_empty(), "no robots to send poses for");
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    for i in 0..warmup + samples {
        tick.tick().await;
        let k = i % robots.len();
        let seq = (i / robots.len()) as u32;
        let p = Pose {
            t_unix_ms: station::now_unix_ms(),
            seq,
            x_m: i as f64 * 0.01,
            y_m: 2.0,
            z_m: 0.1,
            yaw_rad: 0.3,
            pitch_rad: 0.0,
            roll_rad: 0.0,
            v_mps: 0.8,
            omega_rps: 0.0,
            fix: FixState::RtkFixed,
            lat_lon_deg: Some((48.2, 16.37)),
        };
        let bytes = msg::encode(&p);
        let (session, id) = &robots[k];
        on_sent(id, seq, i >= warmup);
        session
            .put(keys::key(id, Topic::Pose), bytes)
            .congestion_control(zenoh::qos::CongestionControl::Drop)
            .await
            .map_err(|e| anyhow::anyhow!("zenoh put: {e}"))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_like_tiles_round_trip_and_merge_bench_counts_every_tile() {
        let t = robot_like_tile(TileIndex { tx: 3, ty: -2 }, 4, 1_790_000_000, 7);
        let known = t
            .cells
            .iter()
            .filter(|c| c.state != CellState::Unknown)
            .count();
        assert!(known > 1000 && known < 4096, "{known} known cells");
        assert!(t.cells.iter().any(|c| c.state == CellState::Obstacle));
        assert_eq!(
            decode_tile(&encode_tile(&t)).unwrap(),
            common::grid::wire_tile(&t)
        );
        let r = merge_bench(800).unwrap();
        assert_eq!(r["tiles"], 800);
        // Every update carries newer stamps, so every one changes its merged tile.
        assert_eq!(r["changed_tiles"], 800);
        assert!(r["pipeline_tiles_per_s"].as_f64().unwrap() > 0.0);
    }
}
