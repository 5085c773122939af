//! What a running station declares on its session: the subscription to every robot key, the
//! liveliness subscription, the zone queryable; and the queries that resync a robot.

use std::sync::Arc;
use std::time::Duration;

use common::keys::{self, Topic};
use common::msg;
use zenoh::query::ConsolidationMode;
use zenoh::sample::SampleKind;

use super::{zerr, AbortOnDrop};
use crate::station::{Inner, StationError};

/// What keeps the declarations alive (dropped: undeclared, tasks ended).
pub type Declarations = Vec<Box<dyn std::any::Any + Send + Sync>>;

/// The station's subscriptions on its current session: every robot key, liveliness (with
/// history, so robots already there are seen at once), and the queryable of the zone sets.
/// Samples reach [`Inner::on_sample`] as they come, on Zenoh's task (nothing is decoded there
/// that the merge decodes again).
pub async fn declare(inner: &Arc<Inner>) -> Result<Declarations, StationError> {
    let session = inner.session();
    let mut subs: Declarations = Vec::new();
    {
        let i2 = inner.clone();
        let rt = tokio::runtime::Handle::current();
        let sub = session
            .declare_subscriber(keys::all())
            .callback(move |sample| {
                if sample.kind() != SampleKind::Put {
                    return;
                }
                let _g = rt.enter();
                let key = sample.key_expr().as_str();
                let payload = sample.payload().to_bytes();
                i2.on_sample(key, &payload);
            })
            .await
            .map_err(zerr)?;
        subs.push(Box::new(sub));
    }
    let i3 = inner.clone();
    let rt = tokio::runtime::Handle::current();
    let live = session
        .liveliness()
        .declare_subscriber(keys::all_alive())
        .history(true)
        .callback(move |sample| {
            let _g = rt.enter();
            i3.on_liveliness(sample.key_expr().as_str(), sample.kind() == SampleKind::Put);
        })
        .await
        .map_err(zerr)?;
    subs.push(Box::new(live));
    // Robots that start after the zones were drawn ask for them here.
    let zq = session
        .declare_queryable(keys::all_zones())
        .await
        .map_err(zerr)?;
    let i4 = inner.clone();
    let zone_task = tokio::spawn(async move {
        while let Ok(q) = zq.recv_async().await {
            let key = q.key_expr().as_str().to_string();
            let Ok((robot, Topic::Zones)) = keys::parse(&key) else {
                continue;
            };
            if let Some(set) = i4.zone_set(robot.as_str()) {
                if let Err(e) = q.reply(&key, msg::encode(&set)).await {
                    tracing::warn!("zones reply to {robot}: {e}");
                }
            }
        }
    });
    subs.push(Box::new(AbortOnDrop(zone_task)));
    Ok(subs)
}

/// Asks every queryable on `selector` (a robot's session, tiles or route), handing each reply to
/// `on_sample` as if it had been published; the number of replies.
pub async fn query_all(
    session: &zenoh::Session,
    selector: &str,
    mut on_sample: impl FnMut(&str, &[u8]),
) -> usize {
    let replies = match session
        .get(selector)
        .consolidation(ConsolidationMode::None)
        .timeout(Duration::from_secs(5))
        .await
    {
        Ok(r) => r,
        Err(e) => {
            tracing::warn!("query {selector} failed: {e}");
            return 0;
        }
    };
    let mut n = 0;
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            let key = sample.key_expr().as_str().to_string();
            let payload = sample.payload().to_bytes();
            on_sample(&key, &payload);
            n += 1;
        }
    }
    n
}
