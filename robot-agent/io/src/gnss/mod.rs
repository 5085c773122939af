//! GNSS input: NMEA-0183 lines from a serial port, a TCP stream or UDP datagrams ([`lines`]),
//! decoded by the shared parser (`common::geo::nmea`) into fixes and headings ([`NmeaDecoder`]),
//! and gpsd's JSON protocol ([`gpsd`]). Every refused line is counted with its reason.

pub mod gpsd;
pub mod lines;
mod nmea;

pub use gpsd::{decode_gpsd_report, GpsdClient, GpsdError};
pub use lines::LineSource;
pub use nmea::{GnssStats, NmeaDecoder};

use crate::sample::{Heading, NavFix};

/// One thing a GNSS source delivers.
#[derive(Clone, Debug, PartialEq)]
pub enum GnssEvent {
    /// A position fix (or a report that there is none: status [`crate::sample::FixStatus::NoFix`]).
    Fix(NavFix),
    /// A true heading.
    Heading(Heading),
}

/// Seconds since the Unix epoch now: sources stamp what they receive (NMEA carries only the
/// time of day, and the receiver's clock is not ours).
pub fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}
