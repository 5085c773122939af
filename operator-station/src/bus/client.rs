//! The short-lived Zenoh sessions of the CLI commands (`robots`, `goal`, `stop`): who is alive,
//! a robot's session and position, and one command sent in its envelope.

use std::time::Duration;

use common::command::RobotContext;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, Session};
use zenoh::query::ConsolidationMode;

use crate::station;

/// Opens a session with `zc`.
pub async fn open(zc: zenoh::Config) -> anyhow::Result<zenoh::Session> {
    zenoh::open(zc)
        .await
        .map_err(|e| anyhow::anyhow!("zenoh: {e}"))
}

/// The robots whose liveliness token answers within `wait`, sorted.
pub async fn alive_robots(s: &zenoh::Session, wait: Duration) -> anyhow::Result<Vec<String>> {
    let replies = s
        .liveliness()
        .get(keys::all_alive())
        .timeout(wait)
        .await
        .map_err(|e| anyhow::anyhow!("liveliness query: {e}"))?;
    let mut out = Vec::new();
    while let Ok(r) = replies.recv_async().await {
        if let Ok(sample) = r.result() {
            if let Ok((id, Topic::Alive)) = keys::parse(sample.key_expr().as_str()) {
                out.push(id.to_string());
            }
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

/// The robot's session as its queryable answers within `wait` (None: no answer or undecodable).
pub async fn robot_session_msg(
    s: &zenoh::Session,
    rid: &RobotId,
    wait: Duration,
) -> Option<Session> {
    let mut session: Option<Session> = None;
    if let Ok(replies) = s
        .get(keys::key(rid, Topic::Session))
        .consolidation(ConsolidationMode::None)
        .timeout(wait)
        .await
    {
        while let Ok(r) = replies.recv_async().await {
            if let Ok(sample) = r.result() {
                session = msg::decode(&sample.payload().to_bytes()).ok();
            }
        }
    }
    session
}

/// Sends one command in its envelope (this call's own sender id) and closes the session.
pub async fn put_and_close<T: serde::Serialize>(
    s: zenoh::Session,
    rid: &RobotId,
    topic: Topic,
    cmd: &T,
) -> anyhow::Result<()> {
    let stamper = common::command::CommandStamper::new(super::sender_id(&s));
    let payload = msg::encode_cmd(stamper.next(station::now_unix_ms()), cmd);
    let r = super::put_command(&s, keys::key(rid, topic), payload)
        .await
        .map_err(|e| anyhow::anyhow!(e));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let _ = s.close().await;
    r
}

/// The robot's position from one of its poses (it publishes them at 10 Hz), for the goal
/// contract; empty when none comes within a second.
pub async fn robot_context(s: &zenoh::Session, rid: &RobotId) -> RobotContext {
    let Ok(sub) = s.declare_subscriber(keys::key(rid, Topic::Pose)).await else {
        return RobotContext::default();
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs(1);
    while let Ok(Ok(sample)) = tokio::time::timeout_at(deadline, sub.recv_async()).await {
        if let Ok(p) = msg::decode::<msg::Pose>(&sample.payload().to_bytes()) {
            return RobotContext {
                position_m: Some((p.x_m, p.y_m)),
                lat_lon_deg: p.lat_lon_deg,
                mapped: None,
            };
        }
    }
    RobotContext::default()
}
