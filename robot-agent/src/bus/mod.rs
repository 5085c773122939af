//! The only place that touches Zenoh: publishes session, pose, tiles, path, status and routes;
//! answers queries for the session, every current tile and the recorded routes; receives and
//! validates commands.
//!
//! Two faces: [`RobotBus`] is async (tokio), [`BusHandle`] is the blocking-friendly face for the
//! synchronous simulation loop (its `publish_*` calls never block: they hand the message to the
//! bus task). Commands arrive validated as [`Command`]; refused ones arrive as
//! [`Command::Refused`] with the reason, so the agent can put it in its status. Every command's
//! header (sender, sequence, time) goes through a [`ReplayGuard`](common::command::ReplayGuard)
//! first: a replayed command is refused and counted apart.
//!
//! With certificates ([`ZenohSettings::tls`]) the session speaks only TLS with mutual
//! authentication and enforces the robot's access rules ([`secure`]); without, it refuses every
//! endpoint off loopback.

mod command_in;
mod handle;
pub mod orpheus;
pub mod secure;
mod session;
mod settings;
pub mod tiles;
pub mod translate;
pub mod uplink;

use std::time::Duration;

pub use command_in::{parse_command, validate, Command, Parsed};
pub use common::command::CommandLimits;
pub use handle::BusHandle;
pub use session::RobotBus;
pub use settings::{
    apply_terranav_defaults, BusConfig, BusFile, ZenohMode, ZenohSettings, LEASE_MS,
};

/// Teleop silence after which the robot must stop.
pub const DEADMAN: Duration = Duration::from_millis(300);

/// Default endpoint of the operator station (agents connect, the station listens).
pub const DEFAULT_STATION_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// Why the bus could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BusError {
    /// The Zenoh configuration could not be read or is invalid.
    #[error("zenoh config: {0}")]
    Config(String),
    /// The Zenoh session or one of its declarations failed.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// The background runtime could not be started.
    #[error("runtime: {0}")]
    Runtime(String),
    /// An endpoint this robot must not use (a plain link off loopback), with what to do instead.
    #[error("{0}")]
    Refused(String),
}

fn zerr(e: impl std::fmt::Display) -> BusError {
    BusError::Zenoh(e.to_string())
}

/// Counters of the bus, for the status message.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Commands refused since start.
    pub commands_refused: u32,
    /// Payloads on command keys that failed to decode since start.
    pub decode_errors: u32,
    /// Commands refused as replays since start (also counted in `commands_refused`).
    pub commands_replayed: u32,
}

/// The robot's clock for the replay guard and for messages; both faces read it.
fn now_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}
