//! NMEA-0183: framing, checksum, the standard sentences terranav uses, and their formatting.
//!
//! A sentence is `$`, an address (`GPGGA`, or `P` + maker for proprietary ones such as `PTNL`),
//! comma-separated fields, `*`, two hex digits of the XOR of every byte between `$` and `*`, CR LF.
//! [`parse_sentence`] checks all of that and decodes `GGA`, `RMC`, `HDT`, Trimble `$PTNL,AVR` and
//! `$PTNL,GGK` (see [`crate::geo::trimble`]) and `ZDA`; `VTG`, `GSA`, `GSV`, `GLL`, `GST`, `GNS`
//! and `TXT` are recognised and returned as [`Sentence::Other`]; anything else is
//! [`NmeaError::Unsupported`]. Bad input always gives a typed [`NmeaError`], never a panic.
//!
//! Why not the `nmea` crate: it keeps GGA altitude, geoid separation and HDOP as `f32` (1864.182 m
//! comes back as 1864.1820068..., and at 20 km the `f32` step is 2 mm, so the 1 mm agreement
//! with gpsd cannot be promised), it does not reject minutes >= 60 or latitudes above 90, it
//! has no Trimble sentences, and it pulls in `nom` and `chrono`. Positions here are parsed
//! straight from the decimal text into `f64` (`deg + minutes / 60`), so 8-decimal-minute RTK
//! output keeps its full 1e-10 deg resolution.

use std::fmt;

use super::attitude::{self, Pashr, Ths};
use super::trimble;

/// Why a line is not a usable NMEA sentence.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum NmeaError {
    /// Nothing but whitespace.
    #[error("empty line")]
    Empty,
    /// The line does not start with `$`.
    #[error("not an NMEA sentence (no leading '$')")]
    NoStart,
    /// A byte outside printable ASCII inside the sentence.
    #[error("non-printable or non-ASCII character in sentence")]
    InvalidCharacter,
    /// No `*hh` checksum (every sentence terranav accepts must carry one).
    #[error("missing checksum ('*hh')")]
    MissingChecksum,
    /// The sentence ends before a required part (address, checksum digits).
    #[error("truncated sentence: {0}")]
    Truncated(&'static str),
    /// The checksum field is not exactly two hex digits.
    #[error("malformed checksum field {0:?}")]
    MalformedChecksum(String),
    /// The stated checksum differs from the XOR of the sentence.
    #[error("bad checksum: sentence says {stated:02X}, computed {computed:02X}")]
    BadChecksum {
        /// Checksum written in the sentence.
        stated: u8,
        /// Checksum computed over the sentence body.
        computed: u8,
    },
    /// The sentence has too few or too many fields.
    #[error("{sentence}: expected {min}..={max} fields, found {found}")]
    FieldCount {
        /// Sentence type, e.g. `GGA`.
        sentence: &'static str,
        /// Fewest fields accepted.
        min: usize,
        /// Most fields accepted.
        max: usize,
        /// Fields found.
        found: usize,
    },
    /// A numeric field does not hold a (finite, plain decimal) number.
    #[error("{sentence} {field}: bad number {value:?}")]
    BadNumber {
        /// Sentence type.
        sentence: &'static str,
        /// Field name.
        field: &'static str,
        /// The offending text (shortened).
        value: String,
    },
    /// A field holds a number or flag outside its allowed range (lat > 90, minutes >= 60,
    /// GGA quality > 8, hemisphere not N/S, ...).
    #[error("{sentence} {field}: value {value:?} out of range")]
    OutOfRange {
        /// Sentence type.
        sentence: &'static str,
        /// Field name.
        field: &'static str,
        /// The offending text (shortened).
        value: String,
    },
    /// A well-formed sentence of a type this module does not decode.
    #[error("unsupported sentence {0:?}")]
    Unsupported(String),
}

/// Shortens untrusted text kept in an error so that a huge garbage line cannot make a huge error.
pub(crate) fn clip(s: &str) -> String {
    s.chars().take(24).collect()
}

/// UTC time of day as sent by a receiver (`hhmmss.ss`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcTime {
    /// Hour, 0-23.
    pub hour: u8,
    /// Minute, 0-59.
    pub minute: u8,
    /// Second, 0-60 (60 only in a leap second).
    pub second: u8,
    /// Fraction of the second, nanoseconds.
    pub nanos: u32,
}

impl UtcTime {
    /// Seconds since midnight UTC.
    pub fn seconds_of_day(&self) -> f64 {
        f64::from(self.hour) * 3600.0
            + f64::from(self.minute) * 60.0
            + f64::from(self.second)
            + f64::from(self.nanos) * 1e-9
    }

    /// The time of day `t_s` seconds after some midnight (wrapped into one day, rounded to the
    /// nanosecond). Handy for simulated receivers counting seconds since start.
    pub fn from_seconds_of_day(t_s: f64) -> Self {
        let t = if t_s.is_finite() {
            t_s.rem_euclid(86_400.0)
        } else {
            0.0
        };
        let total_ns = (t * 1e9).round() as u64 % 86_400_000_000_000;
        let secs = total_ns / 1_000_000_000;
        Self {
            hour: (secs / 3600) as u8,
            minute: (secs / 60 % 60) as u8,
            second: (secs % 60) as u8,
            nanos: (total_ns % 1_000_000_000) as u32,
        }
    }

    /// `hhmmss.ss`, the NMEA form (fraction truncated to centiseconds).
    pub fn to_nmea(&self) -> String {
        format!(
            "{:02}{:02}{:02}.{:02}",
            self.hour,
            self.minute,
            self.second,
            self.nanos / 10_000_000
        )
    }
}

impl fmt::Display for UtcTime {
    /// `hh:mm:ss.sss` (ISO 8601 time of day, milliseconds).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:02}:{:02}:{:02}.{:03}",
            self.hour,
            self.minute,
            self.second,
            self.nanos / 1_000_000
        )
    }
}

/// A calendar date (UTC) as carried by RMC (`ddmmyy`) or GGK (`mmddyy`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcDate {
    /// Full year (two-digit years are mapped to 1980..=2079).
    pub year: u16,
    /// Month, 1-12.
    pub month: u8,
    /// Day of month, 1-31.
    pub day: u8,
}

impl fmt::Display for UtcDate {
    /// `yyyy-mm-dd`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

/// GGA: time, position, fix quality, satellites, HDOP and heights of one fix.
#[derive(Clone, Debug, PartialEq)]
pub struct Gga {
    /// Talker id, e.g. `GP`, `GN`.
    pub talker: String,
    /// UTC time of the fix.
    pub time: Option<UtcTime>,
    /// Latitude, degrees north.
    pub lat_deg: Option<f64>,
    /// Longitude, degrees east.
    pub lon_deg: Option<f64>,
    /// Fix quality 0-8: 0 invalid, 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float,
    /// 6 dead reckoning, 7 manual, 8 simulator.
    pub quality: u8,
    /// Satellites used.
    pub satellites: Option<u8>,
    /// Horizontal dilution of precision.
    pub hdop: Option<f64>,
    /// Orthometric height (above mean sea level / the geoid), metres.
    pub alt_msl_m: Option<f64>,
    /// Geoid separation (geoid above the WGS-84 ellipsoid), metres.
    pub geoid_sep_m: Option<f64>,
    /// Age of the differential corrections, seconds.
    pub dgps_age_s: Option<f64>,
    /// Differential reference station id.
    pub dgps_station: Option<u16>,
}

/// GGA quality 0: no fix.
pub const QUALITY_INVALID: u8 = 0;
/// GGA quality 1: autonomous GNSS fix.
pub const QUALITY_GPS: u8 = 1;
/// GGA quality 2: differential fix.
pub const QUALITY_DGPS: u8 = 2;
/// GGA quality 4: RTK with fixed integer ambiguities (cm level).
pub const QUALITY_RTK_FIXED: u8 = 4;
/// GGA quality 5: RTK float (dm level).
pub const QUALITY_RTK_FLOAT: u8 = 5;

impl Gga {
    /// Height above the WGS-84 ellipsoid, `alt_msl + geoid_sep` (what [`crate::geo::wgs84`] needs).
    pub fn alt_hae_m(&self) -> Option<f64> {
        Some(self.alt_msl_m? + self.geoid_sep_m?)
    }

    /// Whether the fix carries a usable position: quality 1..=5, lat/lon present, and not
    /// "0 satellites used" (receivers such as the Hemisphere in hemi.log claim quality 1 with 0
    /// satellites while starting up; gpsd reports those as no fix too).
    pub fn has_fix(&self) -> bool {
        (1..=5).contains(&self.quality)
            && self.satellites != Some(0)
            && self.lat_deg.is_some()
            && self.lon_deg.is_some()
    }
}

/// RMC: recommended minimum data (time, date, validity, position, speed, track).
#[derive(Clone, Debug, PartialEq)]
pub struct Rmc {
    /// Talker id.
    pub talker: String,
    /// UTC time of the fix.
    pub time: Option<UtcTime>,
    /// Status `A` (valid) or `V` (warning).
    pub valid: bool,
    /// Latitude, degrees north.
    pub lat_deg: Option<f64>,
    /// Longitude, degrees east.
    pub lon_deg: Option<f64>,
    /// Speed over ground, m/s (sent in knots).
    pub speed_mps: Option<f64>,
    /// Track made good, degrees true.
    pub track_deg: Option<f64>,
    /// UTC date.
    pub date: Option<UtcDate>,
    /// Magnetic variation, degrees, east positive.
    pub magvar_deg: Option<f64>,
    /// FAA mode indicator (NMEA 2.3+), e.g. `A`, `D`, `R`, `F`.
    pub mode: Option<char>,
}

/// HDT: true heading (e.g. of a dual-antenna receiver's baseline).
#[derive(Clone, Debug, PartialEq)]
pub struct Hdt {
    /// Talker id.
    pub talker: String,
    /// Heading, degrees clockwise from true north (absent while the receiver has none).
    pub heading_deg: Option<f64>,
}

/// ZDA: UTC time and date (what gpsd takes the date from when there is no RMC).
#[derive(Clone, Debug, PartialEq)]
pub struct Zda {
    /// Talker id.
    pub talker: String,
    /// UTC time.
    pub time: Option<UtcTime>,
    /// UTC date.
    pub date: Option<UtcDate>,
}

/// One decoded sentence.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Sentence {
    /// `--GGA`.
    Gga(Gga),
    /// `--RMC`.
    Rmc(Rmc),
    /// `--HDT`.
    Hdt(Hdt),
    /// `--THS`: true heading with a mode flag.
    Ths(Ths),
    /// `$PASHR`: attitude (heading, roll, pitch) of a GNSS/INS unit.
    Pashr(Pashr),
    /// `--ZDA`.
    Zda(Zda),
    /// `$PTNL,AVR`.
    Avr(trimble::Avr),
    /// `$PTNL,GGK`.
    Ggk(trimble::Ggk),
    /// A valid, checksummed sentence of a known type terranav ignores (`VTG`, `ZDA`, ...).
    Other {
        /// Talker id (`GP`) or proprietary maker (`PTNL`).
        talker: String,
        /// Sentence type (`VTG`).
        kind: String,
    },
}

impl Sentence {
    /// Short type name: `GGA`, `RMC`, `HDT`, `AVR`, `GGK`, or the ignored type's name.
    pub fn kind(&self) -> &str {
        match self {
            Sentence::Gga(_) => "GGA",
            Sentence::Rmc(_) => "RMC",
            Sentence::Hdt(_) => "HDT",
            Sentence::Ths(_) => "THS",
            Sentence::Pashr(_) => "PASHR",
            Sentence::Zda(_) => "ZDA",
            Sentence::Avr(_) => "AVR",
            Sentence::Ggk(_) => "GGK",
            Sentence::Other { kind, .. } => kind,
        }
    }

    /// UTC time carried by the sentence, if any.
    pub fn time(&self) -> Option<UtcTime> {
        match self {
            Sentence::Gga(s) => s.time,
            Sentence::Rmc(s) => s.time,
            Sentence::Zda(s) => s.time,
            Sentence::Avr(s) => s.time,
            Sentence::Ggk(s) => s.time,
            Sentence::Pashr(s) => s.time,
            Sentence::Hdt(_) | Sentence::Ths(_) | Sentence::Other { .. } => None,
        }
    }
}

/// Types that are valid NMEA but carry nothing terranav uses.
const IGNORED: [&str; 7] = ["VTG", "GSA", "GSV", "GLL", "GST", "GNS", "TXT"];

/// XOR of all bytes (the NMEA checksum of the text between `$` and `*`).
pub fn checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |acc, b| acc ^ b)
}

/// `$` + `body` + `*` + checksum + CR LF: a complete sentence ready to send.
pub fn frame(body: &str) -> String {
    format!("${body}*{:02X}\r\n", checksum(body.as_bytes()))
}

/// A checksum-verified sentence split into its address and fields.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The address field: `GPGGA`, `PTNL`, `NALST`.
    pub address: &'a str,
    /// The fields after the address (never the checksum).
    pub fields: Vec<&'a str>,
}

/// Checks framing and checksum of one line (trailing CR/LF/whitespace allowed) and splits it.
pub fn split_frame(line: &str) -> Result<Frame<'_>, NmeaError> {
    let line = line.trim_end_matches(['\r', '\n', ' ', '\t']);
    let line = line.trim_start_matches([' ', '\t']);
    if line.is_empty() {
        return Err(NmeaError::Empty);
    }
    if !line.bytes().all(|b| (0x20..0x7f).contains(&b)) {
        return Err(NmeaError::InvalidCharacter);
    }
    // All ASCII from here on: byte indices are char boundaries, slicing cannot panic.
    let rest = line.strip_prefix('$').ok_or(NmeaError::NoStart)?;
    let (body, cs) = rest.rsplit_once('*').ok_or(NmeaError::MissingChecksum)?;
    if cs.len() < 2 {
        return Err(NmeaError::Truncated("checksum needs two hex digits"));
    }
    if cs.len() > 2 || !cs.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(NmeaError::MalformedChecksum(clip(cs)));
    }
    let stated = u8::from_str_radix(cs, 16).map_err(|_| NmeaError::MalformedChecksum(clip(cs)))?;
    let computed = checksum(body.as_bytes());
    if stated != computed {
        return Err(NmeaError::BadChecksum { stated, computed });
    }
    if body.contains(['$', '*']) {
        return Err(NmeaError::InvalidCharacter);
    }
    let mut parts = body.split(',');
    let address = parts.next().unwrap_or("");
    if address.is_empty() {
        return Err(NmeaError::Truncated("no address field"));
    }
    if !address.bytes().all(|b| b.is_ascii_alphanumeric()) {
        return Err(NmeaError::Unsupported(clip(address)));
    }
    Ok(Frame {
        address,
        fields: parts.collect(),
    })
}

/// Parses one line holding one sentence (trailing CR LF optional).
pub fn parse_sentence(line: &str) -> Result<Sentence, NmeaError> {
    let frame = split_frame(line)?;
    if frame.address == "PTNL" {
        return trimble::parse_ptnl(&frame.fields);
    }
    if frame.address == "PASHR" {
        return attitude::parse_pashr(&frame.fields).map(Sentence::Pashr);
    }
    if frame.address.len() != 5 || frame.address.starts_with('P') {
        return Err(NmeaError::Unsupported(clip(frame.address)));
    }
    let (talker, kind) = frame.address.split_at(2);
    let f = &frame.fields;
    match kind {
        "GGA" => parse_gga(talker, f).map(Sentence::Gga),
        "RMC" => parse_rmc(talker, f).map(Sentence::Rmc),
        "HDT" => parse_hdt(talker, f).map(Sentence::Hdt),
        "THS" => attitude::parse_ths(talker, f).map(Sentence::Ths),
        "ZDA" => parse_zda(talker, f).map(Sentence::Zda),
        k if IGNORED.contains(&k) => Ok(Sentence::Other {
            talker: talker.to_string(),
            kind: k.to_string(),
        }),
        _ => Err(NmeaError::Unsupported(clip(frame.address))),
    }
}

// ---------------------------------------------------------------------------------------------
// Field helpers, shared with trimble.rs and orpheus.rs.

pub(crate) fn field_count(
    sentence: &'static str,
    f: &[&str],
    min: usize,
    max: usize,
) -> Result<(), NmeaError> {
    if f.len() < min || f.len() > max {
        return Err(NmeaError::FieldCount {
            sentence,
            min,
            max,
            found: f.len(),
        });
    }
    Ok(())
}

/// A plain decimal number: optional sign, digits, optional point and digits. No exponent,
/// no `inf`/`nan` (which `f64::from_str` would accept).
pub(crate) fn is_plain_decimal(s: &str) -> bool {
    let digits = s.strip_prefix(['+', '-']).unwrap_or(s);
    let mut seen_digit = false;
    let mut seen_point = false;
    for b in digits.bytes() {
        match b {
            b'0'..=b'9' => seen_digit = true,
            b'.' if !seen_point => seen_point = true,
            _ => return false,
        }
    }
    seen_digit
}

/// An optional decimal field: empty -> `None`.
pub(crate) fn opt_f64(
    sentence: &'static str,
    field: &'static str,
    s: &str,
) -> Result<Option<f64>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    let bad = || NmeaError::BadNumber {
        sentence,
        field,
        value: clip(s),
    };
    if !is_plain_decimal(s) {
        return Err(bad());
    }
    let v: f64 = s.parse().map_err(|_| bad())?;
    if !v.is_finite() {
        return Err(bad());
    }
    Ok(Some(v))
}

/// An optional decimal field that must lie in `[lo, hi]`.
pub(crate) fn opt_f64_in(
    sentence: &'static str,
    field: &'static str,
    s: &str,
    lo: f64,
    hi: f64,
) -> Result<Option<f64>, NmeaError> {
    let v = opt_f64(sentence, field, s)?;
    if let Some(x) = v {
        if !(lo..=hi).contains(&x) {
            return Err(NmeaError::OutOfRange {
                sentence,
                field,
                value: clip(s),
            });
        }
    }
    Ok(v)
}

/// An optional unsigned integer field (digits only) no larger than `max`.
pub(crate) fn opt_uint(
    sentence: &'static str,
    field: &'static str,
    s: &str,
    max: u64,
) -> Result<Option<u64>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    if s.len() > 18 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(NmeaError::BadNumber {
            sentence,
            field,
            value: clip(s),
        });
    }
    let v: u64 = s.parse().map_err(|_| NmeaError::BadNumber {
        sentence,
        field,
        value: clip(s),
    })?;
    if v > max {
        return Err(NmeaError::OutOfRange {
            sentence,
            field,
            value: clip(s),
        });
    }
    Ok(Some(v))
}

/// `hhmmss[.sss]` -> time; empty -> `None`.
pub(crate) fn opt_time(sentence: &'static str, s: &str) -> Result<Option<UtcTime>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    let bad = || NmeaError::BadNumber {
        sentence,
        field: "time",
        value: clip(s),
    };
    let (whole, frac) = s.split_once('.').unwrap_or((s, ""));
    if whole.len() != 6
        || !whole.bytes().all(|b| b.is_ascii_digit())
        || !frac.bytes().all(|b| b.is_ascii_digit())
    {
        return Err(bad());
    }
    let num = |r: std::ops::Range<usize>| whole[r].parse::<u8>().map_err(|_| bad());
    let (hour, minute, second) = (num(0..2)?, num(2..4)?, num(4..6)?);
    if hour > 23 || minute > 59 || second > 60 {
        return Err(NmeaError::OutOfRange {
            sentence,
            field: "time",
            value: clip(s),
        });
    }
    // Fraction digits to nanoseconds exactly (digits past the ninth are dropped).
    let mut nanos: u32 = 0;
    for i in 0..9 {
        let digit = frac.as_bytes().get(i).map_or(0, |b| u32::from(b - b'0'));
        nanos = nanos * 10 + digit;
    }
    Ok(Some(UtcTime {
        hour,
        minute,
        second,
        nanos,
    }))
}

/// Two-digit year -> full year (NMEA dates carry no century; GNSS receivers date from 1980).
fn full_year(yy: u8) -> u16 {
    if yy >= 80 {
        1900 + u16::from(yy)
    } else {
        2000 + u16::from(yy)
    }
}

/// Six-digit date; `day_first` for RMC's `ddmmyy`, else GGK's `mmddyy`.
pub(crate) fn opt_date(
    sentence: &'static str,
    s: &str,
    day_first: bool,
) -> Result<Option<UtcDate>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    if s.len() != 6 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return Err(NmeaError::BadNumber {
            sentence,
            field: "date",
            value: clip(s),
        });
    }
    let b = s.as_bytes();
    let two = |i: usize| (b[i] - b'0') * 10 + (b[i + 1] - b'0');
    let (a, c, yy) = (two(0), two(2), two(4));
    let (day, month) = if day_first { (a, c) } else { (c, a) };
    if !(1..=12).contains(&month) || !(1..=31).contains(&day) {
        return Err(NmeaError::OutOfRange {
            sentence,
            field: "date",
            value: clip(s),
        });
    }
    Ok(Some(UtcDate {
        year: full_year(yy),
        month,
        day,
    }))
}

/// `ddmm.mmmm` / `dddmm.mmmm` + hemisphere -> signed degrees; both empty -> `None`.
///
/// `max_deg` is 90 for latitude, 180 for longitude; `pos`/`neg` the hemisphere letters.
pub(crate) fn opt_angle(
    sentence: &'static str,
    field: &'static str,
    value: &str,
    hemi: &str,
    max_deg: f64,
    pos: &str,
    neg: &str,
) -> Result<Option<f64>, NmeaError> {
    if value.is_empty() && hemi.is_empty() {
        return Ok(None);
    }
    let bad = || NmeaError::BadNumber {
        sentence,
        field,
        value: clip(value),
    };
    let range = |v: &str| NmeaError::OutOfRange {
        sentence,
        field,
        value: clip(v),
    };
    let (int, frac) = value.split_once('.').unwrap_or((value, ""));
    if int.len() < 3
        || int.len() > 5
        || !int.bytes().all(|b| b.is_ascii_digit())
        || !frac.bytes().all(|b| b.is_ascii_digit())
    {
        return Err(bad());
    }
    let deg_digits = int.len() - 2;
    let deg: f64 = int[..deg_digits].parse().map_err(|_| bad())?;
    let minutes: f64 = value[deg_digits..].parse().map_err(|_| bad())?;
    if minutes >= 60.0 {
        return Err(range(value));
    }
    let abs = deg + minutes / 60.0;
    if abs > max_deg {
        return Err(range(value));
    }
    let sign = if hemi == pos {
        1.0
    } else if hemi == neg {
        -1.0
    } else {
        return Err(range(hemi));
    };
    Ok(Some(sign * abs))
}

/// Signed degrees -> (`ddmm.mmmm...`, hemisphere) with `decimals` decimals of minutes,
/// rounded once in integer units so that 59.9999999995' carries into the degrees.
pub(crate) fn format_angle(
    deg: f64,
    deg_digits: usize,
    decimals: u32,
    pos: char,
    neg: char,
) -> (String, char) {
    let hemi = if deg < 0.0 { neg } else { pos };
    let scale = 10u64.pow(decimals);
    let units = (deg.abs() * 60.0 * scale as f64).round() as u64;
    let d = units / (60 * scale);
    let rem = units % (60 * scale);
    let text = format!(
        "{d:0dw$}{:02}.{:0fw$}",
        rem / scale,
        rem % scale,
        dw = deg_digits,
        fw = decimals as usize
    );
    (text, hemi)
}

fn unit_field(sentence: &'static str, field: &'static str, s: &str) -> Result<(), NmeaError> {
    if s.is_empty() || s == "M" {
        Ok(())
    } else {
        Err(NmeaError::OutOfRange {
            sentence,
            field,
            value: clip(s),
        })
    }
}

fn opt_fmt(v: Option<f64>, decimals: usize) -> String {
    v.filter(|x| x.is_finite())
        .map_or(String::new(), |x| format!("{x:.decimals$}"))
}

// ---------------------------------------------------------------------------------------------
// GGA

fn parse_gga(talker: &str, f: &[&str]) -> Result<Gga, NmeaError> {
    const S: &str = "GGA";
    // Receivers in the field end GGA early (no geoid separation, no differential age or
    // station); gpsd reads such sentences, so missing trailing fields are read as empty.
    field_count(S, f, 9, 14)?;
    let f: Vec<&str> = (0..14).map(|i| f.get(i).copied().unwrap_or("")).collect();
    unit_field(S, "altitude unit", f[9])?;
    unit_field(S, "geoid separation unit", f[11])?;
    Ok(Gga {
        talker: talker.to_string(),
        time: opt_time(S, f[0])?,
        lat_deg: opt_angle(S, "latitude", f[1], f[2], 90.0, "N", "S")?,
        lon_deg: opt_angle(S, "longitude", f[3], f[4], 180.0, "E", "W")?,
        // An empty quality field is read as 0 (no fix): some receivers send it so while starting.
        quality: opt_uint(S, "quality", f[5], 8)?.unwrap_or(0) as u8,
        satellites: opt_uint(S, "satellites", f[6], 255)?.map(|v| v as u8),
        hdop: opt_f64_in(S, "hdop", f[7], 0.0, 1e4)?,
        alt_msl_m: opt_f64(S, "altitude", f[8])?,
        geoid_sep_m: opt_f64(S, "geoid separation", f[10])?,
        dgps_age_s: opt_f64_in(S, "dgps age", f[12], 0.0, 1e9)?,
        dgps_station: opt_uint(S, "dgps station", f[13], 65535)?.map(|v| v as u16),
    })
}

/// Formats a GGA sentence (with `$`, checksum and CR LF). Latitude/longitude get 8 decimals of
/// minutes (2e-10 deg, as RTK receivers send), heights 3 decimals (1 mm), HDOP 1 decimal.
/// Absent values become empty fields; a talker that is not two characters becomes `GP`.
pub fn format_gga(g: &Gga) -> String {
    let talker = if g.talker.len() == 2 { &g.talker } else { "GP" };
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
        "{talker}GGA,{},{lat},{ns},{lon},{ew},{},{},{},{},M,{},M,{},{}",
        g.time.map_or(String::new(), |t| t.to_nmea()),
        g.quality.min(8),
        g.satellites.map_or(String::new(), |n| format!("{n:02}")),
        opt_fmt(g.hdop, 1),
        opt_fmt(g.alt_msl_m, 3),
        opt_fmt(g.geoid_sep_m, 3),
        opt_fmt(g.dgps_age_s, 1),
        g.dgps_station.map_or(String::new(), |n| format!("{n:04}")),
    );
    frame(&body)
}

// ---------------------------------------------------------------------------------------------
// RMC

/// Knots -> m/s.
const KNOT_MPS: f64 = 1852.0 / 3600.0;

fn parse_rmc(talker: &str, f: &[&str]) -> Result<Rmc, NmeaError> {
    const S: &str = "RMC";
    // 11 fields (NMEA 2.0), 12 with the FAA mode (2.3), 13 with the navigational status (4.1).
    field_count(S, f, 11, 13)?;
    let valid = match f[1] {
        "A" => true,
        "V" | "" => false,
        other => {
            return Err(NmeaError::OutOfRange {
                sentence: S,
                field: "status",
                value: clip(other),
            })
        }
    };
    let magvar = opt_f64_in(S, "magnetic variation", f[9], 0.0, 1000.0)?;
    let magvar_deg = match (magvar, f[10]) {
        (None, _) => None,
        (Some(v), "E") => Some(v),
        (Some(v), "W") => Some(-v),
        (Some(_), other) => {
            return Err(NmeaError::OutOfRange {
                sentence: S,
                field: "magnetic variation direction",
                value: clip(other),
            })
        }
    };
    let mode = match f.get(11).copied().unwrap_or("") {
        "" => None,
        m if m.len() == 1 => m.chars().next(),
        m => {
            return Err(NmeaError::OutOfRange {
                sentence: S,
                field: "mode",
                value: clip(m),
            })
        }
    };
    Ok(Rmc {
        talker: talker.to_string(),
        time: opt_time(S, f[0])?,
        valid,
        lat_deg: opt_angle(S, "latitude", f[2], f[3], 90.0, "N", "S")?,
        lon_deg: opt_angle(S, "longitude", f[4], f[5], 180.0, "E", "W")?,
        speed_mps: opt_f64_in(S, "speed", f[6], 0.0, 1e6)?.map(|kn| kn * KNOT_MPS),
        track_deg: opt_f64_in(S, "track", f[7], 0.0, 360.0)?,
        date: opt_date(S, f[8], true)?,
        magvar_deg,
        mode,
    })
}

/// Formats an RMC sentence (NMEA 2.3 form with the mode field; 8 decimals of minutes).
pub fn format_rmc(r: &Rmc) -> String {
    let talker = if r.talker.len() == 2 { &r.talker } else { "GP" };
    let (lat, ns) =
        r.lat_deg
            .filter(|v| v.is_finite())
            .map_or((String::new(), String::new()), |v| {
                let (t, h) = format_angle(v, 2, 8, 'N', 'S');
                (t, h.to_string())
            });
    let (lon, ew) =
        r.lon_deg
            .filter(|v| v.is_finite())
            .map_or((String::new(), String::new()), |v| {
                let (t, h) = format_angle(v, 3, 8, 'E', 'W');
                (t, h.to_string())
            });
    let (magvar, magdir) = match r.magvar_deg.filter(|v| v.is_finite()) {
        Some(v) => (format!("{:.1}", v.abs()), if v < 0.0 { "W" } else { "E" }),
        None => (String::new(), ""),
    };
    let body = format!(
        "{talker}RMC,{},{},{lat},{ns},{lon},{ew},{},{},{},{magvar},{magdir},{}",
        r.time.map_or(String::new(), |t| t.to_nmea()),
        if r.valid { 'A' } else { 'V' },
        opt_fmt(r.speed_mps.map(|v| v / KNOT_MPS), 3),
        opt_fmt(r.track_deg, 3),
        r.date.map_or(String::new(), |d| format!(
            "{:02}{:02}{:02}",
            d.day,
            d.month,
            d.year % 100
        )),
        r.mode
            .filter(|c| c.is_ascii_alphabetic())
            .map_or(String::new(), String::from),
    );
    frame(&body)
}

// ---------------------------------------------------------------------------------------------
// HDT

fn parse_hdt(talker: &str, f: &[&str]) -> Result<Hdt, NmeaError> {
    const S: &str = "HDT";
    field_count(S, f, 2, 2)?;
    if !(f[1].is_empty() || f[1] == "T") {
        return Err(NmeaError::OutOfRange {
            sentence: S,
            field: "reference",
            value: clip(f[1]),
        });
    }
    Ok(Hdt {
        talker: talker.to_string(),
        heading_deg: opt_f64_in(S, "heading", f[0], 0.0, 360.0)?,
    })
}

/// Formats an HDT sentence (heading with 3 decimals; `None` -> empty field).
pub fn format_hdt(talker: &str, heading_deg: Option<f64>) -> String {
    let talker = if talker.len() == 2 { talker } else { "GP" };
    let heading = heading_deg
        .filter(|v| v.is_finite())
        .map(|v| v.rem_euclid(360.0));
    frame(&format!("{talker}HDT,{},T", opt_fmt(heading, 3)))
}

// ---------------------------------------------------------------------------------------------
// ZDA

fn parse_zda(talker: &str, f: &[&str]) -> Result<Zda, NmeaError> {
    const S: &str = "ZDA";
    field_count(S, f, 6, 6)?;
    let day = opt_uint(S, "day", f[1], 31)?;
    let month = opt_uint(S, "month", f[2], 12)?;
    let year = opt_uint(S, "year", f[3], 9999)?;
    // Local zone fields are checked but not kept: terranav works in UTC.
    opt_f64_in(S, "zone hours", f[4], -13.0, 13.0)?;
    opt_uint(S, "zone minutes", f[5], 59)?;
    let date = match (day, month, year) {
        (Some(d @ 1..), Some(m @ 1..), Some(y)) => Some(UtcDate {
            year: y as u16,
            month: m as u8,
            day: d as u8,
        }),
        (None, None, None) => None,
        _ => {
            return Err(NmeaError::OutOfRange {
                sentence: S,
                field: "date",
                value: clip(&format!("{},{},{}", f[1], f[2], f[3])),
            })
        }
    };
    Ok(Zda {
        talker: talker.to_string(),
        time: opt_time(S, f[0])?,
        date,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zda_gives_time_and_date() {
        let Ok(Sentence::Zda(z)) = parse_sentence("$GPZDA,193913.00,07,09,2018,00,00*63") else {
            panic!("not a ZDA");
        };
        assert_eq!(
            z.time.map(|t| t.to_string()).as_deref(),
            Some("19:39:13.000")
        );
        assert_eq!(z.date.map(|d| d.to_string()).as_deref(), Some("2018-09-07"));
        assert!(matches!(
            parse_sentence(&frame("GPZDA,193913.00,00,09,2018,00,00")),
            Err(NmeaError::OutOfRange { .. })
        ));
    }

    const GGA_RTK: &str =
        "$GNGGA,132819.60,4134.49795459,N,09345.03431408,W,2,10,0.9,278.161,M,-31.442,M,6.6,0133*6A";

    #[test]
    fn gga_decodes_full_precision() {
        let Ok(Sentence::Gga(g)) = parse_sentence(GGA_RTK) else {
            panic!("not a GGA");
        };
        assert_eq!(g.talker, "GN");
        assert_eq!(
            g.time.map(|t| t.to_string()).as_deref(),
            Some("13:28:19.600")
        );
        assert_eq!(g.lat_deg, Some(41.0 + 34.497_954_59 / 60.0));
        assert_eq!(g.lon_deg, Some(-(93.0 + 45.034_314_08 / 60.0)));
        assert_eq!((g.quality, g.satellites, g.hdop), (2, Some(10), Some(0.9)));
        assert_eq!(g.alt_msl_m, Some(278.161));
        assert_eq!(g.geoid_sep_m, Some(-31.442));
        assert!((g.alt_hae_m().unwrap_or(0.0) - 246.719).abs() < 1e-9);
        assert_eq!(g.dgps_station, Some(133));
    }

    #[test]
    fn empty_gga_has_no_fix() {
        let Ok(Sentence::Gga(g)) = parse_sentence("$GPGGA,,,,,,0,,,,M,,M,,*66\r\n") else {
            panic!("not a GGA");
        };
        assert_eq!(
            (g.time, g.lat_deg, g.quality, g.alt_hae_m()),
            (None, None, 0, None)
        );
        assert!(!g.has_fix());
    }

    #[test]
    fn framing_errors_are_typed() {
        let flipped = GGA_RTK.replace("*6A", "*6B");
        assert_eq!(
            parse_sentence(&flipped),
            Err(NmeaError::BadChecksum {
                stated: 0x6B,
                computed: 0x6A
            })
        );
        assert_eq!(
            parse_sentence("$GPHDT,274.07,T"),
            Err(NmeaError::MissingChecksum)
        );
        assert_eq!(parse_sentence("GPHDT,274.07,T*03"), Err(NmeaError::NoStart));
        assert!(matches!(
            parse_sentence("$GPHDT,274.07,T*0"),
            Err(NmeaError::Truncated(_))
        ));
        assert!(matches!(
            parse_sentence("$GPHDT,274.07,T*0G"),
            Err(NmeaError::MalformedChecksum(_))
        ));
        assert_eq!(parse_sentence("  \r\n"), Err(NmeaError::Empty));
        assert_eq!(
            parse_sentence("$GPHDT,27é*03"),
            Err(NmeaError::InvalidCharacter)
        );
    }

    fn sentence(body: &str) -> String {
        frame(body)
    }

    #[test]
    fn out_of_range_fields_are_rejected() {
        let cases = [
            (
                "GPGGA,120000,9100.0000,N,00000.0000,E,1,05,1.0,0.0,M,0.0,M,,",
                "latitude",
            ),
            (
                "GPGGA,120000,4560.0000,N,00000.0000,E,1,05,1.0,0.0,M,0.0,M,,",
                "latitude",
            ),
            (
                "GPGGA,120000,4500.0000,X,00000.0000,E,1,05,1.0,0.0,M,0.0,M,,",
                "latitude",
            ),
            (
                "GPGGA,120000,4500.0000,N,18100.0000,E,1,05,1.0,0.0,M,0.0,M,,",
                "longitude",
            ),
            (
                "GPGGA,120000,4500.0000,N,00000.0000,E,9,05,1.0,0.0,M,0.0,M,,",
                "quality",
            ),
            (
                "GPGGA,250000,4500.0000,N,00000.0000,E,1,05,1.0,0.0,M,0.0,M,,",
                "time",
            ),
            (
                "GPGGA,120000,4500.0000,N,00000.0000,E,1,05,1.0,0.0,F,0.0,M,,",
                "altitude unit",
            ),
            ("GPHDT,361.0,T", "heading"),
            (
                "GPRMC,120000,X,4500.0,N,00000.0,E,0.0,0.0,010120,,,A",
                "status",
            ),
            (
                "GPRMC,120000,A,4500.0,N,00000.0,E,0.0,0.0,320120,,,A",
                "date",
            ),
        ];
        for (body, field) in cases {
            match parse_sentence(&sentence(body)) {
                Err(NmeaError::OutOfRange { field: f, .. }) => assert_eq!(f, field, "{body}"),
                other => panic!("{body}: {other:?}"),
            }
        }
    }

    #[test]
    fn bad_numbers_and_counts_are_rejected() {
        for body in [
            "GPGGA,120000,45x0.0000,N,00000.0000,E,1,05,1.0,0.0,M,0.0,M,,",
            "GPGGA,120000,4500.0000,N,00000.0000,E,1,05,1.0,inf,M,0.0,M,,",
            "GPGGA,120000,4500.0000,N,00000.0000,E,1,05,1.0,1e3,M,0.0,M,,",
            "GPGGA,120000,4500.0000,N,00000.0000,E,1,-5,1.0,0.0,M,0.0,M,,",
        ] {
            assert!(
                matches!(
                    parse_sentence(&sentence(body)),
                    Err(NmeaError::BadNumber { .. })
                ),
                "{body}"
            );
        }
        assert!(matches!(
            parse_sentence(&sentence("GPGGA,120000,4500.0000,N")),
            Err(NmeaError::FieldCount { found: 3, .. })
        ));
        assert!(matches!(
            parse_sentence(&sentence("GPXYZ,1,2")),
            Err(NmeaError::Unsupported(_))
        ));
        assert!(matches!(
            parse_sentence(&sentence("GPVTG,,T,,M,,N,,K,N")),
            Ok(Sentence::Other { .. })
        ));
    }

    #[test]
    fn formatted_gga_parses_back() {
        let g = Gga {
            talker: "GN".into(),
            time: Some(UtcTime::from_seconds_of_day(48_499.6)),
            lat_deg: Some(-33.999_999_999_99),
            lon_deg: Some(151.123_456_789),
            quality: QUALITY_RTK_FIXED,
            satellites: Some(12),
            hdop: Some(0.8),
            alt_msl_m: Some(12.345),
            geoid_sep_m: Some(22.1),
            dgps_age_s: Some(1.0),
            dgps_station: Some(42),
        };
        let text = format_gga(&g);
        assert!(text.ends_with("\r\n"), "{text}");
        assert!(text.contains(",3400.00000000,S,"), "{text}");
        let Ok(Sentence::Gga(back)) = parse_sentence(&text) else {
            panic!("{text}");
        };
        assert_eq!(back.time, g.time);
        assert!((back.lat_deg.unwrap_or(0.0) - -34.0).abs() < 1e-12);
        assert!((back.lon_deg.unwrap_or(0.0) - 151.123_456_789).abs() < 1e-9);
        assert_eq!(back.alt_msl_m, Some(12.345));
    }

    #[test]
    fn formatted_rmc_and_hdt_parse_back() {
        let r = Rmc {
            talker: "GP".into(),
            time: Some(UtcTime::from_seconds_of_day(3600.25)),
            valid: true,
            lat_deg: Some(45.5),
            lon_deg: Some(-7.25),
            speed_mps: Some(1.0),
            track_deg: Some(90.0),
            date: Some(UtcDate {
                year: 2026,
                month: 11,
                day: 23,
            }),
            magvar_deg: Some(-2.5),
            mode: Some('R'),
        };
        let Ok(Sentence::Rmc(back)) = parse_sentence(&format_rmc(&r)) else {
            panic!("{}", format_rmc(&r));
        };
        assert_eq!(
            (back.date, back.magvar_deg, back.mode),
            (r.date, r.magvar_deg, r.mode)
        );
        assert!((back.speed_mps.unwrap_or(0.0) - 1.0).abs() < 1e-3);
        let Ok(Sentence::Hdt(h)) = parse_sentence(&format_hdt("GN", Some(-90.0))) else {
            panic!("hdt");
        };
        assert_eq!(h.heading_deg, Some(270.0));
    }

    #[test]
    fn gga_without_its_trailing_fields_is_read() {
        // Up to the altitude (9 fields) and up to its unit (10): heights are then orthometric
        // only, as such receivers send them.
        for body in [
            "GPGGA,120000,4500.0000,N,00700.0000,E,4,12,0.8,250.5",
            "GPGGA,120000,4500.0000,N,00700.0000,E,4,12,0.8,250.5,M",
            "GPGGA,120000,4500.0000,N,00700.0000,E,4,12,0.8,250.5,M,47.0,M",
        ] {
            let Ok(Sentence::Gga(g)) = parse_sentence(&frame(body)) else {
                panic!("{body}");
            };
            assert_eq!((g.quality, g.alt_msl_m), (4, Some(250.5)), "{body}");
            assert_eq!(g.dgps_station, None);
        }
        assert!(matches!(
            parse_sentence(&frame("GPGGA,120000,4500.0000,N,00700.0000,E,4,12,0.8")),
            Err(NmeaError::FieldCount { found: 8, .. })
        ));
        assert!(parse_sentence(&frame(
            "GPGGA,120000,4500.0000,N,00700.0000,E,4,12,0.8,250.5,X"
        ))
        .is_err());
    }

    #[test]
    fn time_of_day_wraps_and_rounds() {
        let t = UtcTime::from_seconds_of_day(86_400.0 + 3661.5);
        assert_eq!(
            (t.hour, t.minute, t.second, t.nanos),
            (1, 1, 1, 500_000_000)
        );
        assert_eq!(t.to_nmea(), "010101.50");
        assert_eq!(UtcTime::from_seconds_of_day(f64::NAN).seconds_of_day(), 0.0);
    }
}
