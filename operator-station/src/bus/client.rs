//! The short-lived Zenoh sessions of the CLI commands (`robots`, `goal`, `stop`): who is alive,
//! a robot's session and position, and a command sent until the robot's status shows it.

use std::time::Duration;

use common::command::RobotContext;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, Session, Status};
use zenoh::query::ConsolidationMode;

use super::confirm::{Delivery, Expect, Outcome, Policy, Step};
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

/// The first message on `sub` within `wait` that decodes as a `T` (None: none came or none
/// decoded).
async fn first_decoded<T: serde::de::DeserializeOwned>(
    sub: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    wait: Duration,
) -> Option<T> {
    let deadline = tokio::time::Instant::now() + wait;
    while let Ok(Ok(sample)) = tokio::time::timeout_at(deadline, sub.recv_async()).await {
        if let Ok(m) = msg::decode::<T>(&sample.payload().to_bytes()) {
            return Some(m);
        }
    }
    None
}

/// Sends a command in its envelope (this call's own sender id, a fresh sequence number for every
/// send) until the robot's status shows it taken or refused, at most `policy.attempts` times
/// (`confirm`), then closes the session. `expect` is built from the status the robot published
/// before the first send (if one came within `baseline_wait`), so a goal id can be chosen that
/// the robot is not already showing.
pub async fn send_confirmed<T: serde::Serialize>(
    s: zenoh::Session,
    rid: &RobotId,
    topic: Topic,
    cmd: impl FnOnce(Option<&Status>) -> (T, Expect),
    policy: Policy,
    baseline_wait: Duration,
) -> anyhow::Result<(T, Outcome, Option<Status>)> {
    let sub = s
        .declare_subscriber(keys::key(rid, Topic::Status))
        .await
        .map_err(|e| anyhow::anyhow!("subscribe to {rid}'s status: {e}"))?;
    let baseline = first_decoded::<Status>(&sub, baseline_wait).await;
    let (cmd, expect) = cmd(baseline.as_ref());
    let mut delivery = Delivery::new(expect, policy, baseline);
    let stamper = common::command::CommandStamper::new(super::sender_id(&s));
    let t0 = tokio::time::Instant::now();
    let result = loop {
        match delivery.step(t0.elapsed().as_secs_f64()) {
            Step::Send => {
                let payload = msg::encode_cmd(stamper.next(station::now_unix_ms()), &cmd);
                if let Err(e) = super::put_command(&s, keys::key(rid, topic), payload).await {
                    break Err(anyhow::anyhow!(e));
                }
                delivery.sent(t0.elapsed().as_secs_f64());
            }
            Step::WaitUntil(t_s) => {
                let deadline = t0 + Duration::from_secs_f64(t_s);
                match tokio::time::timeout_at(deadline, sub.recv_async()).await {
                    Ok(Ok(sample)) => {
                        if let Ok(st) = msg::decode::<Status>(&sample.payload().to_bytes()) {
                            delivery.status(st);
                        }
                    }
                    Ok(Err(e)) => break Err(anyhow::anyhow!("{rid}'s status: {e}")),
                    Err(_) => {}
                }
            }
            Step::Done(outcome) => break Ok(outcome),
        }
    };
    drop(sub);
    let _ = s.close().await;
    result.map(|outcome| (cmd, outcome, delivery.last_status().cloned()))
}

/// The robot's position from one of its poses (it publishes them at 10 Hz), for the goal
/// contract; empty when none comes within a second.
pub async fn robot_context(s: &zenoh::Session, rid: &RobotId) -> RobotContext {
    let Ok(sub) = s.declare_subscriber(keys::key(rid, Topic::Pose)).await else {
        return RobotContext::default();
    };
    match first_decoded::<msg::Pose>(&sub, Duration::from_secs(1)).await {
        Some(p) => RobotContext {
            position_m: Some((p.x_m, p.y_m)),
            lat_lon_deg: p.lat_lon_deg,
            mapped: None,
        },
        None => RobotContext::default(),
    }
}
