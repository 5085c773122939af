//! NMEA lines -> [`GnssEvent`]s, with counts of what was used and what was refused.

use std::collections::BTreeMap;

use common::geo::nmea::{parse_sentence, Sentence};

use super::GnssEvent;
use crate::sample::{FixStatus, Heading, NavFix};

/// What an NMEA stream delivered.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GnssStats {
    /// Lines that were valid sentences.
    pub sentences: u64,
    /// Fixes produced (GGA).
    pub fixes: u64,
    /// Headings produced (HDT, THS, PASHR).
    pub headings: u64,
    /// Refused lines by reason (the parser's error, without the line's own values).
    pub refused: BTreeMap<String, u64>,
}

impl GnssStats {
    /// All refused lines.
    pub fn refused_total(&self) -> u64 {
        self.refused.values().sum()
    }
}

/// Turns NMEA lines into fixes (from GGA) and headings (from HDT, THS, PASHR); other valid sentences are
/// counted and skipped.
#[derive(Debug, Default)]
pub struct NmeaDecoder {
    stats: GnssStats,
}

/// A short, value-free name for a refusal, so the counts group by kind.
fn reason(e: &common::geo::nmea::NmeaError) -> String {
    let s = format!("{e:?}");
    s.split(['(', ' ', '{'])
        .next()
        .unwrap_or("Other")
        .to_owned()
}

impl NmeaDecoder {
    /// A decoder with zero counts.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counts so far.
    pub fn stats(&self) -> &GnssStats {
        &self.stats
    }

    /// Decodes one line received at `recv_s` (Unix seconds).
    pub fn feed(&mut self, line: &str, recv_s: f64) -> Option<GnssEvent> {
        let line = line.trim();
        if line.is_empty() {
            return None;
        }
        let sentence = match parse_sentence(line) {
            Ok(s) => s,
            Err(e) => {
                *self.stats.refused.entry(reason(&e)).or_default() += 1;
                return None;
            }
        };
        self.stats.sentences += 1;
        match sentence {
            Sentence::Gga(g) => {
                self.stats.fixes += 1;
                let status = match (g.lat_deg, g.lon_deg) {
                    (Some(_), Some(_)) => FixStatus::from_gga_quality(g.quality),
                    _ => FixStatus::NoFix,
                };
                Some(GnssEvent::Fix(NavFix {
                    stamp_s: recv_s,
                    lat_deg: g.lat_deg.unwrap_or(f64::NAN),
                    lon_deg: g.lon_deg.unwrap_or(f64::NAN),
                    // Without the geoid separation only the orthometric height is known.
                    alt_m: g.alt_hae_m().or(g.alt_msl_m).unwrap_or(f64::NAN),
                    status,
                    covariance_m2: None,
                    gga_quality: Some(g.quality),
                }))
            }
            Sentence::Hdt(_) | Sentence::Ths(_) | Sentence::Pashr(_) => {
                let heading_deg = match sentence {
                    Sentence::Hdt(h) => h.heading_deg,
                    Sentence::Ths(h) => h.heading_deg,
                    Sentence::Pashr(p) => p.usable_heading_deg(),
                    _ => None,
                }?;
                self.stats.headings += 1;
                Some(GnssEvent::Heading(Heading {
                    stamp_s: recv_s,
                    heading_deg,
                }))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::geo::nmea::frame;

    #[test]
    fn gga_hdt_and_refusals() {
        let mut d = NmeaDecoder::new();
        let gga = frame("GPGGA,123519,4807.038,N,01131.000,E,4,08,0.9,545.4,M,46.9,M,,");
        let Some(GnssEvent::Fix(f)) = d.feed(&gga, 10.0) else {
            panic!("no fix from {gga}")
        };
        assert_eq!(f.status, FixStatus::Gbas);
        assert!((f.lat_deg - 48.1173).abs() < 1e-9);
        assert!((f.alt_m - 592.3).abs() < 1e-9);
        let Some(GnssEvent::Heading(h)) = d.feed(&frame("GPHDT,274.07,T"), 11.0) else {
            panic!("no heading")
        };
        assert_eq!(h.heading_deg, 274.07);
        let Some(GnssEvent::Heading(h)) = d.feed(&frame("GNTHS,12.5,A"), 11.5) else {
            panic!("no THS heading")
        };
        assert_eq!(h.heading_deg, 12.5);
        let pashr = frame("PASHR,085335.000,224.19,T,-01.26,+00.83,+00.00,0.1,0.1,0.2,2,1");
        let Some(GnssEvent::Heading(h)) = d.feed(&pashr, 11.6) else {
            panic!("no PASHR heading")
        };
        assert_eq!(h.heading_deg, 224.19);
        assert!(d.feed("$GPGGA,garbage*00", 12.0).is_none());
        assert!(d.feed("hello", 12.0).is_none());
        assert!(d.feed(&frame("GPVTG,,T,,M,0.0,N,0.0,K,A"), 12.0).is_none());
        assert_eq!(d.stats().sentences, 5);
        assert_eq!(d.stats().refused_total(), 2);
    }
}
