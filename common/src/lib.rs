//! What the terranav robot agent and operator station must agree on.
//!
//! - [`command`]: the command contract: checks with stable refusal codes, shared by senders and robots.
//! - [`msg`]: the wire messages of the Zenoh key space, postcard-encoded with a schema version.
//! - [`keys`]: every Zenoh key expression, built and parsed by functions.
//! - [`grid`]: traversability cell states, map tiles on the fixed map-frame lattice, and the tile codec.
//! - [`geo`]: WGS-84 geodetic / ECEF / ENU conversions and NMEA-0183 sentences.
//! - [`geom`]: small SE(2)/SE(3) helpers over nalgebra.
//! - [`zone`]: polygon geometry of keep-out and slow zones (inside, distance, checks).
//! - [`robot`]: the robot profile (body, limits, sensor mounts) that agent, simulator and station read.
//! - [`security`]: identities, the access rules on the key space, TLS settings, the PKI folder layout,
//!   and which endpoints are loopback.
#![deny(missing_docs)]

pub mod bus_config;
pub mod command;
pub mod geo;
pub mod geom;
pub mod grid;
pub mod keys;
pub mod msg;
pub mod robot;
pub mod security;
pub mod shared_data;
pub mod zone;
