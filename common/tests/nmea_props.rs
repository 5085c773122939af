//! Property tests of the NMEA / Trimble / Orpheus codecs: formatting then parsing gives the
//! values back (to the resolution of the text form), and no input, however broken, panics a
//! parser.

use common::geo::nmea::{
    format_gga, format_hdt, format_rmc, frame, parse_sentence, Gga, NmeaError, Rmc, Sentence,
    UtcDate, UtcTime,
};
use common::geo::orpheus::{format_orpheus, parse_orpheus, OrpheusMessage, RoutePoint};
use common::geo::trimble::{format_avr, format_ggk, Avr, Ggk};
use proptest::prelude::*;

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Times with centisecond resolution (what `hhmmss.ss` carries).
fn any_time() -> impl Strategy<Value = UtcTime> {
    (0u32..8_640_000).prop_map(|cs| UtcTime::from_seconds_of_day(f64::from(cs) / 100.0))
}

fn any_lat() -> impl Strategy<Value = f64> {
    prop_oneof![
        -90.0..=90.0f64,
        Just(90.0),
        Just(-90.0),
        Just(0.0),
        Just(-1e-12)
    ]
}

fn any_lon() -> impl Strategy<Value = f64> {
    prop_oneof![-180.0..=180.0f64, Just(180.0), Just(-179.999_999_999_999)]
}

fn opt<T: std::fmt::Debug + Clone>(
    s: impl Strategy<Value = T>,
) -> impl Strategy<Value = Option<T>> {
    prop_oneof![1 => Just(None), 4 => s.prop_map(Some)]
}

/// Sentences from the real logs and the simulator's formatters: seeds for mutation.
const SEEDS: [&str; 8] = [
    "GNGGA,132819.60,4134.49795459,N,09345.03431408,W,2,10,0.9,278.161,M,-31.442,M,6.6,0133",
    "GNRMC,132819.60,A,4134.49795459,N,09345.03431408,W,0.148,124.888,180320,11.5985,E,D",
    "GPHDT,274.07,T",
    "GPGGA,,,,,,0,,,,M,,M,,",
    "PTNL,AVR,212604.30,+52.1800,Yaw,,,-0.0807,Roll,12.579,3,1.4,16",
    "PTNL,GGK,102939.00,051910,5000.97323841,N,00827.62010742,E,5,09,1.9,EHT150.790,M",
    "NALST,3,5005.017290,N,01425.112415,W,0.020,0.031",
    "CASPD,40",
];

proptest! {
    #![proptest_config(config(3000))]

    #[test]
    fn gga_round_trips(
        time in opt(any_time()),
        lat in any_lat(), lon in any_lon(),
        quality in 0u8..=8, satellites in opt(0u8..=99),
        hdop_dm in opt(0u32..999),
        alt_mm in opt(-1_000_000i64..20_000_000), sep_mm in opt(-120_000i64..120_000),
        talker in prop_oneof![Just("GP"), Just("GN"), Just("GL")],
    ) {
        let g = Gga {
            talker: talker.to_string(), time, lat_deg: Some(lat), lon_deg: Some(lon), quality,
            satellites, hdop: hdop_dm.map(|v| f64::from(v) / 10.0),
            alt_msl_m: alt_mm.map(|v| v as f64 / 1000.0), geoid_sep_m: sep_mm.map(|v| v as f64 / 1000.0),
            dgps_age_s: None, dgps_station: None,
        };
        let text = format_gga(&g);
        prop_assert!(text.ends_with("\r\n"));
        let back = match parse_sentence(&text) {
            Ok(Sentence::Gga(b)) => b,
            other => return Err(TestCaseError::fail(format!("{text}: {other:?}"))),
        };
        prop_assert_eq!(&back.talker, &g.talker);
        prop_assert_eq!(back.time, g.time);
        prop_assert_eq!((back.quality, back.satellites, back.hdop), (g.quality, g.satellites, g.hdop));
        prop_assert!((back.lat_deg.unwrap_or(f64::NAN) - lat).abs() < 1e-9, "{}", text);
        prop_assert!((back.lon_deg.unwrap_or(f64::NAN) - lon).abs() < 1e-9, "{}", text);
        for (a, b) in [(back.alt_msl_m, g.alt_msl_m), (back.geoid_sep_m, g.geoid_sep_m), (back.alt_hae_m(), g.alt_hae_m())] {
            prop_assert_eq!(a.is_some(), b.is_some());
            if let (Some(a), Some(b)) = (a, b) {
                prop_assert!((a - b).abs() < 1e-3, "{}", text);
            }
        }
    }

    #[test]
    fn rmc_round_trips(
        time in opt(any_time()), valid in any::<bool>(), lat in any_lat(), lon in any_lon(),
        speed in opt(0.0..100.0f64), track in opt(0.0..359.9f64),
        day in 1u8..=28, month in 1u8..=12, year in 1980u16..2080,
    ) {
        let r = Rmc {
            talker: "GN".into(), time, valid, lat_deg: Some(lat), lon_deg: Some(lon),
            speed_mps: speed, track_deg: track, date: Some(UtcDate { year, month, day }),
            magvar_deg: None, mode: Some('A'),
        };
        let text = format_rmc(&r);
        let back = match parse_sentence(&text) {
            Ok(Sentence::Rmc(b)) => b,
            other => return Err(TestCaseError::fail(format!("{text}: {other:?}"))),
        };
        prop_assert_eq!((back.time, back.valid, back.date, back.mode), (r.time, r.valid, r.date, r.mode));
        prop_assert!((back.lat_deg.unwrap_or(f64::NAN) - lat).abs() < 1e-9);
        prop_assert!((back.lon_deg.unwrap_or(f64::NAN) - lon).abs() < 1e-9);
        if let (Some(a), Some(b)) = (back.speed_mps, speed) {
            prop_assert!((a - b).abs() < 1e-3);
        }
    }

    #[test]
    fn avr_and_hdt_round_trip(
        time in opt(any_time()), yaw in opt(0.0..360.0f64),
        tilt in opt(-90.0..90.0f64), roll in opt(-90.0..90.0f64),
        range in opt(0.0..1000.0f64), quality in 0u8..=4, sats in opt(0u8..=99),
    ) {
        let a = Avr { time, yaw_deg: yaw, tilt_deg: tilt, roll_deg: roll, range_m: range, quality, pdop: Some(1.5), satellites: sats };
        let text = format_avr(&a);
        let back = match parse_sentence(&text) {
            Ok(Sentence::Avr(b)) => b,
            other => return Err(TestCaseError::fail(format!("{text}: {other:?}"))),
        };
        prop_assert_eq!((back.time, back.quality, back.satellites, back.pdop), (a.time, a.quality, a.satellites, a.pdop));
        for (x, y, tol) in [(back.yaw_deg, yaw, 5.1e-5), (back.tilt_deg, tilt, 5.1e-5), (back.roll_deg, roll, 5.1e-5), (back.range_m, range, 5.1e-4)] {
            prop_assert_eq!(x.is_some(), y.is_some(), "{}", text);
            if let (Some(x), Some(y)) = (x, y) {
                // Yaw near 360 may come back as 360.0000 (the same direction).
                let d = (x - y).abs();
                prop_assert!(d < tol || (d - 360.0).abs() < tol, "{}", text);
            }
        }
        let hdt = format_hdt("GN", yaw);
        match parse_sentence(&hdt) {
            Ok(Sentence::Hdt(h)) => {
                prop_assert_eq!(h.heading_deg.is_some(), yaw.is_some());
                if let (Some(x), Some(y)) = (h.heading_deg, yaw) {
                    let d = (x - y).abs();
                    prop_assert!(d < 5.1e-4 || (d - 360.0).abs() < 5.1e-4, "{}", hdt);
                }
            }
            other => return Err(TestCaseError::fail(format!("{hdt}: {other:?}"))),
        }
    }

    #[test]
    fn ggk_round_trips(time in opt(any_time()), lat in any_lat(), lon in any_lon(), h_mm in opt(-1_000_000i64..10_000_000), quality in 0u8..=13) {
        let g = Ggk {
            time, date: Some(UtcDate { year: 2026, month: 11, day: 23 }), lat_deg: Some(lat), lon_deg: Some(lon),
            quality, satellites: Some(12), dop: Some(1.1), alt_hae_m: h_mm.map(|v| v as f64 / 1000.0),
        };
        let text = format_ggk(&g);
        let back = match parse_sentence(&text) {
            Ok(Sentence::Ggk(b)) => b,
            other => return Err(TestCaseError::fail(format!("{text}: {other:?}"))),
        };
        prop_assert_eq!((back.time, back.date, back.quality), (g.time, g.date, g.quality));
        prop_assert!((back.lat_deg.unwrap_or(f64::NAN) - lat).abs() < 1e-9);
        prop_assert!((back.lon_deg.unwrap_or(f64::NAN) - lon).abs() < 1e-9);
        if let (Some(a), Some(b)) = (back.alt_hae_m, g.alt_hae_m) {
            prop_assert!((a - b).abs() < 1e-3);
        }
    }

    #[test]
    fn orpheus_round_trips(id in any::<u32>(), lat in any_lat(), lon in any_lon(), e1 in 0.0..100.0f64, e2 in 0.0..100.0f64, pct in 0u8..=100, insert in any::<bool>()) {
        let p = RoutePoint { id, lat_deg: lat, lon_deg: lon, lat_err_m: e1, lon_err_m: e2 };
        let m = if insert { OrpheusMessage::Insert(p) } else { OrpheusMessage::RoutePoint(p) };
        let text = format_orpheus(&m);
        let back = match parse_orpheus(&text) {
            Ok(OrpheusMessage::Insert(b)) | Ok(OrpheusMessage::RoutePoint(b)) => b,
            other => return Err(TestCaseError::fail(format!("{text}: {other:?}"))),
        };
        prop_assert_eq!(back.id, id);
        // 6 decimals of minutes: 8.4e-9 deg, about 1 mm.
        prop_assert!((back.lat_deg - lat).abs() < 1e-8 && (back.lon_deg - lon).abs() < 1e-8, "{}", text);
        prop_assert!((back.lat_err_m - e1).abs() < 6e-4 && (back.lon_err_m - e2).abs() < 6e-4);
        prop_assert_eq!(parse_orpheus(&format_orpheus(&OrpheusMessage::SpeedLimit(pct))), Ok(OrpheusMessage::SpeedLimit(pct)));
    }
}

proptest! {
    #![proptest_config(config(20_000))]

    #[test]
    fn arbitrary_text_never_panics(s in "\\PC*") {
        let _ = parse_sentence(&s);
        let _ = parse_orpheus(&s);
    }

    #[test]
    fn nmea_like_text_never_panics(s in "\\$[A-Z]{0,6}(,[-+0-9A-Z.]{0,12}){0,16}(\\*[0-9A-Fa-f]{0,3})?") {
        let _ = parse_sentence(&s);
        let _ = parse_orpheus(&s);
    }

    /// Mutations of real sentences, re-checksummed so they reach the field parsers.
    #[test]
    fn mutated_sentences_never_panic(
        seed in 0usize..SEEDS.len(),
        edits in proptest::collection::vec((any::<prop::sample::Index>(), prop_oneof![
            Just(""), Just(","), Just("."), Just("-"), Just("9"), Just("0"), Just("99999999999999999999"),
            Just("N"), Just("E"), Just("é"), Just("*"), Just("$"), Just("inf"), Just("1e5"), Just("END"),
        ]), 1..4),
    ) {
        let mut body = SEEDS[seed].to_string();
        for (at, text) in edits {
            let mut i = at.index(body.len() + 1);
            while !body.is_char_boundary(i) { i -= 1; }
            // Either insert or replace one char.
            if i < body.len() && text.len() == 1 {
                let end = (i + 1..=body.len()).find(|&j| body.is_char_boundary(j)).unwrap_or(body.len());
                body.replace_range(i..end, text);
            } else {
                body.insert_str(i, text);
            }
        }
        let line = frame(&body);
        let r1 = parse_sentence(&line);
        let r2 = parse_orpheus(&line);
        // A checksum we computed ourselves is never the complaint (unless the body holds '*').
        if !body.contains('*') {
            prop_assert!(!matches!(r1, Err(NmeaError::BadChecksum { .. })), "{:?}", r1);
            prop_assert!(!matches!(r2, Err(NmeaError::BadChecksum { .. })), "{:?}", r2);
        }
    }
}
