//! gpsd's JSON protocol, the way Linux robots share one receiver: connect to gpsd's TCP port
//! (2947), send `?WATCH={"enable":true,"json":true}`, read one JSON report per line. `TPV`
//! reports carry the fix (mode 0/1 none, 2 2D, 3 3D; `status` 2 DGPS, 3 RTK fixed, 4 RTK float,
//! 5 dead reckoning; `altHAE` the ellipsoidal height, `epx`/`epy`/`epv` 95% errors in metres);
//! `ATT` reports (attitude-capable receivers) give a heading; `VERSION`, `DEVICES`, `WATCH`,
//! `SKY` and the rest are counted and skipped.

use serde::Deserialize;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

use super::lines::LineSource;
use super::GnssEvent;
use crate::sample::{FixStatus, Heading, NavFix};

/// The command that starts gpsd's JSON reports.
pub const WATCH: &str = "?WATCH={\"enable\":true,\"json\":true}\n";

/// Why a gpsd line was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum GpsdError {
    /// Not JSON, or not an object with a `class`.
    #[error("not a gpsd JSON report: {0}")]
    Json(String),
    /// A TPV report whose fields are inconsistent or out of range.
    #[error("bad TPV: {0}")]
    BadTpv(String),
}

#[derive(Deserialize)]
struct Report {
    class: String,
    #[serde(default)]
    mode: Option<u8>,
    #[serde(default)]
    status: Option<u8>,
    #[serde(default)]
    time: Option<String>,
    #[serde(default)]
    lat: Option<f64>,
    #[serde(default)]
    lon: Option<f64>,
    #[serde(default, rename = "altHAE")]
    alt_hae: Option<f64>,
    #[serde(default)]
    alt: Option<f64>,
    #[serde(default)]
    epx: Option<f64>,
    #[serde(default)]
    epy: Option<f64>,
    #[serde(default)]
    epv: Option<f64>,
    #[serde(default)]
    heading: Option<f64>,
}

/// Days from 1970-01-01 to a civil date (proleptic Gregorian; Howard Hinnant's algorithm).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146097 + doe - 719468
}

/// Parses gpsd's ISO-8601 UTC time (`2024-05-01T12:00:00.000Z`) to Unix seconds.
pub fn parse_iso8601_utc(s: &str) -> Option<f64> {
    let s = s.strip_suffix('Z')?;
    let (date, time) = s.split_once('T')?;
    let mut d = date.splitn(3, '-').map(|v| v.parse::<i64>().ok());
    let (y, mo, da) = (d.next()??, d.next()??, d.next()??);
    let mut t = time.splitn(3, ':');
    let h: i64 = t.next()?.parse().ok()?;
    let mi: i64 = t.next()?.parse().ok()?;
    let sec: f64 = t.next()?.parse().ok()?;
    if !(1..=12).contains(&mo)
        || !(1..=31).contains(&da)
        || h > 23
        || mi > 59
        || !(0.0..61.0).contains(&sec)
    {
        return None;
    }
    Some((days_from_civil(y, mo, da) * 86400 + h * 3600 + mi * 60) as f64 + sec)
}

/// Decodes one gpsd line: `Ok(Some)` for a TPV fix (or a `heading` from an attitude-capable
/// receiver's `ATT`), `Ok(None)` for a report of another class, `Err` for garbage. A TPV
/// without `time` is stamped `recv_s`.
pub fn decode_gpsd_report(line: &str, recv_s: f64) -> Result<Option<GnssEvent>, GpsdError> {
    let r: Report = serde_json::from_str(line).map_err(|e| GpsdError::Json(e.to_string()))?;
    let stamp_s = match &r.time {
        Some(t) => parse_iso8601_utc(t).ok_or_else(|| GpsdError::BadTpv(format!("time {t:?}")))?,
        None => recv_s,
    };
    match r.class.as_str() {
        "TPV" => {
            let mode = r.mode.unwrap_or(0);
            let (lat, lon) = match (r.lat, r.lon) {
                (Some(a), Some(o)) if mode >= 2 => (a, o),
                _ => {
                    return Ok(Some(GnssEvent::Fix(NavFix {
                        stamp_s,
                        lat_deg: f64::NAN,
                        lon_deg: f64::NAN,
                        alt_m: f64::NAN,
                        status: FixStatus::NoFix,
                        covariance_m2: None,
                        gga_quality: None,
                    })))
                }
            };
            if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
                return Err(GpsdError::BadTpv(format!("position ({lat}, {lon})")));
            }
            // TPV status: 2 DGPS, 3 RTK fixed, 4 RTK float, 5 dead reckoning, 6 GNSS + DR;
            // 0, 1 and the rest a plain fix.
            let (status, gga_quality) = match r.status.unwrap_or(1) {
                2 => (FixStatus::Sbas, 2),
                3 => (FixStatus::Gbas, 4),
                4 => (FixStatus::Gbas, 5),
                5 | 6 => (FixStatus::Fix, 6),
                _ => (FixStatus::Fix, 1),
            };
            let alt_m = if mode >= 3 {
                r.alt_hae.or(r.alt).unwrap_or(f64::NAN)
            } else {
                f64::NAN
            };
            // gpsd's ep* are 95% bounds; one sigma is about half.
            let covariance_m2 = match (r.epx, r.epy) {
                (Some(x), Some(y)) => {
                    let v = r.epv.map(|v| (v / 2.0).powi(2)).unwrap_or(0.0);
                    Some([
                        (x / 2.0).powi(2),
                        0.0,
                        0.0,
                        0.0,
                        (y / 2.0).powi(2),
                        0.0,
                        0.0,
                        0.0,
                        v,
                    ])
                }
                _ => None,
            };
            Ok(Some(GnssEvent::Fix(NavFix {
                stamp_s,
                lat_deg: lat,
                lon_deg: lon,
                alt_m,
                status,
                covariance_m2,
                gga_quality: Some(gga_quality),
            })))
        }
        "ATT" => Ok(r.heading.filter(|h| h.is_finite()).map(|h| {
            GnssEvent::Heading(Heading {
                stamp_s,
                heading_deg: h.rem_euclid(360.0),
            })
        })),
        _ => Ok(None),
    }
}

/// A gpsd client: reports as [`GnssEvent`]s, with counts.
pub struct GpsdClient {
    lines: LineSource,
    /// Reports decoded into events.
    pub events: u64,
    /// Reports of other classes (VERSION, DEVICES, SKY, ...).
    pub skipped: u64,
    /// Lines refused, and the last reason.
    pub refused: u64,
    /// The last refusal.
    pub last_error: Option<GpsdError>,
}

impl GpsdClient {
    /// Connects to gpsd at `host:port` and starts the JSON watch.
    pub async fn connect(host: &str, port: u16) -> std::io::Result<Self> {
        let mut stream = TcpStream::connect((host, port)).await?;
        stream.write_all(WATCH.as_bytes()).await?;
        Ok(GpsdClient {
            lines: LineSource::Tcp(tokio::io::BufReader::new(stream)),
            events: 0,
            skipped: 0,
            refused: 0,
            last_error: None,
        })
    }

    /// The next fix or heading; `None` when gpsd closed the connection.
    pub async fn next(&mut self) -> std::io::Result<Option<GnssEvent>> {
        while let Some(line) = self.lines.next_line().await? {
            match decode_gpsd_report(&line, super::unix_now_s()) {
                Ok(Some(ev)) => {
                    self.events += 1;
                    return Ok(Some(ev));
                }
                Ok(None) => self.skipped += 1,
                Err(e) => {
                    self.refused += 1;
                    self.last_error = Some(e);
                }
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tpv_and_others() {
        let tpv = r#"{"class":"TPV","device":"/dev/pts/1","mode":3,"status":3,"time":"2024-05-01T12:00:01.500Z","lat":48.1173,"lon":11.5166,"altHAE":592.3,"alt":545.4,"epx":0.02,"epy":0.04,"epv":0.06}"#;
        let Ok(Some(GnssEvent::Fix(f))) = decode_gpsd_report(tpv, 0.0) else {
            panic!()
        };
        assert_eq!(f.status, FixStatus::Gbas);
        assert_eq!(f.alt_m, 592.3);
        assert_eq!(f.stamp_s, 1714564801.5);
        assert!((f.covariance_m2.unwrap()[4] - 0.0004).abs() < 1e-12);
        assert_eq!(f.gga_quality, Some(4));
        // RTK float says so, though a NavFix status cannot.
        let float = r#"{"class":"TPV","mode":3,"status":4,"lat":48.1,"lon":11.5,"altHAE":590.0}"#;
        let Ok(Some(GnssEvent::Fix(f))) = decode_gpsd_report(float, 0.0) else {
            panic!()
        };
        assert_eq!((f.status, f.gga_quality), (FixStatus::Gbas, Some(5)));
        let nofix = r#"{"class":"TPV","mode":1}"#;
        let Ok(Some(GnssEvent::Fix(f))) = decode_gpsd_report(nofix, 7.0) else {
            panic!()
        };
        assert_eq!((f.status, f.stamp_s), (FixStatus::NoFix, 7.0));
        assert_eq!(
            decode_gpsd_report(r#"{"class":"SKY","satellites":[]}"#, 0.0),
            Ok(None)
        );
        assert!(decode_gpsd_report("{not json", 0.0).is_err());
        assert!(decode_gpsd_report(r#"{"class":"TPV","mode":2,"lat":95,"lon":0}"#, 0.0).is_err());
        assert_eq!(parse_iso8601_utc("1970-01-01T00:00:00Z"), Some(0.0));
        assert_eq!(
            parse_iso8601_utc("2000-03-01T00:00:00.000Z"),
            Some(951868800.0)
        );
    }
}
