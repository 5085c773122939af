//! terranav operator station: tracks robots, merges their tiles into one large map, persists
//! sessions, tracks, routes and tiles in SQLite, and serves the browser UI and its API.
#![deny(missing_docs)]

pub mod alerts;
pub mod api;
pub mod basemap;
pub mod cli;
pub mod fleet;
pub mod merge;
pub mod missions;
pub mod station;
pub mod store;
pub mod zones;
