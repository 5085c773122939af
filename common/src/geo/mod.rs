//! WGS-84 geodesy and NMEA-0183 sentences.
//!
//! - [`wgs84`]: geodetic (lat, lon, ellipsoidal height) <-> ECEF <-> local ENU, exact on the
//!   ellipsoid (no flat-earth approximation), plus [`LocalFrame`] for repeated conversions at one datum.
//! - [`nmea`]: NMEA-0183 framing and checksum, parsers for `GGA`, `RMC`, `HDT` (and `VTG`/`ZDA`/...
//!   recognised and ignored), and formatters so a simulated receiver emits what the parser reads.
//! - [`attitude`]: `THS` (true heading with a mode flag) and `$PASHR` (GNSS/INS attitude).
//! - [`trimble`]: Trimble proprietary `$PTNL,AVR` (dual-antenna attitude) and `$PTNL,GGK` (RTK
//!   position with ellipsoidal height).
//! - [`orpheus`]: the Orpheus navigation-computer protocol (route lists and route edits).
//!
//! Geodetic points are [`crate::msg::Datum`] (degrees, metres above the ellipsoid); ECEF and
//! ENU vectors are `nalgebra::Vector3<f64>` in metres.

pub mod attitude;
pub mod nmea;
pub mod orpheus;
pub mod trimble;
pub mod wgs84;

pub use attitude::{Pashr, Ths};
pub use nmea::{
    format_gga, format_hdt, format_rmc, parse_sentence, Gga, Hdt, NmeaError, Rmc, Sentence,
    UtcDate, UtcTime,
};
pub use orpheus::{format_orpheus, parse_orpheus, OrpheusMessage, RoutePoint};
pub use trimble::{format_avr, format_ggk, Avr, Ggk};
pub use wgs84::{ecef_to_geodetic, enu_to_lla, geodetic_to_ecef, lla_to_enu, LocalFrame};
