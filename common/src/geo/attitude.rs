//! Heading and attitude sentences beyond HDT that real dual-antenna receivers and GNSS/INS units
//! send: the standard `--THS` (true heading with a mode flag, NMEA 3.0+; u-blox, Septentrio,
//! Hemisphere) and the proprietary `$PASHR` (heading, roll, pitch and heave; Ashtech, Hemisphere,
//! SBG, Applanix), which gpsd also decodes.
//!
//! ```text
//! $GNTHS,hhh.hh,m*cs                      m: A autonomous, E estimated (dead reckoning),
//!                                            M manual, S simulator, V not valid
//! $PASHR,hhmmss.sss,hhh.hh,T,rrr.rr,ppp.pp,hhh.hh,a.aaa,b.bbb,c.ccc,q,i*cs
//!        time      heading   roll   pitch  heave  roll/pitch/heading sd  GNSS quality (0 none,
//!                                                                        1 no RTK, 2 RTK), INS
//!                                                                        status (0 aligning,
//!                                                                        1 aligned)
//! ```
//! Many units end `$PASHR` after heave or after the accuracies; both are accepted.

use super::nmea::{clip, field_count, opt_f64_in, opt_time, opt_uint, NmeaError, UtcTime};

/// `--THS`: true heading and whether it is valid.
#[derive(Clone, Debug, PartialEq)]
pub struct Ths {
    /// Talker id.
    pub talker: String,
    /// Heading, degrees clockwise from true north; `None` when the mode says not valid (`V`) or
    /// the field is empty.
    pub heading_deg: Option<f64>,
    /// Mode indicator: `A`, `E`, `M`, `S` or `V`.
    pub mode: char,
}

/// `$PASHR`: attitude of a GNSS/INS unit.
#[derive(Clone, Debug, PartialEq)]
pub struct Pashr {
    /// UTC time.
    pub time: Option<UtcTime>,
    /// True heading, degrees clockwise from north.
    pub heading_deg: Option<f64>,
    /// Roll, degrees (positive: right side down).
    pub roll_deg: Option<f64>,
    /// Pitch, degrees (positive: nose up).
    pub pitch_deg: Option<f64>,
    /// Heave, metres.
    pub heave_m: Option<f64>,
    /// Standard deviation of the heading, degrees, when sent.
    pub heading_sd_deg: Option<f64>,
    /// GNSS quality flag: 0 no position, 1 without RTK, 2 RTK; `None` when not sent.
    pub gnss_quality: Option<u8>,
    /// INS status: 0 still aligning, 1 aligned; `None` when not sent.
    pub ins_aligned: Option<bool>,
}

impl Pashr {
    /// The heading, when the unit says it can be used: not while its INS is still aligning or
    /// it has no GNSS position.
    pub fn usable_heading_deg(&self) -> Option<f64> {
        if self.ins_aligned == Some(false) || self.gnss_quality == Some(0) {
            return None;
        }
        self.heading_deg
    }
}

pub(crate) fn parse_ths(talker: &str, f: &[&str]) -> Result<Ths, NmeaError> {
    const S: &str = "THS";
    field_count(S, f, 2, 2)?;
    let mode = match f[1] {
        "A" | "E" | "M" | "S" | "V" => f[1].chars().next().unwrap_or('V'),
        other => {
            return Err(NmeaError::OutOfRange {
                sentence: S,
                field: "mode",
                value: clip(other),
            })
        }
    };
    let heading = opt_f64_in(S, "heading", f[0], 0.0, 360.0)?;
    Ok(Ths {
        talker: talker.to_string(),
        heading_deg: heading.filter(|_| mode != 'V').map(|h| h.rem_euclid(360.0)),
        mode,
    })
}

pub(crate) fn parse_pashr(f: &[&str]) -> Result<Pashr, NmeaError> {
    const S: &str = "PASHR";
    field_count(S, f, 6, 11)?;
    if !(f[2].is_empty() || f[2] == "T") {
        return Err(NmeaError::OutOfRange {
            sentence: S,
            field: "heading reference",
            value: clip(f[2]),
        });
    }
    let get = |i: usize| f.get(i).copied().unwrap_or("");
    Ok(Pashr {
        time: opt_time(S, f[0])?,
        heading_deg: opt_f64_in(S, "heading", f[1], 0.0, 360.0)?.map(|h| h.rem_euclid(360.0)),
        roll_deg: opt_f64_in(S, "roll", f[3], -180.0, 180.0)?,
        pitch_deg: opt_f64_in(S, "pitch", f[4], -90.0, 90.0)?,
        heave_m: opt_f64_in(S, "heave", f[5], -1e3, 1e3)?,
        heading_sd_deg: opt_f64_in(S, "heading accuracy", get(8), 0.0, 360.0)?,
        gnss_quality: opt_uint(S, "gnss quality", get(9), 2)?.map(|q| q as u8),
        ins_aligned: opt_uint(S, "ins status", get(10), 1)?.map(|s| s == 1),
    })
}

#[cfg(test)]
mod tests {
    use super::super::nmea::{frame, parse_sentence, Sentence};

    #[test]
    fn ths_gives_a_heading_unless_not_valid() {
        let Ok(Sentence::Ths(t)) = parse_sentence(&frame("GNTHS,77.52,A")) else {
            panic!("ths");
        };
        assert_eq!((t.heading_deg, t.mode), (Some(77.52), 'A'));
        let Ok(Sentence::Ths(t)) = parse_sentence(&frame("GNTHS,77.52,V")) else {
            panic!("ths V");
        };
        assert_eq!(t.heading_deg, None);
        let Ok(Sentence::Ths(t)) = parse_sentence(&frame("GNTHS,,V")) else {
            panic!("empty ths");
        };
        assert_eq!(t.heading_deg, None);
        assert!(parse_sentence(&frame("GNTHS,77.5,X")).is_err());
        assert!(parse_sentence(&frame("GNTHS,377.5,A")).is_err());
        assert!(parse_sentence(&frame("GNTHS,77.5")).is_err());
    }

    #[test]
    fn pashr_full_and_short_forms() {
        let full = frame("PASHR,085335.000,224.19,T,-01.26,+00.83,+00.00,0.101,0.113,0.267,2,1");
        let Ok(Sentence::Pashr(p)) = parse_sentence(&full) else {
            panic!("{full}");
        };
        assert_eq!(p.heading_deg, Some(224.19));
        assert_eq!((p.roll_deg, p.pitch_deg), (Some(-1.26), Some(0.83)));
        assert_eq!((p.gnss_quality, p.ins_aligned), (Some(2), Some(true)));
        assert_eq!(p.heading_sd_deg, Some(0.267));
        assert_eq!(p.usable_heading_deg(), Some(224.19));
        let short = frame("PASHR,085335.00,224.19,T,-01.26,+00.83,+00.00");
        let Ok(Sentence::Pashr(p)) = parse_sentence(&short) else {
            panic!("{short}");
        };
        assert_eq!((p.heading_deg, p.ins_aligned), (Some(224.19), None));
        assert_eq!(p.usable_heading_deg(), Some(224.19));
        let aligning = frame("PASHR,085335.000,224.19,T,-01.26,+00.83,+00.00,0.1,0.1,0.2,2,0");
        let Ok(Sentence::Pashr(p)) = parse_sentence(&aligning) else {
            panic!("{aligning}");
        };
        assert_eq!(p.usable_heading_deg(), None);
        for bad in [
            "PASHR,085335.000,224.19,M,-01.26,+00.83,+00.00",
            "PASHR,085335.000,224.19,T,-01.26",
            "PASHR,085335.000,224.19,T,-01.26,+95.0,+00.00",
            "PASHR,085335.000,nan,T,-01.26,+0.83,+00.00",
        ] {
            assert!(parse_sentence(&frame(bad)).is_err(), "{bad}");
        }
    }
}
