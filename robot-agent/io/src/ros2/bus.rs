//! [`Ros2Bus`]: ROS 2 topics on a Zenoh session, in either key form.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use zenoh::handlers::FifoChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::Sample;
use zenoh::Session;

use super::attachment::Attachment;
use super::keys::{Endpoint, KeyForm, Ros2Graph, RosType, TWIST};
use crate::cdr::{self, CdrError};
use crate::sample::Twist;

/// A Zenoh failure (declaring, publishing).
#[derive(Debug, thiserror::Error)]
#[error("zenoh: {0}")]
pub struct Ros2Error(pub String);

fn zerr(e: impl std::fmt::Display) -> Ros2Error {
    Ros2Error(e.to_string())
}

/// Counts for one subscribed topic.
#[derive(Debug, Default)]
pub struct TopicStats {
    /// Samples decoded.
    pub decoded: AtomicU64,
    /// Samples whose CDR was refused.
    pub bad_cdr: AtomicU64,
    /// rmw-form samples without a readable attachment (still decoded: the payload is what
    /// matters, the attachment only carries metadata).
    pub bad_attachment: AtomicU64,
}

/// A subscribed topic: decoded samples in arrival order.
pub struct Subscription<T> {
    sub: Subscriber<FifoChannelHandler<Sample>>,
    decode: fn(&[u8]) -> Result<T, CdrError>,
    form: KeyForm,
    stats: Arc<TopicStats>,
    _token: Option<LivelinessToken>,
}

impl<T> Subscription<T> {
    /// The next sample: `Some(Ok)` decoded, `Some(Err)` a refused one (already counted; go on),
    /// `None` when the session closed.
    pub async fn recv(&self) -> Option<Result<T, CdrError>> {
        let sample = self.sub.recv_async().await.ok()?;
        if self.form == KeyForm::Rmw {
            let ok = sample
                .attachment()
                .is_some_and(|a| Attachment::decode(&a.to_bytes()).is_ok());
            if !ok {
                self.stats.bad_attachment.fetch_add(1, Ordering::Relaxed);
            }
        }
        let r = (self.decode)(&sample.payload().to_bytes());
        let counter = if r.is_ok() {
            &self.stats.decoded
        } else {
            &self.stats.bad_cdr
        };
        counter.fetch_add(1, Ordering::Relaxed);
        Some(r)
    }

    /// This topic's counters (shared: readable while the subscription runs).
    pub fn stats(&self) -> Arc<TopicStats> {
        self.stats.clone()
    }

    /// The Zenoh key subscribed to.
    pub fn key(&self) -> String {
        self.sub.key_expr().to_string()
    }
}

/// Publishes CDR samples of one type on one topic (with rmw_zenoh's attachment in that form).
pub struct Ros2Publisher {
    publisher: Publisher<'static>,
    form: KeyForm,
    gid: [u8; 16],
    sequence: AtomicU64,
    _token: Option<LivelinessToken>,
}

impl Ros2Publisher {
    /// Sends one encoded sample (`cdr::encode_*`); `now_unix_ns` is the send time for the rmw
    /// attachment (the caller owns the clock).
    pub async fn put_cdr(&self, payload: Vec<u8>, now_unix_ns: i64) -> Result<(), Ros2Error> {
        let put = self.publisher.put(payload);
        match self.form {
            KeyForm::Bridge => put.await.map_err(zerr),
            KeyForm::Rmw => {
                let a = Attachment {
                    sequence_number: self.sequence.fetch_add(1, Ordering::Relaxed) as i64 + 1,
                    source_timestamp_ns: now_unix_ns,
                    source_gid: self.gid,
                };
                put.attachment(a.encode()).await.map_err(zerr)
            }
        }
    }

    /// The Zenoh key published on.
    pub fn key(&self) -> String {
        self.publisher.key_expr().to_string()
    }

    /// Whether a subscriber matches this publisher now (Zenoh's matching status), so a player
    /// can wait for its listener instead of sending into the void.
    pub async fn has_subscribers(&self) -> Result<bool, Ros2Error> {
        self.publisher
            .matching_status()
            .await
            .map(|s| s.matching())
            .map_err(zerr)
    }
}

/// Publishes `geometry_msgs/msg/Twist` on one topic.
pub struct TwistPublisher(Ros2Publisher);

impl TwistPublisher {
    /// Sends one command; `now_unix_ns` is the send time for the rmw attachment (the caller owns
    /// the clock).
    pub async fn put(&self, t: &Twist, now_unix_ns: i64) -> Result<(), Ros2Error> {
        self.0.put_cdr(cdr::encode_twist(t), now_unix_ns).await
    }

    /// The Zenoh key published on.
    pub fn key(&self) -> String {
        self.0.key()
    }
}

/// The robot's ROS 2 graph seen through a Zenoh session. In the rmw form it is a node named
/// `node_name` with its own liveliness token, so `ros2 node list` on the robot shows it.
pub struct Ros2Bus {
    session: Session,
    graph: Ros2Graph,
    node: String,
    zid: String,
    next_entity: AtomicU64,
    _node_token: Option<LivelinessToken>,
}

/// A GID for an entity: rmw_zenoh hashes the entity's token; any stable 16 bytes unique to the
/// entity will do, so this is FNV-1a 128 of the token.
fn gid_of(token: &str) -> [u8; 16] {
    let mut h: u128 = 0x6c62272e07bb014262b821756295c58d;
    for b in token.bytes() {
        h ^= b as u128;
        h = h.wrapping_mul(0x0000000001000000000000000000013B);
    }
    h.to_le_bytes()
}

impl Ros2Bus {
    /// Joins the graph on an open session.
    pub async fn new(
        session: Session,
        graph: Ros2Graph,
        node_name: &str,
    ) -> Result<Self, Ros2Error> {
        let zid = session.zid().to_string();
        let node_token = match graph.form {
            KeyForm::Bridge => None,
            KeyForm::Rmw => Some(
                session
                    .liveliness()
                    .declare_token(graph.node_token(&zid, 0, node_name))
                    .await
                    .map_err(zerr)?,
            ),
        };
        Ok(Ros2Bus {
            session,
            graph,
            node: node_name.to_owned(),
            zid,
            next_entity: AtomicU64::new(1),
            _node_token: node_token,
        })
    }

    /// The graph (form, domain, namespace).
    pub fn graph(&self) -> &Ros2Graph {
        &self.graph
    }

    async fn token(
        &self,
        topic: &str,
        ty: &RosType,
        publisher: bool,
    ) -> Result<Option<(LivelinessToken, String)>, Ros2Error> {
        if self.graph.form == KeyForm::Bridge {
            return Ok(None);
        }
        let key = self.graph.endpoint_token(Endpoint {
            zid: &self.zid,
            node_id: 0,
            entity_id: self.next_entity.fetch_add(1, Ordering::Relaxed) as u32,
            node: &self.node,
            topic,
            ty,
            publisher,
        });
        let token = self
            .session
            .liveliness()
            .declare_token(key.clone())
            .await
            .map_err(zerr)?;
        Ok(Some((token, key)))
    }

    /// Subscribes to `topic` of type `ty`, decoding each sample with `decode` (one of the
    /// `cdr::decode_*` functions).
    pub async fn subscribe<T>(
        &self,
        topic: &str,
        ty: &RosType,
        decode: fn(&[u8]) -> Result<T, CdrError>,
    ) -> Result<Subscription<T>, Ros2Error> {
        let sub = self
            .session
            .declare_subscriber(self.graph.subscribe_key(topic, ty))
            .await
            .map_err(zerr)?;
        let token = self.token(topic, ty, false).await?.map(|(t, _)| t);
        Ok(Subscription {
            sub,
            decode,
            form: self.graph.form,
            stats: Arc::default(),
            _token: token,
        })
    }

    /// Declares a publisher of `ty` on `topic`.
    pub async fn publisher(&self, topic: &str, ty: &RosType) -> Result<Ros2Publisher, Ros2Error> {
        let publisher = self
            .session
            .declare_publisher(self.graph.publish_key(topic, ty))
            .await
            .map_err(zerr)?;
        let (token, gid) = match self.token(topic, ty, true).await? {
            Some((t, key)) => (Some(t), gid_of(&key)),
            None => (None, gid_of(publisher.key_expr().as_ref())),
        };
        Ok(Ros2Publisher {
            publisher,
            form: self.graph.form,
            gid,
            sequence: AtomicU64::new(0),
            _token: token,
        })
    }

    /// Declares the `cmd_vel` publisher on `topic`.
    pub async fn twist_publisher(&self, topic: &str) -> Result<TwistPublisher, Ros2Error> {
        Ok(TwistPublisher(self.publisher(topic, &TWIST).await?))
    }
}
