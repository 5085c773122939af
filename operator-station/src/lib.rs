//! terranav operator station: tracks robots, merges their tiles into one large map, persists
//! sessions, tracks, routes and tiles in SQLite, and serves the browser UI and its API. With the
//! fleet's certificates (`pki`), its links are TLS with mutual authentication under access rules
//! (`bus::secure`); all its Zenoh I/O is in `bus`.
#![deny(missing_docs)]

pub mod alerts;
pub mod api;
pub mod basemap;
pub mod bus;
pub mod cli;
pub mod deliveries;
pub mod export;
pub mod fleet;
pub mod history;
pub mod merge;
pub mod missions;
pub mod pki;
pub mod pyramid;
/// Secure links, now in the station's bus ([`bus::secure`]).
pub use bus::secure as security;
pub mod station;
pub mod store;
pub mod zones;
