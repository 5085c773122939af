//! The Orpheus navigation-computer protocol (methods.md section 7): NMEA framing and checksum,
//! route lists and route edits exchanged between the navigation computer (`NA`) and the
//! control application (`CA`).
//!
//! ```text
//! $NALST,id,ddmm.mmmmmm,N,dddmm.mmmmmm,E,lat_err_m,lon_err_m*cs   route point (list)
//! $NALST,END*cs                                                     end of the route list
//! $NAWPT,id*cs                                                      waypoint id reached
//! $CAREM,id*cs   / $CAREM,END*cs                                    remove waypoint / end of removals
//! $CAINS,id,lat,N,lon,E,lat_err_m,lon_err_m*cs / $CAINS,END*cs      insert at id (shifting the rest)
//! $CASPD,pct*cs                                                     speed limit, 0-100 %
//! ```
//! Errors are [`NmeaError`]s, with the sentence named by its full address (`NALST`).

use super::nmea::{
    clip, field_count, format_angle, frame, opt_angle, opt_f64_in, opt_uint, split_frame, NmeaError,
};

/// One route point: its id, position and the 1-sigma position errors the recorder gave it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoutePoint {
    /// Waypoint id (index in the route).
    pub id: u32,
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Latitude (north) error, metres.
    pub lat_err_m: f64,
    /// Longitude (east) error, metres.
    pub lon_err_m: f64,
}

/// One message of the protocol.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum OrpheusMessage {
    /// `$NALST,id,...`: a point of the recorded route.
    RoutePoint(RoutePoint),
    /// `$NALST,END`: the route list is complete.
    RouteEnd,
    /// `$NAWPT,id`: the robot reached waypoint `id`.
    WaypointReached(u32),
    /// `$CAREM,id`: remove waypoint `id`.
    Remove(u32),
    /// `$CAREM,END`: end of removals.
    RemoveEnd,
    /// `$CAINS,id,...`: insert a point at `id`, shifting the rest.
    Insert(RoutePoint),
    /// `$CAINS,END`: end of insertions.
    InsertEnd,
    /// `$CASPD,pct`: speed limit, percent of the maximum (0-100).
    SpeedLimit(u8),
}

const MAX_ID: u64 = u32::MAX as u64;

fn parse_id(sentence: &'static str, s: &str) -> Result<u32, NmeaError> {
    match opt_uint(sentence, "id", s, MAX_ID)? {
        Some(id) => Ok(id as u32),
        None => Err(NmeaError::BadNumber {
            sentence,
            field: "id",
            value: String::new(),
        }),
    }
}

fn required<T>(
    sentence: &'static str,
    field: &'static str,
    v: Result<Option<T>, NmeaError>,
) -> Result<T, NmeaError> {
    v?.ok_or(NmeaError::BadNumber {
        sentence,
        field,
        value: String::new(),
    })
}

fn parse_point(sentence: &'static str, f: &[&str]) -> Result<RoutePoint, NmeaError> {
    field_count(sentence, f, 7, 7)?;
    Ok(RoutePoint {
        id: parse_id(sentence, f[0])?,
        lat_deg: required(
            sentence,
            "latitude",
            opt_angle(sentence, "latitude", f[1], f[2], 90.0, "N", "S"),
        )?,
        lon_deg: required(
            sentence,
            "longitude",
            opt_angle(sentence, "longitude", f[3], f[4], 180.0, "E", "W"),
        )?,
        lat_err_m: required(
            sentence,
            "lat_err",
            opt_f64_in(sentence, "lat_err", f[5], 0.0, 1e7),
        )?,
        lon_err_m: required(
            sentence,
            "lon_err",
            opt_f64_in(sentence, "lon_err", f[6], 0.0, 1e7),
        )?,
    })
}

/// `id` or `END` (a one-field message).
fn id_or_end(sentence: &'static str, f: &[&str]) -> Result<Option<u32>, NmeaError> {
    field_count(sentence, f, 1, 1)?;
    if f[0] == "END" {
        Ok(None)
    } else {
        parse_id(sentence, f[0]).map(Some)
    }
}

/// Parses one protocol line (trailing CR LF optional).
pub fn parse_orpheus(line: &str) -> Result<OrpheusMessage, NmeaError> {
    let frame = split_frame(line)?;
    let f = &frame.fields;
    let end = f.len() == 1 && f[0] == "END";
    match frame.address {
        "NALST" if end => Ok(OrpheusMessage::RouteEnd),
        "NALST" => parse_point("NALST", f).map(OrpheusMessage::RoutePoint),
        "CAINS" if end => Ok(OrpheusMessage::InsertEnd),
        "CAINS" => parse_point("CAINS", f).map(OrpheusMessage::Insert),
        "NAWPT" => {
            field_count("NAWPT", f, 1, 1)?;
            parse_id("NAWPT", f[0]).map(OrpheusMessage::WaypointReached)
        }
        "CAREM" => Ok(match id_or_end("CAREM", f)? {
            Some(id) => OrpheusMessage::Remove(id),
            None => OrpheusMessage::RemoveEnd,
        }),
        "CASPD" => {
            field_count("CASPD", f, 1, 1)?;
            let pct = required("CASPD", "percent", opt_uint("CASPD", "percent", f[0], 100))?;
            Ok(OrpheusMessage::SpeedLimit(pct as u8))
        }
        other => Err(NmeaError::Unsupported(clip(other))),
    }
}

fn point_fields(p: &RoutePoint) -> String {
    let (lat, ns) = format_angle(p.lat_deg, 2, 6, 'N', 'S');
    let (lon, ew) = format_angle(p.lon_deg, 3, 6, 'E', 'W');
    format!(
        "{},{lat},{ns},{lon},{ew},{:.3},{:.3}",
        p.id,
        p.lat_err_m.abs(),
        p.lon_err_m.abs()
    )
}

/// Formats one message as a complete sentence (checksum, CR LF). Minutes get 6 decimals
/// (about 2 mm), errors 3; speed limits above 100 % are sent as 100.
pub fn format_orpheus(m: &OrpheusMessage) -> String {
    let body = match m {
        OrpheusMessage::RoutePoint(p) => format!("NALST,{}", point_fields(p)),
        OrpheusMessage::RouteEnd => "NALST,END".to_string(),
        OrpheusMessage::WaypointReached(id) => format!("NAWPT,{id}"),
        OrpheusMessage::Remove(id) => format!("CAREM,{id}"),
        OrpheusMessage::RemoveEnd => "CAREM,END".to_string(),
        OrpheusMessage::Insert(p) => format!("CAINS,{}", point_fields(p)),
        OrpheusMessage::InsertEnd => "CAINS,END".to_string(),
        OrpheusMessage::SpeedLimit(pct) => format!("CASPD,{}", (*pct).min(100)),
    };
    frame(&body)
}

/// A whole route list: one `$NALST` per point, then `$NALST,END`.
pub fn format_route(points: &[RoutePoint]) -> Vec<String> {
    points
        .iter()
        .map(|p| format_orpheus(&OrpheusMessage::RoutePoint(*p)))
        .chain(std::iter::once(format_orpheus(&OrpheusMessage::RouteEnd)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(id: u32) -> RoutePoint {
        RoutePoint {
            id,
            lat_deg: 50.083_621_5,
            lon_deg: -14.418_540_25,
            lat_err_m: 0.02,
            lon_err_m: 0.031,
        }
    }

    #[test]
    fn every_message_round_trips() {
        let msgs = [
            OrpheusMessage::RoutePoint(point(3)),
            OrpheusMessage::RouteEnd,
            OrpheusMessage::WaypointReached(7),
            OrpheusMessage::Remove(2),
            OrpheusMessage::RemoveEnd,
            OrpheusMessage::Insert(point(4)),
            OrpheusMessage::InsertEnd,
            OrpheusMessage::SpeedLimit(40),
        ];
        for m in msgs {
            let text = format_orpheus(&m);
            assert!(text.ends_with("\r\n"));
            let back = parse_orpheus(&text).unwrap_or_else(|e| panic!("{text}: {e}"));
            match (m, back) {
                (OrpheusMessage::RoutePoint(a), OrpheusMessage::RoutePoint(b))
                | (OrpheusMessage::Insert(a), OrpheusMessage::Insert(b)) => {
                    assert_eq!(a.id, b.id);
                    // 6 decimals of minutes: 1e-6/60 deg.
                    assert!((a.lat_deg - b.lat_deg).abs() < 1e-8, "{text}");
                    assert!((a.lon_deg - b.lon_deg).abs() < 1e-8, "{text}");
                    assert_eq!((a.lat_err_m, a.lon_err_m), (b.lat_err_m, b.lon_err_m));
                }
                (a, b) => assert_eq!(a, b),
            }
        }
    }

    #[test]
    fn wire_form_matches_the_spec() {
        let text = format_orpheus(&OrpheusMessage::RoutePoint(point(3)));
        assert!(
            text.starts_with("$NALST,3,5005.017290,N,01425.112415,W,0.020,0.031*"),
            "{text}"
        );
        assert_eq!(format_route(&[point(0), point(1)]).len(), 3);
        assert_eq!(
            format_orpheus(&OrpheusMessage::RouteEnd),
            frame("NALST,END")
        );
    }

    #[test]
    fn bad_messages_are_typed_errors() {
        let good = format_orpheus(&OrpheusMessage::WaypointReached(5));
        let corrupted = good.replace("NAWPT,5", "NAWPT,6");
        assert!(matches!(
            parse_orpheus(&corrupted),
            Err(NmeaError::BadChecksum { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("CASPD,101")),
            Err(NmeaError::OutOfRange { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("CASPD,")),
            Err(NmeaError::BadNumber { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("NAWPT,END")),
            Err(NmeaError::BadNumber { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("NALST,1,5005.0,N,01425.1,W,0.1")),
            Err(NmeaError::FieldCount { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("NALST,1,5005.0,N,01425.1,W,-0.1,0.1")),
            Err(NmeaError::OutOfRange { .. })
        ));
        assert!(matches!(
            parse_orpheus(&frame("CAXYZ,1")),
            Err(NmeaError::Unsupported(_))
        ));
        assert_eq!(parse_orpheus("$CAREM,END"), Err(NmeaError::MissingChecksum));
    }
}
