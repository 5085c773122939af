//! `operator-station bench fleet --robots N`: one station and N lightweight robots on loopback,
//! over real Zenoh sessions, at a real robot's rates.
//!
//! The robots' side runs in a child process (`bench fleet-robots`), so that the CPU and memory
//! measured are the station's own:
//! 1. it records a real robot once: `robot-agent` on the `park` scenario (the demo's robot:
//!    simulated world plus agent) connected to a recorder session, driving a goal 40 m along the
//!    main path, for `--record-s` seconds; every tile it publishes is kept with its time and
//!    bytes (nothing is written to disk);
//! 2. it opens N client sessions to the station, each a robot with its own session message and
//!    datum (so every robot's tiles are new work for the merge), and replays the recorded tiles
//!    on the recorded timeline (robot k shifted by k/N of a second) while every robot publishes
//!    poses at 10 Hz through the shared pose loop ([`super::send_poses`]);
//! 3. it prints a line for every tile and pose it puts (robot, tile or seq, Unix time in µs).
//!
//! The station (this process) notes when each tile change and pose event comes out of it.
//! Merge lag: a tile's put to the first change of that tile merged after it (a put whose tile did
//! not change is counted with the next change, so the lag is an upper bound); pose latency: put
//! to the station's pose event (it forwards at most ~10 Hz per robot).

use std::collections::{BTreeMap, HashMap};
use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use common::command::CommandStamper;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, GoalCmd, GoalTarget, Session};
use serde_json::json;
use tokio::sync::broadcast::error::RecvError;

use super::{free_endpoint, send_poses, BenchArgs};
use crate::bus;
use crate::station::{self, Station, StationOptions};

/// Unix time now, µs (both processes read the same clock).
fn now_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0)
}

/// This process's CPU time (user + system), seconds, from `/proc/self/stat` (Linux's 100 ticks
/// a second); None elsewhere.
fn cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces) start at the state, field 3.
    let rest = s.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// A `/proc/self/status` size in MiB (`VmRSS`, `VmHWM`).
fn mem_mib(field: &str) -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn pct(v: &mut [f64], p: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() - 1) as f64 * p).round() as usize])
}

/// What the robots' process reported.
#[derive(Default)]
struct RobotsLog {
    /// (robot, tx, ty, put µs).
    tiles: Vec<(String, i32, i32, u64)>,
    /// (robot, seq) -> put µs.
    poses: HashMap<(String, u32), u64>,
    /// Replay start and end, µs.
    start_us: Option<u64>,
    end_us: Option<u64>,
    /// CPU seconds of the station when the replay started and ended.
    cpu_start: Option<f64>,
    cpu_end: Option<f64>,
    /// The recording: tiles, distinct tiles, seconds.
    recorded: Option<serde_json::Value>,
    /// The robots' own CPU seconds over the replay.
    robots_cpu_s: Option<f64>,
}

/// What the station emitted: tile changes by (datum, tx, ty) and pose events by (robot, seq),
/// each with the Unix µs it came out.
#[derive(Default)]
struct StationLog {
    tiles: HashMap<(String, i32, i32), Vec<u64>>,
    tile_events: usize,
    last_tile_us: u64,
    poses: HashMap<(String, u32), u64>,
    lagged: u64,
}

/// Runs the fleet bench: the station here, the robots in a child process.
pub async fn run(a: &BenchArgs) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(a.robots > 0 && a.record_s > 0.0, "nothing to measure");
    let dir = std::env::temp_dir().join(format!("terranav-bench-fleet-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = measure(a, &dir).await;
    let _ = std::fs::remove_dir_all(&dir);
    result
}

async fn measure(a: &BenchArgs, dir: &std::path::Path) -> anyhow::Result<serde_json::Value> {
    let ep = free_endpoint()?;
    let st = Station::start(StationOptions {
        zenoh: station::zenoh_config(None, None, std::slice::from_ref(&ep), &[])?,
        db: dir.join("fleet.sqlite"),
        alerts: crate::alerts::AlertConfig::default(),
        map_history_s: 60,
    })
    .await?;
    let log: Arc<Mutex<StationLog>> = Arc::default();
    let mut events = st.inner.events.subscribe();
    let l2 = log.clone();
    let listener = tokio::spawn(async move {
        loop {
            let ev = match events.recv().await {
                Ok(ev) => ev,
                Err(RecvError::Lagged(n)) => {
                    l2.lock().unwrap_or_else(|p| p.into_inner()).lagged += n;
                    continue;
                }
                Err(RecvError::Closed) => break,
            };
            let t = now_us();
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&ev) else {
                continue;
            };
            let mut g = l2.lock().unwrap_or_else(|p| p.into_inner());
            match v["type"].as_str() {
                Some("tile") => {
                    let k = (
                        v["datum_id"].as_str().unwrap_or("").to_string(),
                        v["tx"].as_i64().unwrap_or(0) as i32,
                        v["ty"].as_i64().unwrap_or(0) as i32,
                    );
                    g.tiles.entry(k).or_default().push(t);
                    g.tile_events += 1;
                    g.last_tile_us = t;
                }
                Some("pose") => {
                    let k = (
                        v["robot"].as_str().unwrap_or("").to_string(),
                        v["pose"]["seq"].as_u64().unwrap_or(u64::MAX) as u32,
                    );
                    g.poses.entry(k).or_insert(t);
                }
                _ => {}
            }
        }
    });

    let exe = std::env::current_exe().context("this executable")?;
    let mut child = Command::new(exe)
        .args(["bench", "fleet-robots", "--robots", &a.robots.to_string()])
        .args([
            "--record-s",
            &a.record_s.to_string(),
            "--fleet-endpoint",
            &ep,
        ])
        .arg("--scenario")
        .arg(&a.scenario)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .context("start the robots' process")?;
    let out = child.stdout.take().context("robots' stdout")?;
    let rlog: Arc<Mutex<RobotsLog>> = Arc::default();
    let r2 = rlog.clone();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(out).lines().map_while(Result::ok) {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) else {
                continue;
            };
            let mut g = r2.lock().unwrap_or_else(|p| p.into_inner());
            let robot = v["robot"].as_str().unwrap_or("").to_string();
            let t = v["t_us"].as_u64().unwrap_or(0);
            match v["ev"].as_str() {
                Some("tile") => g.tiles.push((
                    robot,
                    v["tx"].as_i64().unwrap_or(0) as i32,
                    v["ty"].as_i64().unwrap_or(0) as i32,
                    t,
                )),
                Some("pose") => {
                    g.poses
                        .insert((robot, v["seq"].as_u64().unwrap_or(0) as u32), t);
                }
                Some("start") => {
                    g.start_us = Some(t);
                    g.cpu_start = cpu_s();
                }
                Some("end") => {
                    g.end_us = Some(t);
                    g.cpu_end = cpu_s();
                    g.robots_cpu_s = v["robots_cpu_s"].as_f64();
                }
                Some("recorded") => {
                    eprintln!("fleet: recorded {v}");
                    g.recorded = Some(v);
                }
                _ => {}
            }
        }
    });
    let status = tokio::task::spawn_blocking(move || child.wait()).await??;
    let _ = tokio::task::spawn_blocking(move || reader.join()).await;
    anyhow::ensure!(status.success(), "the robots' process failed: {status}");
    // Let the merge drain: until no tile change came for a second (at most 60 s).
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        tokio::time::sleep(Duration::from_millis(250)).await;
        let last = log.lock().unwrap_or_else(|p| p.into_inner()).last_tile_us;
        if now_us().saturating_sub(last) > 1_000_000 || Instant::now() > deadline {
            break;
        }
    }
    let rss_end = mem_mib("VmRSS:");
    let rss_peak = mem_mib("VmHWM:");
    let datums: HashMap<String, String> = {
        let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
        f.robots
            .iter()
            .filter_map(|(id, r)| Some((id.clone(), r.datum_id.clone()?)))
            .collect()
    };
    listener.abort();
    st.stop().await;

    let r = std::mem::take(&mut *rlog.lock().unwrap_or_else(|p| p.into_inner()));
    let s = std::mem::take(&mut *log.lock().unwrap_or_else(|p| p.into_inner()));
    let (start, end) = (
        r.start_us.context("the robots never started replaying")?,
        r.end_us.context("the robots never finished replaying")?,
    );
    // Merge lag: each put to the first change of its tile at or after it.
    let mut puts: BTreeMap<(String, i32, i32), Vec<u64>> = BTreeMap::new();
    for (robot, tx, ty, t) in &r.tiles {
        if let Some(d) = datums.get(robot) {
            puts.entry((d.clone(), *tx, *ty)).or_default().push(*t);
        }
    }
    let mut lags_ms = Vec::new();
    let mut unmerged = 0usize;
    for (k, ts) in &mut puts {
        ts.sort_unstable();
        let mut evs = s.tiles.get(k).cloned().unwrap_or_default();
        evs.sort_unstable();
        let mut j = 0;
        for t in ts.iter() {
            while j < evs.len() && evs[j] < *t {
                j += 1;
            }
            match evs.get(j) {
                Some(e) => lags_ms.push((*e - *t) as f64 / 1000.0),
                None => unmerged += 1,
            }
        }
    }
    let mut pose_ms: Vec<f64> = r
        .poses
        .iter()
        .filter_map(|(k, t)| s.poses.get(k).map(|e| e.saturating_sub(*t) as f64 / 1000.0))
        .collect();
    let replay_s = (end - start) as f64 / 1e6;
    let merged_span_s = (s.last_tile_us.max(end) - start) as f64 / 1e6;
    let tiles_put = r.tiles.len();
    let station_cpu_s = match (r.cpu_start, r.cpu_end) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    let out = json!({
        "recorded": r.recorded,
        "replay_s": replay_s,
        "tiles_put": tiles_put,
        "tile_changes": s.tile_events,
        "tiles_put_per_s": tiles_put as f64 / replay_s.max(1e-9),
        "tiles_never_followed_by_a_change": unmerged,
        "merge_lag_median_ms": pct(&mut lags_ms, 0.5),
        "merge_lag_max_ms": pct(&mut lags_ms, 1.0),
        "poses_put": r.poses.len(),
        "pose_events": pose_ms.len(),
        "pose_latency_median_ms": pct(&mut pose_ms, 0.5),
        "events_lagged": s.lagged,
        "merge_threads": crate::merge::default_threads(),
        "station_cpu_s": station_cpu_s,
        "station_cpu_pct": station_cpu_s.map(|c| 100.0 * c / replay_s.max(1e-9)),
        "station_rss_mib": rss_end,
        "station_rss_peak_mib": rss_peak,
        "robots_process_cpu_s": r.robots_cpu_s,
        // The keys the issue asks for, last so they are easy to find.
        "robots": a.robots,
        "merge_lag_p99_ms": pct(&mut lags_ms, 0.99),
        "pose_latency_p99_ms": pct(&mut pose_ms, 0.99),
        "merge_tiles_per_s": tiles_put.saturating_sub(unmerged) as f64 / merged_span_s.max(1e-9),
    });
    eprintln!(
        "fleet: {} robots, {tiles_put} tiles put in {replay_s:.1} s ({:.0}/s): merge lag p99 {} ms \
         (median {}), pose latency p99 {} ms (median {}, {} of {} poses), station CPU {} % of one \
         core, RSS {} MiB (peak {})",
        a.robots,
        out["tiles_put_per_s"].as_f64().unwrap_or(0.0),
        fmt(&out["merge_lag_p99_ms"]),
        fmt(&out["merge_lag_median_ms"]),
        fmt(&out["pose_latency_p99_ms"]),
        fmt(&out["pose_latency_median_ms"]),
        out["pose_events"],
        out["poses_put"],
        fmt(&out["station_cpu_pct"]),
        fmt(&out["station_rss_mib"]),
        fmt(&out["station_rss_peak_mib"]),
    );
    Ok(out)
}

fn fmt(v: &serde_json::Value) -> String {
    v.as_f64().map_or("-".into(), |x| format!("{x:.1}"))
}

/// One recorded tile: seconds after the goal, its index, its bytes as published.
struct Recorded {
    t_s: f64,
    tx: i32,
    ty: i32,
    bytes: Vec<u8>,
}

/// The robots' process: records a real `park` robot, then replays it as `--robots` robots into
/// the station at `--fleet-endpoint`, printing a JSON line for every put.
pub async fn robots_side(a: &BenchArgs) -> anyhow::Result<()> {
    let ep = a
        .fleet_endpoint
        .clone()
        .context("--fleet-endpoint is required")?;
    let (session_msg, tiles) = record(a).await?;
    let distinct: std::collections::BTreeSet<(i32, i32)> =
        tiles.iter().map(|t| (t.tx, t.ty)).collect();
    println!(
        "{}",
        json!({"ev": "recorded", "tiles": tiles.len(), "distinct_tiles": distinct.len(),
               "seconds": a.record_s, "mean_tile_bytes":
               tiles.iter().map(|t| t.bytes.len()).sum::<usize>() as f64 / tiles.len() as f64})
    );
    let n = a.robots;
    let ids: Vec<RobotId> = (0..n)
        .map(|i| RobotId::new(format!("fleet-{i}")))
        .collect::<Result<_, _>>()?;
    let mut robots = Vec::new();
    for (k, id) in ids.iter().enumerate() {
        // Clients of the station (as robots behind a site router are): no peer mesh among 50.
        let s = zenoh::open(station::zenoh_config(
            None,
            Some("client"),
            &[],
            std::slice::from_ref(&ep),
        )?)
        .await
        .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
        let mut sm = session_msg.clone();
        sm.robot = id.to_string();
        sm.session_id = format!("{id}-fleet-bench");
        sm.source = "bench fleet".into();
        // Its own datum, a kilometre apart per robot, so every robot's tiles are new merges.
        if let Some(d) = sm.datum.as_mut() {
            d.lat_deg += 0.01 * k as f64;
        }
        bus::put_command(&s, keys::key(id, Topic::Session), msg::encode(&sm))
            .await
            .map_err(|e| anyhow::anyhow!(e))?;
        robots.push((s, id.clone()));
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    // The timeline: every robot replays the recording, robot k shifted by k/N of a second.
    let mut timeline: Vec<(f64, usize, usize)> = Vec::with_capacity(n * tiles.len());
    for k in 0..n {
        for (i, t) in tiles.iter().enumerate() {
            timeline.push((t.t_s + k as f64 / n as f64, k, i));
        }
    }
    timeline.sort_by(|a, b| a.0.total_cmp(&b.0));
    let cpu0 = cpu_s();
    println!("{}", json!({"ev": "start", "t_us": now_us()}));
    let t0 = tokio::time::Instant::now();
    let tile_task = async {
        for (t, k, i) in &timeline {
            tokio::time::sleep_until(t0 + Duration::from_secs_f64(*t)).await;
            let (s, id) = &robots[*k];
            let r = &tiles[*i];
            println!(
                "{}",
                json!({"ev": "tile", "robot": id.as_str(), "tx": r.tx, "ty": r.ty, "t_us": now_us()})
            );
            // Tiles are reliable, as the robot bus puts them.
            bus::put_command(
                s,
                keys::key(id, Topic::Tile { tx: r.tx, ty: r.ty }),
                r.bytes.clone(),
            )
            .await
            .map_err(|e| anyhow::anyhow!(e))?;
        }
        anyhow::Ok(())
    };
    // Poses: every robot at 10 Hz for the length of the recording.
    let samples = (n as f64 * 10.0 * (a.record_s + 1.0)) as usize;
    let pose_task = send_poses(
        &robots,
        Duration::from_secs_f64(0.1 / n as f64),
        0,
        samples,
        |id, seq, _| {
            println!(
                "{}",
                json!({"ev": "pose", "robot": id.as_str(), "seq": seq, "t_us": now_us()})
            );
        },
    );
    let (rt, rp) = tokio::join!(tile_task, pose_task);
    rt?;
    rp?;
    let robots_cpu = match (cpu0, cpu_s()) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    println!(
        "{}",
        json!({"ev": "end", "t_us": now_us(), "robots_cpu_s": robots_cpu})
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
    for (s, _) in robots {
        let _ = s.close().await;
    }
    Ok(())
}

/// Runs one real robot in `--scenario`, drives it toward a goal 40 m east of its start, and keeps
/// its session and every tile it publishes for `--record-s` seconds.
async fn record(a: &BenchArgs) -> anyhow::Result<(Session, Vec<Recorded>)> {
    let rec_ep = free_endpoint()?;
    let rec = zenoh::open(station::zenoh_config(
        None,
        None,
        std::slice::from_ref(&rec_ep),
        &[],
    )?)
    .await
    .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    type Heard = Arc<Mutex<(Option<Session>, Vec<(Instant, i32, i32, Vec<u8>)>)>>;
    let heard: Heard = Arc::default();
    let h2 = heard.clone();
    let _sub = rec
        .declare_subscriber(keys::all())
        .callback(move |sample| {
            let now = Instant::now();
            let Ok((_, topic)) = keys::parse(sample.key_expr().as_str()) else {
                return;
            };
            let mut g = h2.lock().unwrap_or_else(|p| p.into_inner());
            match topic {
                Topic::Session => {
                    if let Ok(s) = msg::decode::<Session>(&sample.payload().to_bytes()) {
                        g.0 = Some(s);
                    }
                }
                Topic::Tile { tx, ty } => {
                    g.1.push((now, tx, ty, sample.payload().to_bytes().to_vec()))
                }
                _ => {}
            }
        })
        .await
        .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    let scenario = if a.scenario.is_file() {
        a.scenario.clone()
    } else {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(&a.scenario)
    };
    anyhow::ensure!(scenario.is_file(), "no scenario {}", a.scenario.display());
    let mut children = crate::cli::Children(Vec::new(), false);
    let rid = RobotId::new("rec-1")?;
    crate::cli::start_robot(
        &crate::cli::robot_agent_bin(),
        &scenario,
        rid.as_str(),
        1,
        "0,0,0",
        (&rec_ep, None),
        None,
        &mut children,
    )?;
    let up = Instant::now() + Duration::from_secs(120);
    while heard.lock().unwrap_or_else(|p| p.into_inner()).0.is_none() {
        anyhow::ensure!(
            Instant::now() < up,
            "the recorded robot published no session within 120 s"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The goal twice, a second apart: the first may come before the robot subscribed.
    let stamper = CommandStamper::new(bus::sender_id(&rec));
    for _ in 0..2 {
        let goal = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Map {
                x_m: 40.0,
                y_m: 0.0,
            },
            tolerance_m: 0.0,
        };
        let payload = msg::encode_cmd(stamper.next(station::now_unix_ms()), &goal);
        bus::put_command(&rec, keys::key(&rid, Topic::CmdGoal), payload)
            .await
            .map_err(|e| anyhow::anyhow!(e))?;
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    let t0 = Instant::now();
    tokio::time::sleep(Duration::from_secs_f64(a.record_s)).await;
    drop(children);
    let (session, raw) = std::mem::take(&mut *heard.lock().unwrap_or_else(|p| p.into_inner()));
    let _ = rec.close().await;
    let session = session.context("no session recorded")?;
    // Tiles from the goal on, and those published before it once at time 0 (what a robot
    // joining the station sends first).
    let tiles: Vec<Recorded> = raw
        .into_iter()
        .map(|(t, tx, ty, bytes)| Recorded {
            t_s: t
                .saturating_duration_since(t0)
                .as_secs_f64()
                .min(a.record_s),
            tx,
            ty,
            bytes,
        })
        .collect();
    anyhow::ensure!(
        !tiles.is_empty(),
        "the recorded robot published no tiles in {} s",
        a.record_s
    );
    Ok((session, tiles))
}
