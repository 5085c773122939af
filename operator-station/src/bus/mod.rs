//! The station's Zenoh side, in one place: the session config (built from the settings shared
//! with the robot, [`common::bus_config`]), the subscriptions and queryables of a running station
//! ([`subscribe`]), the commands it publishes ([`put_command`]), the short-lived sessions of the
//! CLI commands ([`client`]), and secure links ([`secure`]). The rest of the station sees samples
//! as `(key, payload)` and sends commands as encoded payloads.

pub mod client;
pub mod confirm;
pub mod secure;
pub mod subscribe;

use std::path::Path;

use common::bus_config::{DefaultListen, SessionPlan};

use crate::station::StationError;

/// Default Zenoh endpoint the station listens on (robots connect there).
pub const DEFAULT_LISTEN_ENDPOINT: &str = "tcp/127.0.0.1:7447";

fn zerr(e: impl std::fmt::Display) -> StationError {
    StationError::Zenoh(e.to_string())
}

/// Builds a Zenoh config: a json5 file or the terranav defaults (peer, multicast scouting off,
/// 1.5 s lease, fast reconnect; [`common::bus_config`], the robot's too), then explicit
/// listen/connect endpoints and mode. Without a file and without `listen` it listens on a
/// loopback port only.
pub fn zenoh_config(
    file: Option<&Path>,
    mode: Option<&str>,
    listen: &[String],
    connect: &[String],
) -> Result<zenoh::Config, StationError> {
    let mut c = match file {
        Some(f) => {
            zenoh::Config::from_file(f).map_err(|e| zerr(format!("{}: {e}", f.display())))?
        }
        None => zenoh::Config::default(),
    };
    let plan = SessionPlan {
        file_given: file.is_some(),
        mode,
        listen,
        connect,
        default_listen: DefaultListen::Loopback,
    };
    for (k, v) in plan.settings() {
        c.insert_json5(k, &v)
            .map_err(|e| zerr(format!("{k} = {v}: {e}")))?;
    }
    Ok(c)
}

/// Opens the station's session with `zc`.
pub async fn open(zc: zenoh::Config) -> Result<zenoh::Session, StationError> {
    zenoh::open(zc).await.map_err(zerr)
}

/// A sender id for the commands of `session`'s process: the session id is random, so it differs
/// for every station and every CLI call.
pub fn sender_id(session: &zenoh::Session) -> u64 {
    let zid = session.zid().to_le_bytes();
    let mut b = [0u8; 8];
    b.copy_from_slice(&zid[..8]);
    u64::from_le_bytes(b)
}

/// Publishes a command (or the zones) to a robot's key: reliable, blocking rather than dropping
/// when the link is congested (a lost stop or goal is worse than a late one).
pub async fn put_command(
    session: &zenoh::Session,
    key: String,
    payload: Vec<u8>,
) -> Result<(), String> {
    session
        .put(key, payload)
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .await
        .map_err(|e| format!("zenoh put: {e}"))
}

/// A task that ends with its owner.
pub struct AbortOnDrop(pub tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}
