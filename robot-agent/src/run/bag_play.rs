//! `robot-agent lidar play`: a ROS 2 bag's `velodyne_msgs/msg/VelodyneScan` messages published
//! as a VLP-16 driver would, on a ROS 2 topic over Zenoh (bridge or rmw key form), at the pace
//! they were recorded. The payload is the recorded CDR, unchanged, unless `restamp` moves every
//! stamp so the first message is now (for mixing a recording with live sensors).

use crate::bus::ZenohSettings;
use io::ros2::keys::VELODYNE_SCAN;
use io::ros2::{Ros2Bus, Ros2Graph};
use sensing::velodyne::rosbag::{decode_velodyne_scan, encode_velodyne_scan, BagReader};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Time left for the last messages to leave before the session closes, seconds.
const LINGER_S: f64 = 0.5;

/// What to play, and where.
#[derive(Clone, Debug)]
pub struct PlayOptions {
    /// The bag: a `.db3` file, or a bag folder holding one.
    pub bag: PathBuf,
    /// The bag topic to read (default: its first VelodyneScan topic).
    pub topic: Option<String>,
    /// The topic to publish on (default: the bag topic).
    pub publish_as: Option<String>,
    /// The ROS 2 graph (key form, domain, namespace).
    pub graph: Ros2Graph,
    /// The Zenoh session (listen, like a bridge; or connect).
    pub zenoh: ZenohSettings,
    /// Speed factor (2 = twice as fast as recorded).
    pub rate: f64,
    /// Wait this long for a subscriber before the first message (0: do not wait), seconds.
    pub wait_subscriber_s: f64,
    /// Shift every stamp so the first message is stamped now.
    pub restamp: bool,
}

fn unix_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// The `.db3` of `bag` (the file, or the only one in the folder).
fn db3(bag: &Path) -> anyhow::Result<PathBuf> {
    if !bag.is_dir() {
        return Ok(bag.to_path_buf());
    }
    let files: Vec<PathBuf> = std::fs::read_dir(bag)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "db3"))
        .collect();
    match files.as_slice() {
        [one] => Ok(one.clone()),
        [] => anyhow::bail!("{}: no .db3 file in the folder", bag.display()),
        _ => anyhow::bail!("{}: several .db3 files; name one", bag.display()),
    }
}

/// Plays the bag until its end or `stop`; returns the summary.
pub fn play(o: &PlayOptions, stop: &AtomicBool) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(o.rate.is_finite() && o.rate > 0.0, "--rate must be > 0");
    let path = db3(&o.bag)?;
    let mut reader = BagReader::open(&path, o.topic.as_deref())?;
    let topic = o.publish_as.clone().unwrap_or_else(|| reader.topic.clone());
    // Zenoh needs the multi-thread scheduler.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    let config = o.zenoh.to_config()?;
    rt.block_on(async {
        let session = zenoh::open(config)
            .await
            .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
        let bus = Ros2Bus::new(session, o.graph.clone(), "terranav_player").await?;
        let publisher = bus.publisher(&topic, &VELODYNE_SCAN).await?;
        tracing::info!(
            "playing {} ({} messages of {}) on {}",
            path.display(),
            reader.len(),
            reader.topic,
            publisher.key()
        );
        let waiting = Instant::now();
        if o.wait_subscriber_s > 0.0 {
            while !publisher.has_subscribers().await? {
                anyhow::ensure!(
                    waiting.elapsed().as_secs_f64() < o.wait_subscriber_s,
                    "no subscriber on {} within {} s",
                    publisher.key(),
                    o.wait_subscriber_s
                );
                if stop.load(Ordering::Relaxed) {
                    return Ok(serde_json::json!({ "messages": 0, "stopped": true }));
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
        let waited_s = waiting.elapsed().as_secs_f64();
        let (mut messages, mut bytes, mut bad) = (0u64, 0u64, 0u64);
        let mut first: Option<(i64, Instant)> = None;
        let mut shift_s: Option<f64> = None;
        while let Some((t_ns, blob)) = reader.next_raw()? {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            match first {
                None => first = Some((t_ns, Instant::now())),
                Some((t0_ns, wall0)) => {
                    let due = wall0
                        + Duration::from_secs_f64(((t_ns - t0_ns) as f64 * 1e-9 / o.rate).max(0.0));
                    tokio::time::sleep_until(due.into()).await;
                }
            }
            let payload = if o.restamp {
                match decode_velodyne_scan(&blob) {
                    Ok(mut m) => {
                        let by = *shift_s.get_or_insert_with(|| unix_s() - m.stamp_s);
                        m.stamp_s += by;
                        for p in &mut m.packets {
                            p.stamp_s += by;
                        }
                        encode_velodyne_scan(&m)
                    }
                    // Sent as recorded: the listener counts it, as it would from the robot.
                    Err(e) => {
                        tracing::warn!("bag message at {t_ns} ns: {e}; sent unchanged");
                        bad += 1;
                        blob
                    }
                }
            } else {
                blob
            };
            bytes += payload.len() as u64;
            publisher
                .put_cdr(payload, (unix_s() * 1e9) as i64)
                .await
                .map_err(|e| anyhow::anyhow!("publishing: {e}"))?;
            messages += 1;
        }
        tokio::time::sleep(Duration::from_secs_f64(LINGER_S)).await;
        Ok(serde_json::json!({
            "bag": path.display().to_string(),
            "topic": reader.topic,
            "key": publisher.key(),
            "messages": messages,
            "bytes": bytes,
            "undecodable": bad,
            "waited_for_subscriber_s": waited_s,
        }))
    })
}
