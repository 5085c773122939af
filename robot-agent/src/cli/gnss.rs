//! `robot-agent gnss`: NMEA-0183 tools.
//!
//! `gnss decode FILE` prints one JSON object per line for every sentence of an NMEA log (lines
//! starting with `#` are comments, blank lines are skipped). A line that does not decode gives
//! `{"line": N, "error": "..."}` and decoding goes on; the exit status is 0 unless the file cannot
//! be read. A summary goes to stderr.

use std::collections::BTreeMap;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

use anyhow::Context;
use common::geo::nmea::{parse_sentence, Sentence};
use serde::Serialize;

/// Arguments of `robot-agent gnss`.
#[derive(Debug, clap::Args)]
pub struct GnssArgs {
    #[command(subcommand)]
    command: GnssCommand,
}

#[derive(Debug, clap::Subcommand)]
enum GnssCommand {
    /// Decode an NMEA-0183 log: one JSON object per sentence on stdout, a summary on stderr.
    Decode {
        /// The log file (one sentence per line; `#` starts a comment line).
        file: PathBuf,
    },
}

/// Runs `robot-agent gnss`.
pub fn run(args: GnssArgs) -> anyhow::Result<()> {
    match args.command {
        GnssCommand::Decode { file } => decode(&file),
    }
}

/// One output line. Field names carry units where they are not degrees (`lat`, `lon` and the
/// attitude angles are degrees, heights metres); absent values are left out, except `time`,
/// which is always there (null when the sentence has none).
#[derive(Debug, Default, Serialize)]
struct Decoded<'a> {
    line: usize,
    sentence: &'a str,
    talker: &'a str,
    time: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    date: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    valid: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lat: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lon: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    alt_msl: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    geoid_sep: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    alt_hae: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    quality: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    satellites: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    hdop: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pdop: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    dop: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    dgps_age_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    dgps_station: Option<u16>,
    #[serde(skip_serializing_if = "Option::is_none")]
    speed_mps: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    track_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    magvar_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mode: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    heading_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    yaw_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    tilt_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    roll_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    range_m: Option<f64>,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    ignored: bool,
}

#[derive(Debug, Serialize)]
struct BadLine {
    line: usize,
    error: String,
}

fn to_json(line: usize, s: &Sentence) -> Decoded<'_> {
    let mut d = Decoded {
        line,
        sentence: s.kind(),
        time: s.time().map(|t| t.to_string()),
        ..Decoded::default()
    };
    match s {
        Sentence::Gga(g) => {
            d.talker = &g.talker;
            d.lat = g.lat_deg;
            d.lon = g.lon_deg;
            d.alt_msl = g.alt_msl_m;
            d.geoid_sep = g.geoid_sep_m;
            d.alt_hae = g.alt_hae_m();
            d.quality = Some(g.quality);
            d.satellites = g.satellites;
            d.hdop = g.hdop;
            d.dgps_age_s = g.dgps_age_s;
            d.dgps_station = g.dgps_station;
        }
        Sentence::Rmc(r) => {
            d.talker = &r.talker;
            d.date = r.date.map(|x| x.to_string());
            d.valid = Some(r.valid);
            d.lat = r.lat_deg;
            d.lon = r.lon_deg;
            d.speed_mps = r.speed_mps;
            d.track_deg = r.track_deg;
            d.magvar_deg = r.magvar_deg;
            d.mode = r.mode.map(String::from);
        }
        Sentence::Hdt(h) => {
            d.talker = &h.talker;
            d.heading_deg = h.heading_deg;
        }
        Sentence::Ths(h) => {
            d.talker = &h.talker;
            d.heading_deg = h.heading_deg;
            d.mode = Some(h.mode.to_string());
        }
        Sentence::Pashr(p) => {
            d.talker = "PASHR";
            d.heading_deg = p.heading_deg;
            d.roll_deg = p.roll_deg;
            d.tilt_deg = p.pitch_deg;
            d.quality = p.gnss_quality;
        }
        Sentence::Zda(z) => {
            d.talker = &z.talker;
            d.date = z.date.map(|x| x.to_string());
        }
        Sentence::Avr(a) => {
            d.talker = "PTNL";
            d.yaw_deg = a.yaw_deg;
            d.tilt_deg = a.tilt_deg;
            d.roll_deg = a.roll_deg;
            d.range_m = a.range_m;
            d.quality = Some(a.quality);
            d.pdop = a.pdop;
            d.satellites = a.satellites;
        }
        Sentence::Ggk(g) => {
            d.talker = "PTNL";
            d.date = g.date.map(|x| x.to_string());
            d.lat = g.lat_deg;
            d.lon = g.lon_deg;
            d.alt_hae = g.alt_hae_m;
            d.quality = Some(g.quality);
            d.satellites = g.satellites;
            d.dop = g.dop;
        }
        Sentence::Other { talker, .. } => {
            d.talker = talker;
            d.ignored = true;
        }
        // `Sentence` is non-exhaustive: a type added later prints at least its name.
        #[allow(unreachable_patterns)]
        _ => d.ignored = true,
    }
    d
}

/// Counts for the stderr summary.
#[derive(Debug, Default, PartialEq)]
struct Summary {
    decoded: usize,
    bad: usize,
    comments: usize,
    per_kind: BTreeMap<String, usize>,
}

/// Decodes a whole log into JSON lines on `out`.
fn decode_bytes(bytes: &[u8], out: &mut impl Write) -> std::io::Result<Summary> {
    let mut summary = Summary::default();
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        // Invalid UTF-8 becomes U+FFFD, which the parser rejects as a bad character.
        let text = String::from_utf8_lossy(raw);
        let line = text.trim();
        if line.is_empty() {
            continue;
        }
        if line.starts_with('#') {
            summary.comments += 1;
            continue;
        }
        let json = match parse_sentence(line) {
            Ok(s) => {
                summary.decoded += 1;
                *summary.per_kind.entry(s.kind().to_string()).or_default() += 1;
                serde_json::to_string(&to_json(i + 1, &s))
            }
            Err(e) => {
                summary.bad += 1;
                serde_json::to_string(&BadLine {
                    line: i + 1,
                    error: e.to_string(),
                })
            }
        }?;
        writeln!(out, "{json}")?;
    }
    out.flush()?;
    Ok(summary)
}

fn decode(file: &std::path::Path) -> anyhow::Result<()> {
    let bytes = std::fs::read(file).with_context(|| format!("cannot read {}", file.display()))?;
    let stdout = std::io::stdout();
    let mut out = BufWriter::new(stdout.lock());
    let summary = match decode_bytes(&bytes, &mut out) {
        Ok(s) => s,
        // A closed pipe (`| head`) is the reader's choice, not a failure.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
        Err(e) => return Err(e.into()),
    };
    let kinds: Vec<String> = summary
        .per_kind
        .iter()
        .map(|(k, n)| format!("{k} {n}"))
        .collect();
    eprintln!(
        "{}: decoded {} sentences ({}), {} bad lines, {} comment lines",
        file.display(),
        summary.decoded,
        kinds.join(", "),
        summary.bad,
        summary.comments
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    #[test]
    fn decodes_good_lines_and_reports_bad_ones() {
        let log = b"# comment\n\
$GNGGA,132819.60,4134.49795459,N,09345.03431408,W,2,10,0.9,278.161,M,-31.442,M,6.6,0133*6A\r\n\
$GPHDT,274.07,T*04\n\
\n\
$PTNL,AVR,212604.30,+52.1800,Yaw,,,-0.0807,Roll,12.579,3,1.4,16*21\n\
$GPVTG,,T,,M,,N,,K,N*2C\n\
garbage \xff\n";
        let mut out = Vec::new();
        let summary = decode_bytes(log, &mut out).expect("decode");
        assert_eq!((summary.decoded, summary.bad, summary.comments), (3, 2, 1));
        let lines: Vec<Value> = String::from_utf8(out)
            .expect("utf8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect();
        assert_eq!(lines.len(), 5);
        let gga = &lines[0];
        assert_eq!(gga["sentence"], "GGA");
        assert_eq!(gga["line"], 2);
        assert_eq!(gga["time"], "13:28:19.600");
        assert_eq!(gga["lat"].as_f64(), Some(41.0 + 34.497_954_59 / 60.0));
        assert_eq!(gga["quality"], 2);
        assert!((gga["alt_hae"].as_f64().unwrap_or(0.0) - 246.719).abs() < 1e-9);
        assert_eq!(lines[1]["line"], 3);
        assert!(lines[1]["error"]
            .as_str()
            .unwrap_or("")
            .contains("checksum"));
        assert_eq!(lines[2]["roll_deg"].as_f64(), Some(-0.0807));
        assert!(lines[2].get("tilt_deg").is_none());
        assert_eq!(lines[3]["ignored"], true);
        assert_eq!(lines[4]["line"], 7);
    }

    /// The CLI's JSON carries the library's values (which `common/tests/gnss_logs.rs` checks
    /// against gpsd) for every sentence of every real log, with no bad lines.
    #[test]
    fn real_logs_decode_without_errors() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let dir = root.join("../shared/data/gnss");
        if !dir.is_dir() {
            println!("skipping real_logs_decode_without_errors: ../shared/data is absent");
            return;
        }
        for name in [
            "nmea-rtk.log",
            "hemi.log",
            "cat-ms352.log",
            "trimble-avr.txt",
        ] {
            let bytes = std::fs::read(dir.join(name)).expect("read log");
            let mut out = Vec::new();
            let summary = decode_bytes(&bytes, &mut out).expect("decode");
            assert_eq!(summary.bad, 0, "{name}");
            let text = String::from_utf8(out).expect("utf8");
            let mut compared = 0;
            for json in text.lines() {
                let v: Value = serde_json::from_str(json).expect("json");
                let n = v["line"].as_u64().expect("line") as usize;
                let line = String::from_utf8_lossy(
                    bytes.split(|&b| b == b'\n').nth(n - 1).expect("line n"),
                )
                .into_owned();
                let s = parse_sentence(line.trim()).expect("parses");
                assert_eq!(v["sentence"], s.kind(), "{name}:{n}");
                if let Sentence::Gga(g) = s {
                    for (key, want) in [
                        ("lat", g.lat_deg),
                        ("lon", g.lon_deg),
                        ("alt_hae", g.alt_hae_m()),
                    ] {
                        match (v[key].as_f64(), want) {
                            (Some(got), Some(want)) => {
                                assert!((got - want).abs() <= 1e-12, "{name}:{n} {key}")
                            }
                            (None, None) => {}
                            other => panic!("{name}:{n} {key}: {other:?}"),
                        }
                    }
                    compared += 1;
                }
            }
            assert_eq!(summary.decoded, text.lines().count(), "{name}");
            assert!(compared > 0 || name == "trimble-avr.txt", "{name}");
        }
    }
}
