//! WGS-84 geodetic <-> ECEF <-> ENU conversions and NMEA-0183 sentences.
//!
//! (Being written: see issue 2.)
