//! Decodes the real NMEA logs of `../shared/data/gnss/` and compares them with gpsd's decoding
//! (`X.log.chk`): lat/lon to 1e-9 deg, heights to 1 mm, fix mode/status against GGA quality,
//! HDT heading against gpsd's ATT heading.
//!
//! Pairing: a `.chk` file echoes every NMEA sentence gpsd read, followed by the JSON reports that
//! sentence produced. So the test walks the `.chk`, decodes each echoed sentence with our parser
//! (after checking that it is a line of the `.log`), keeps the latest GGA / position / HDT, and
//! compares each TPV or ATT report with that state. gpsd prints lat/lon with 9 decimals and heights
//! with 4, so the tolerances include its rounding (5e-10 deg, 5e-5 m).

use std::collections::HashSet;
use std::path::PathBuf;

use common::geo::nmea::{parse_sentence, Gga, Sentence};
use serde_json::Value;

fn data_dir(what: &str) -> Option<PathBuf> {
    common::shared_data::locate(env!("CARGO_MANIFEST_DIR"), "", what)
}

#[derive(Default, Debug)]
struct Stats {
    sentences: usize,
    tpv_pos: usize,
    tpv_heights: usize,
    tpv_mode: usize,
    tpv_status: usize,
    tpv_time: usize,
    tpv_date: usize,
    att: usize,
    max_pos_err_deg: f64,
    max_height_err_m: f64,
    max_heading_err_deg: f64,
}

/// gpsd's TPV status for a GGA quality (data README): 2 -> 2 (DGPS), 4 -> 3 (RTK fixed),
/// 5 -> 4 (RTK float); 0/1 -> absent.
fn expected_status(quality: u8) -> Option<i64> {
    match quality {
        2 => Some(2),
        4 => Some(3),
        5 => Some(4),
        _ => None,
    }
}

/// gpsd's TPV mode for a GGA: no fix -> 1, a fix with altitude -> 3 (3D), without -> 2.
/// Like gpsd, a fix claimed with 0 satellites used (hemi.log's start-up) counts as no fix.
fn expected_mode(g: &Gga) -> i64 {
    if !g.has_fix() {
        1
    } else if g.alt_msl_m.is_some() {
        3
    } else {
        2
    }
}

fn check_log(dir: &std::path::Path, name: &str) -> Stats {
    let log = std::fs::read_to_string(dir.join(name)).expect("read log");
    let chk = std::fs::read_to_string(dir.join(format!("{name}.chk"))).expect("read chk");
    let mut stats = Stats::default();

    // Every sentence of the log decodes.
    let mut log_sentences = HashSet::new();
    for (i, line) in log.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Err(e) = parse_sentence(line) {
            panic!("{name}:{}: {line}: {e}", i + 1);
        }
        stats.sentences += 1;
        log_sentences.insert(line.to_string());
    }

    let mut last_gga: Option<Gga> = None;
    let mut last_pos: Option<(f64, f64)> = None;
    let mut last_heading: Option<f64> = None;
    let mut last_kind = String::new();
    let mut last_time: Option<String> = None;
    let mut last_date: Option<String> = None;
    for (i, line) in chk.lines().enumerate() {
        let at = format!("{name}.chk:{}", i + 1);
        let line = line.trim();
        if line.starts_with('$') {
            assert!(
                log_sentences.contains(line),
                "{at}: echo not in the log: {line}"
            );
            let s = parse_sentence(line).unwrap_or_else(|e| panic!("{at}: {e}"));
            last_kind = s.kind().to_string();
            last_time = s.time().map(|t| t.to_string());
            last_date = match &s {
                Sentence::Rmc(r) => r.date.map(|d| d.to_string()),
                Sentence::Zda(z) => z.date.map(|d| d.to_string()),
                _ => None,
            };
            match s {
                Sentence::Gga(g) => {
                    if let (Some(lat), Some(lon)) = (g.lat_deg, g.lon_deg) {
                        last_pos = Some((lat, lon));
                    }
                    last_gga = Some(g);
                }
                Sentence::Rmc(r) => {
                    if let (Some(lat), Some(lon)) = (r.lat_deg, r.lon_deg) {
                        last_pos = Some((lat, lon));
                    }
                }
                Sentence::Hdt(h) => last_heading = h.heading_deg,
                _ => {}
            }
            continue;
        }
        if !line.starts_with('{') {
            continue;
        }
        let v: Value = serde_json::from_str(line).unwrap_or_else(|e| panic!("{at}: {e}"));
        match v["class"].as_str() {
            Some("TPV") => {
                // gpsd's time is ISO 8601 "2018-09-07T19:39:14.000Z": the time of day must be the
                // sentence's, and the date the sentence's when it carries one (RMC, ZDA).
                if let (Some(theirs), Some(mine)) = (v["time"].as_str(), &last_time) {
                    let (date, time) = theirs.split_once('T').unwrap_or(("", theirs));
                    assert_eq!(time.trim_end_matches('Z'), mine, "{at}: time");
                    if let Some(my_date) = &last_date {
                        assert_eq!(date, my_date, "{at}: date");
                        stats.tpv_date += 1;
                    }
                    stats.tpv_time += 1;
                }
                if let (Some(lat), Some(lon)) = (v["lat"].as_f64(), v["lon"].as_f64()) {
                    let (my_lat, my_lon) = last_pos.unwrap_or_else(|| panic!("{at}: no position"));
                    let err = (lat - my_lat).abs().max((lon - my_lon).abs());
                    assert!(
                        err <= 1e-9,
                        "{at}: lat/lon {my_lat} {my_lon} vs {lat} {lon}"
                    );
                    stats.max_pos_err_deg = stats.max_pos_err_deg.max(err);
                    stats.tpv_pos += 1;
                }
                if let Some(g) = &last_gga {
                    for (key, mine) in [
                        ("altMSL", g.alt_msl_m),
                        ("geoidSep", g.geoid_sep_m),
                        ("altHAE", g.alt_hae_m()),
                    ] {
                        if let Some(theirs) = v[key].as_f64() {
                            let mine = mine.unwrap_or_else(|| panic!("{at}: no {key}"));
                            let err = (theirs - mine).abs();
                            assert!(err <= 1e-3, "{at}: {key} {mine} vs {theirs}");
                            stats.max_height_err_m = stats.max_height_err_m.max(err);
                            stats.tpv_heights += 1;
                        }
                    }
                    assert_eq!(
                        v["status"].as_i64(),
                        expected_status(g.quality),
                        "{at}: status vs GGA quality {}",
                        g.quality
                    );
                    stats.tpv_status += 1;
                    // Reports produced by a GGA, or by the RMC closing its cycle, carry the GGA's
                    // mode (a ZDA alone produces mode 0, "not seen", and HDT repeats: skipped).
                    if last_kind == "GGA" || last_kind == "RMC" {
                        assert_eq!(v["mode"].as_i64(), Some(expected_mode(g)), "{at}: mode");
                        stats.tpv_mode += 1;
                    }
                }
            }
            Some("ATT") => {
                if let Some(theirs) = v["heading"].as_f64() {
                    let mine = last_heading.unwrap_or_else(|| panic!("{at}: no HDT heading"));
                    let err = (theirs - mine).abs();
                    assert!(err <= 1e-9, "{at}: heading {mine} vs {theirs}");
                    stats.max_heading_err_deg = stats.max_heading_err_deg.max(err);
                    stats.att += 1;
                }
            }
            _ => {}
        }
    }
    println!("{name}: {stats:?}");
    stats
}

#[test]
fn gnss_logs_agree_with_gpsd() {
    let Some(dir) = data_dir("gnss_logs_agree_with_gpsd") else {
        return;
    };
    let gnss = dir.join("gnss");
    let rtk = check_log(&gnss, "nmea-rtk.log");
    assert!(
        rtk.tpv_pos > 100 && rtk.tpv_heights > 300 && rtk.tpv_mode > 50,
        "{rtk:?}"
    );
    let hemi = check_log(&gnss, "hemi.log");
    assert!(
        hemi.att == 4 && hemi.tpv_pos > 10 && hemi.tpv_mode > 100,
        "{hemi:?}"
    );
    let cat = check_log(&gnss, "cat-ms352.log");
    assert!(cat.tpv_pos > 30, "{cat:?}");
}

#[test]
fn rtk_log_has_fixed_and_differential_quality() {
    let Some(dir) = data_dir("rtk_log_has_fixed_and_differential_quality") else {
        return;
    };
    let log = std::fs::read_to_string(dir.join("gnss/nmea-rtk.log")).expect("read");
    let mut qualities = std::collections::BTreeMap::new();
    for line in log.lines().filter(|l| l.starts_with('$')) {
        if let Ok(Sentence::Gga(g)) = parse_sentence(line) {
            *qualities.entry(g.quality).or_insert(0) += 1;
        }
    }
    assert_eq!(qualities.get(&2), Some(&104), "{qualities:?}");
    assert_eq!(qualities.get(&4), Some(&18), "{qualities:?}");
}

#[test]
fn trimble_examples_decode_and_a_bad_checksum_is_rejected() {
    let Some(dir) = data_dir("trimble_examples_decode") else {
        return;
    };
    let text = std::fs::read_to_string(dir.join("gnss/trimble-avr.txt")).expect("read");
    let mut kinds = Vec::new();
    for line in text.lines().filter(|l| l.starts_with('$')) {
        let s = parse_sentence(line).unwrap_or_else(|e| panic!("{line}: {e}"));
        kinds.push(s.kind().to_string());
        match s {
            Sentence::Avr(a) => {
                assert!(
                    a.yaw_deg.is_some() && a.range_m.is_some() && a.quality == 3,
                    "{a:?}"
                );
                assert!(a.tilt_deg.is_some() != a.roll_deg.is_some(), "{a:?}");
            }
            Sentence::Ggk(g) => {
                assert_eq!(g.alt_hae_m, Some(150.790));
                assert!((g.lat_deg.unwrap_or(0.0) - 50.016_220_640_166_67).abs() < 1e-12);
            }
            other => panic!("unexpected {other:?}"),
        }
        // Any single changed character breaks the checksum (or the framing).
        let body_end = line.find('*').unwrap_or(line.len());
        for pos in 1..body_end {
            let mut bytes = line.as_bytes().to_vec();
            bytes[pos] = if bytes[pos] == b'7' { b'8' } else { b'7' };
            let corrupted = String::from_utf8(bytes).expect("ascii");
            assert!(parse_sentence(&corrupted).is_err(), "{corrupted}");
        }
    }
    assert_eq!(kinds, ["AVR", "AVR", "AVR", "GGK"]);
}
