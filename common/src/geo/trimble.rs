//! Trimble proprietary sentences: `$PTNL,AVR` (attitude from a dual-antenna baseline) and
//! `$PTNL,GGK` (time, position, RTK quality and ellipsoidal height).
//!
//! ```text
//! $PTNL,AVR,hhmmss.ss,+yyy.yyyy,Yaw,+t.tttt,Tilt,+r.rrrr,Roll,rrr.rrr,q,p.p,nn*cs
//! $PTNL,GGK,hhmmss.ss,mmddyy,ddmm.mmmmmmmm,N,dddmm.mmmmmmmm,W,q,nn,d.d,EHThhh.hhh,M*cs
//! ```
//! AVR carries either tilt or roll (the other pair of fields is empty), depending on how the
//! antennas are mounted. Yaw is degrees clockwise from true north.

use super::nmea::{
    clip, field_count, format_angle, frame, opt_angle, opt_date, opt_f64, opt_f64_in, opt_time,
    opt_uint, NmeaError, Sentence, UtcDate, UtcTime,
};

/// `$PTNL,AVR`: yaw, tilt and roll of the antenna baseline.
#[derive(Clone, Debug, PartialEq)]
pub struct Avr {
    /// UTC time.
    pub time: Option<UtcTime>,
    /// Yaw (heading of the baseline), degrees clockwise from true north.
    pub yaw_deg: Option<f64>,
    /// Tilt (baseline pitch), degrees.
    pub tilt_deg: Option<f64>,
    /// Roll, degrees.
    pub roll_deg: Option<f64>,
    /// Baseline length between the antennas, metres.
    pub range_m: Option<f64>,
    /// Quality: 0 invalid, 1 autonomous, 2 differential, 3 RTK fixed, 4 RTK float.
    pub quality: u8,
    /// Position dilution of precision.
    pub pdop: Option<f64>,
    /// Satellites used.
    pub satellites: Option<u8>,
}

/// `$PTNL,GGK`: position with an ellipsoidal height (no geoid needed).
#[derive(Clone, Debug, PartialEq)]
pub struct Ggk {
    /// UTC time.
    pub time: Option<UtcTime>,
    /// UTC date.
    pub date: Option<UtcDate>,
    /// Latitude, degrees north.
    pub lat_deg: Option<f64>,
    /// Longitude, degrees east.
    pub lon_deg: Option<f64>,
    /// Trimble GGK quality 0-13: 0 invalid, 1 autonomous, 2 RTK float, 3 RTK fixed, 4 DGPS,
    /// 5 SBAS, 6..=13 network RTK / OmniSTAR / beacon variants.
    pub quality: u8,
    /// Satellites used.
    pub satellites: Option<u8>,
    /// Dilution of precision.
    pub dop: Option<f64>,
    /// Height above the WGS-84 ellipsoid, metres.
    pub alt_hae_m: Option<f64>,
}

/// Dispatches the fields after `PTNL` (first field = message type).
pub(crate) fn parse_ptnl(f: &[&str]) -> Result<Sentence, NmeaError> {
    match f.first().copied() {
        Some("AVR") => parse_avr(&f[1..]).map(Sentence::Avr),
        Some("GGK") => parse_ggk(&f[1..]).map(Sentence::Ggk),
        Some(other) => Err(NmeaError::Unsupported(format!("PTNL,{}", clip(other)))),
        None => Err(NmeaError::Truncated("PTNL without message type")),
    }
}

/// A value + label pair such as `+149.4688,Yaw`; both empty -> `None`.
fn labelled(
    field: &'static str,
    label: &str,
    value: &str,
    got_label: &str,
) -> Result<Option<f64>, NmeaError> {
    if got_label != label && !(got_label.is_empty() && value.is_empty()) {
        return Err(NmeaError::OutOfRange {
            sentence: "AVR",
            field,
            value: clip(got_label),
        });
    }
    opt_f64_in("AVR", field, value, -360.0, 360.0)
}

fn parse_avr(f: &[&str]) -> Result<Avr, NmeaError> {
    const S: &str = "AVR";
    field_count(S, f, 11, 11)?;
    Ok(Avr {
        time: opt_time(S, f[0])?,
        yaw_deg: labelled("yaw", "Yaw", f[1], f[2])?,
        tilt_deg: labelled("tilt", "Tilt", f[3], f[4])?,
        roll_deg: labelled("roll", "Roll", f[5], f[6])?,
        range_m: opt_f64_in(S, "range", f[7], 0.0, 1e6)?,
        quality: opt_uint(S, "quality", f[8], 4)?.unwrap_or(0) as u8,
        pdop: opt_f64_in(S, "pdop", f[9], 0.0, 1e4)?,
        satellites: opt_uint(S, "satellites", f[10], 255)?.map(|v| v as u8),
    })
}

fn parse_ggk(f: &[&str]) -> Result<Ggk, NmeaError> {
    const S: &str = "GGK";
    field_count(S, f, 11, 11)?;
    let height = f[9].strip_prefix("EHT").unwrap_or(f[9]);
    if !(f[10].is_empty() || f[10] == "M") {
        return Err(NmeaError::OutOfRange {
            sentence: S,
            field: "height unit",
            value: clip(f[10]),
        });
    }
    Ok(Ggk {
        time: opt_time(S, f[0])?,
        date: opt_date(S, f[1], false)?,
        lat_deg: opt_angle(S, "latitude", f[2], f[3], 90.0, "N", "S")?,
        lon_deg: opt_angle(S, "longitude", f[4], f[5], 180.0, "E", "W")?,
        quality: opt_uint(S, "quality", f[6], 13)?.unwrap_or(0) as u8,
        satellites: opt_uint(S, "satellites", f[7], 255)?.map(|v| v as u8),
        dop: opt_f64_in(S, "dop", f[8], 0.0, 1e4)?,
        alt_hae_m: opt_f64(S, "height", height)?,
    })
}

fn signed(v: Option<f64>, decimals: usize) -> String {
    v.filter(|x| x.is_finite())
        .map_or(String::new(), |x| format!("{x:+.decimals$}"))
}

fn plain(v: Option<f64>, decimals: usize) -> String {
    v.filter(|x| x.is_finite())
        .map_or(String::new(), |x| format!("{x:.decimals$}"))
}

/// Formats a `$PTNL,AVR` sentence (with checksum and CR LF). Angles get 4 decimals, the
/// baseline 3; an absent angle leaves both its value and its label empty, as receivers do.
pub fn format_avr(a: &Avr) -> String {
    let pair = |v: Option<f64>, label: &str| {
        let text = signed(v, 4);
        if text.is_empty() {
            ",".to_string()
        } else {
            format!("{text},{label}")
        }
    };
    let body = format!(
        "PTNL,AVR,{},{},{},{},{},{},{},{}",
        a.time.map_or(String::new(), |t| t.to_nmea()),
        pair(a.yaw_deg.map(|y| y.rem_euclid(360.0)), "Yaw"),
        pair(a.tilt_deg, "Tilt"),
        pair(a.roll_deg, "Roll"),
        plain(a.range_m, 3),
        a.quality.min(4),
        plain(a.pdop, 1),
        a.satellites.map_or(String::new(), |n| n.to_string()),
    );
    frame(&body)
}

/// Formats a `$PTNL,GGK` sentence (8 decimals of minutes, `EHT` height with 3 decimals).
pub fn format_ggk(g: &Ggk) -> String {
    let (lat, ns) =
        g.lat_deg
            .filter(|v| v.is_finite())
            .map_or((String::new(), String::new()), |v| {
                let (t, h) = format_angle(v, 2, 8, 'N', 'S');
                (t, h.to_string())
            });
    let (lon, ew) =
        g.lon_deg
            .filter(|v| v.is_finite())
            .map_or((String::new(), String::new()), |v| {
                let (t, h) = format_angle(v, 3, 8, 'E', 'W');
                (t, h.to_string())
            });
    let body = format!(
        "PTNL,GGK,{},{},{lat},{ns},{lon},{ew},{},{},{},{},M",
        g.time.map_or(String::new(), |t| t.to_nmea()),
        g.date.map_or(String::new(), |d| format!(
            "{:02}{:02}{:02}",
            d.month,
            d.day,
            d.year % 100
        )),
        g.quality.min(13),
        g.satellites.map_or(String::new(), |n| format!("{n:02}")),
        plain(g.dop, 1),
        g.alt_hae_m
            .filter(|v| v.is_finite())
            .map_or(String::new(), |h| format!("EHT{h:.3}")),
    );
    frame(&body)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::nmea::parse_sentence;

    #[test]
    fn published_avr_examples_decode() {
        let Ok(Sentence::Avr(a)) =
            parse_sentence("$PTNL,AVR,212604.30,+52.1800,Yaw,,,-0.0807,Roll,12.579,3,1.4,16*21")
        else {
            panic!("not an AVR");
        };
        assert_eq!(a.yaw_deg, Some(52.18));
        assert_eq!(a.tilt_deg, None);
        assert_eq!(a.roll_deg, Some(-0.0807));
        assert_eq!(
            (a.range_m, a.quality, a.pdop, a.satellites),
            (Some(12.579), 3, Some(1.4), Some(16))
        );
    }

    #[test]
    fn published_ggk_example_decodes() {
        let line =
            "$PTNL,GGK,102939.00,051910,5000.97323841,N,00827.62010742,E,5,09,1.9,EHT150.790,M*73";
        let Ok(Sentence::Ggk(g)) = parse_sentence(line) else {
            panic!("not a GGK");
        };
        assert_eq!(g.date.map(|d| d.to_string()).as_deref(), Some("2010-05-19"));
        assert_eq!(g.lat_deg, Some(50.0 + 0.973_238_41 / 60.0));
        assert_eq!(g.lon_deg, Some(8.0 + 27.620_107_42 / 60.0));
        assert_eq!(
            (g.quality, g.satellites, g.alt_hae_m),
            (5, Some(9), Some(150.79))
        );
        let again = format_ggk(&g);
        assert_eq!(
            again.trim_end(),
            line,
            "formatting reproduces the receiver's sentence"
        );
    }

    #[test]
    fn avr_round_trips_and_rejects_wrong_labels() {
        let a = Avr {
            time: Some(UtcTime::from_seconds_of_day(65_459.6)),
            yaw_deg: Some(149.4688),
            tilt_deg: Some(0.0134),
            roll_deg: None,
            range_m: Some(60.191),
            quality: 3,
            pdop: Some(2.5),
            satellites: Some(6),
        };
        let text = format_avr(&a);
        assert!(
            text.starts_with("$PTNL,AVR,181059.60,+149.4688,Yaw,+0.0134,Tilt,,,60.191,3,2.5,6*")
        );
        assert_eq!(parse_sentence(&text), Ok(Sentence::Avr(a)));
        let wrong = frame("PTNL,AVR,181059.6,+149.4688,Pitch,+0.0134,Tilt,,,60.191,3,2.5,6");
        assert!(matches!(
            parse_sentence(&wrong),
            Err(NmeaError::OutOfRange { field: "yaw", .. })
        ));
        assert!(matches!(
            parse_sentence(&frame("PTNL,XYZ,1")),
            Err(NmeaError::Unsupported(_))
        ));
        assert!(matches!(
            parse_sentence(&frame("PTNL")),
            Err(NmeaError::Truncated(_))
        ));
    }
}
