//! GNSS sources against real programs: Debian's gpsd reading a recorded receiver log over
//! `tcp://` and serving it to our gpsd client (fixes compared with gpsd's own regression `.chk`
//! file) and to `robot-agent run --gnss gpsd:...` (the fixes the agent took, compared with the
//! `.chk` files of all three logs), and NMEA on a serial port (a pseudo-terminal pair made by
//! socat).
//!
//! Without gpsd or socat a test prints a notice and passes, except under CI=true (scripts/test.sh
//! installs both), where it fails.

use std::collections::BTreeMap;
use std::io::Write;
use std::process::{Command, Stdio};
use std::time::Duration;

use io::gnss::{GnssEvent, GpsdClient, LineSource, NmeaDecoder};
use io::sample::FixStatus;
use io::source::SourceSpec;
use serde_json::Value;
use std::io::BufRead;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use support::{bin, workspace_root, KillOnDrop};
use tokio::io::AsyncWriteExt;

fn have(program: &str) -> bool {
    let ok = Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "{program} is required in CI (scripts/test.sh installs it)"
        );
        eprintln!("SKIP: {program} not installed (apt-get install {program})");
    }
    ok
}

async fn within<T>(what: &str, f: impl std::future::Future<Output = T>) -> T {
    tokio::time::timeout(Duration::from_secs(60), f)
        .await
        .unwrap_or_else(|_| panic!("{what}: nothing within 60 s"))
}

/// The timed TPV fixes of a gpsd `.chk` file: time -> (lat, lon, altHAE).
fn chk_fixes(text: &str) -> BTreeMap<String, (f64, f64, Option<f64>)> {
    text.lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["class"] == "TPV" && v["time"].is_string() && v["lat"].is_number())
        .map(|v| {
            (
                v["time"].as_str().unwrap().to_owned(),
                (
                    v["lat"].as_f64().unwrap(),
                    v["lon"].as_f64().unwrap(),
                    v["altHAE"].as_f64(),
                ),
            )
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn real_gpsd_serves_the_logged_fixes() {
    if !have("gpsd") {
        return;
    }
    let Some(data) = support::shared_data("the gpsd test") else {
        return;
    };
    let dir = data.join("gnss");
    let log = std::fs::read_to_string(dir.join("nmea-rtk.log")).unwrap();
    let want = chk_fixes(&std::fs::read_to_string(dir.join("nmea-rtk.log.chk")).unwrap());
    assert!(want.len() > 50, "chk has {} timed fixes", want.len());
    let lines: Vec<String> = log
        .lines()
        .filter(|l| l.starts_with('$'))
        .map(str::to_owned)
        .collect();

    // The receiver: a TCP server sending the log over and over (gpsd may start reading before
    // our client watches; repeating means every epoch comes past a watching client).
    let feed = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let feed_port = feed.local_addr().unwrap().port();
    let server = tokio::spawn(async move {
        while let Ok((mut s, _)) = feed.accept().await {
            let lines = lines.clone();
            tokio::spawn(async move {
                loop {
                    for l in &lines {
                        if s.write_all(format!("{l}\r\n").as_bytes()).await.is_err() {
                            return;
                        }
                        tokio::time::sleep(Duration::from_millis(2)).await;
                    }
                }
            });
        }
    });

    let gpsd_port = support::free_port();
    let tmp = tempfile::tempdir().unwrap();
    let _gpsd = KillOnDrop::spawn(
        Command::new("gpsd")
            .args(["-N", "-n", "-G", "-S", &gpsd_port.to_string(), "-F"])
            .arg(tmp.path().join("gpsd.sock"))
            .arg(format!("tcp://127.0.0.1:{feed_port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    )
    .unwrap();

    let spec = SourceSpec::parse(&format!("gpsd:127.0.0.1:{gpsd_port}")).unwrap();
    let SourceSpec::Gpsd { host, port } = spec else {
        unreachable!()
    };
    let mut client = within("connect to gpsd", async {
        loop {
            match GpsdClient::connect(&host, port).await {
                Ok(c) => break c,
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
    })
    .await;

    // Collect fixes until most of the chk's epochs were seen (gpsd reports per epoch; the chk
    // was made by gpsfake's pacing, so an epoch or two may differ at the ends).
    let mut seen: BTreeMap<String, (f64, f64, f64)> = BTreeMap::new();
    let need = want.len() * 9 / 10;
    within("fixes from gpsd", async {
        while seen.keys().filter(|t| want.contains_key(*t)).count() < need {
            let Some(GnssEvent::Fix(f)) = client.next().await.unwrap() else {
                continue;
            };
            if f.status == FixStatus::NoFix {
                continue;
            }
            seen.insert(iso(f.stamp_s), (f.lat_deg, f.lon_deg, f.alt_m));
        }
    })
    .await;
    let mut compared = 0;
    for (t, (lat, lon, alt)) in &seen {
        let Some((wlat, wlon, walt)) = want.get(t) else {
            continue;
        };
        assert!(
            (lat - wlat).abs() < 1e-9 && (lon - wlon).abs() < 1e-9,
            "{t}: ({lat}, {lon}) vs chk ({wlat}, {wlon})"
        );
        if let Some(walt) = walt {
            assert!((alt - walt).abs() < 1e-3, "{t}: altHAE {alt} vs chk {walt}");
        }
        compared += 1;
    }
    assert!(
        compared >= need,
        "compared {compared} of {} chk fixes",
        want.len()
    );
    assert_eq!(
        client.refused, 0,
        "gpsd lines refused: {:?}",
        client.last_error
    );
    server.abort();
}

/// Unix seconds -> gpsd's `YYYY-MM-DDTHH:MM:SS.sssZ`.
fn iso(t: f64) -> String {
    let ms = (t * 1000.0).round() as i64;
    let (days, rem) = (ms.div_euclid(86_400_000), ms.rem_euclid(86_400_000));
    // Civil from days (Howard Hinnant).
    let z = days + 719468;
    let era = z.div_euclid(146097);
    let doe = z - era * 146097;
    let yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{:03}Z",
        rem / 3_600_000,
        rem / 60_000 % 60,
        rem / 1000 % 60,
        rem % 1000
    )
}

/// One positioned TPV of a `.chk`: what gpsd decoded from the receiver.
#[derive(Clone, Debug)]
struct ChkFix {
    lat: f64,
    lon: f64,
    alt_hae: Option<f64>,
    mode: u64,
    /// gpsd's status (absent: a plain fix, 1).
    status: u64,
}

fn chk_positions(text: &str) -> Vec<ChkFix> {
    text.lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|v| v["class"] == "TPV" && v["lat"].is_number() && v["mode"].as_u64() >= Some(2))
        .map(|v| ChkFix {
            lat: v["lat"].as_f64().unwrap(),
            lon: v["lon"].as_f64().unwrap(),
            alt_hae: v["altHAE"].as_f64(),
            mode: v["mode"].as_u64().unwrap(),
            status: v["status"].as_u64().unwrap_or(1),
        })
        .collect()
}

/// gpsd's TPV status from a GGA quality (how the agent reports its fixes).
fn gpsd_status(quality: u64) -> u64 {
    match quality {
        2 => 2,
        4 => 3,
        5 => 4,
        6 => 5,
        _ => 1,
    }
}

/// A TCP server sending `lines` over and over, 2 ms apart, to whoever connects (gpsd).
fn nmea_feed(lines: Vec<String>, stop: Arc<AtomicBool>) -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(mut s) = conn else { return };
            let (lines, stop) = (lines.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    for l in &lines {
                        if s.write_all(format!("{l}\r\n").as_bytes()).is_err()
                            || stop.load(Ordering::Relaxed)
                        {
                            return;
                        }
                        std::thread::sleep(Duration::from_millis(2));
                    }
                }
            });
        }
    });
    port
}

/// gpsd reads `log` from a TCP feed; `robot-agent run --no-lidar --gnss gpsd:...
/// --print-fixes` reads gpsd. Every fix the agent took is one of the `.chk`'s with the same
/// position (1e-9 deg), height (1 mm), mode and status, and it took nine in ten of them.
fn gpsd_run_matches_chk(dir: &std::path::Path, log: &str) {
    let text = std::fs::read_to_string(dir.join(log)).unwrap();
    let want = chk_positions(&std::fs::read_to_string(dir.join(format!("{log}.chk"))).unwrap());
    assert!(!want.is_empty(), "{log}: no positioned TPV in the chk");
    let lines: Vec<String> = text
        .lines()
        .filter(|l| l.starts_with('$'))
        .map(str::to_owned)
        .collect();
    let stop = Arc::new(AtomicBool::new(false));
    let feed_port = nmea_feed(lines, stop.clone());
    let gpsd_port = support::free_port();
    let tmp = tempfile::tempdir().unwrap();
    let _gpsd = KillOnDrop::spawn(
        Command::new("gpsd")
            .args(["-N", "-n", "-G", "-S", &gpsd_port.to_string(), "-F"])
            .arg(tmp.path().join("gpsd.sock"))
            .arg(format!("tcp://127.0.0.1:{feed_port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    )
    .unwrap();
    let run_log = tmp.path().join("run.log");
    let mut run = KillOnDrop::spawn(
        Command::new(bin("robot-agent"))
            .current_dir(workspace_root())
            .args([
                "run",
                "--robot",
                "gps-1",
                "--connect",
                &format!("tcp/127.0.0.1:{}", support::free_port()),
                "--no-lidar",
                "--gnss",
                &format!("gpsd:127.0.0.1:{gpsd_port}"),
                "--odom",
                "",
                "--imu",
                "",
                "--print-fixes",
            ])
            .env("RUST_LOG", "info,zenoh=warn")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&run_log).unwrap()),
    )
    .unwrap();
    let out = run.0.stdout.take().unwrap();
    let got: Arc<Mutex<Vec<Value>>> = Arc::default();
    let sink = got.clone();
    let reader = std::thread::spawn(move || {
        let mut last = String::new();
        for l in std::io::BufReader::new(out).lines().map_while(Result::ok) {
            if let Ok(v) = serde_json::from_str::<Value>(&l) {
                if v.get("fix").is_some() {
                    sink.lock().unwrap().push(v["fix"].clone());
                    continue;
                }
            }
            last = l;
        }
        last
    });
    // Every fix taken must be in the chk; most of the chk must be taken.
    let matches = |f: &Value, c: &ChkFix| {
        (f["lat_deg"].as_f64().unwrap() - c.lat).abs() < 1e-9
            && (f["lon_deg"].as_f64().unwrap() - c.lon).abs() < 1e-9
    };
    let need = want.len() * 9 / 10;
    let covered = |got: &[Value]| {
        want.iter()
            .filter(|c| got.iter().any(|f| matches(f, c)))
            .count()
    };
    let t0 = std::time::Instant::now();
    while covered(&got.lock().unwrap()) < need && t0.elapsed() < Duration::from_secs(60) {
        if let Ok(Some(s)) = run.0.try_wait() {
            panic!("{log}: run exited {s}");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let pid = run.0.id().to_string();
    Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    let status = run.0.wait().unwrap();
    stop.store(true, Ordering::Relaxed);
    let summary: Value = serde_json::from_str(&reader.join().unwrap()).unwrap_or(Value::Null);
    let got = got.lock().unwrap().clone();
    let log_tail = std::fs::read_to_string(&run_log).unwrap_or_default();
    assert!(
        status.success(),
        "{log}: run exited {status}
{log_tail}"
    );
    let n_covered = covered(&got);
    println!(
        "{log}: the agent took {} fixes, covering {n_covered} of the chk's {} positioned TPVs; \
         summary gnss {}",
        got.len(),
        want.len(),
        summary["counts"]["gnss"]
    );
    assert!(
        n_covered >= need,
        "{log}: only {n_covered} of {} chk fixes taken
{log_tail}",
        want.len()
    );
    for f in &got {
        let candidates: Vec<&ChkFix> = want.iter().filter(|c| matches(f, c)).collect();
        assert!(!candidates.is_empty(), "{log}: fix {f} is not in the chk");
        let h = f["h_m"].as_f64().unwrap();
        let mode = if h.is_finite() { 3 } else { 2 };
        let status = gpsd_status(f["quality"].as_u64().unwrap());
        assert!(
            candidates.iter().any(|c| c.mode == mode
                && c.status == status
                && c.alt_hae.is_none_or(|a| (a - h).abs() < 1e-3)),
            "{log}: fix {f} (mode {mode}, status {status}) differs from the chk's {candidates:?}"
        );
    }
    let taken = summary["counts"]["gnss"]["fixes"].as_u64().unwrap_or(0);
    assert_eq!(taken, got.len() as u64, "{log}: summary {summary}");
    assert_eq!(
        summary["counts"]["undecodable"],
        serde_json::json!([]),
        "{log}: gpsd lines refused: {summary}"
    );
}

#[test]
fn gpsd_through_robot_agent_run_gives_the_chk_fixes() {
    if !have("gpsd") {
        return;
    }
    let Some(data) = support::shared_data("the gpsd run test") else {
        return;
    };
    for log in ["nmea-rtk.log", "hemi.log", "cat-ms352.log"] {
        gpsd_run_matches_chk(&data.join("gnss"), log);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmea_from_a_serial_port() {
    if !have("socat") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (gnss, feed) = (tmp.path().join("gnss"), tmp.path().join("feed"));
    let _socat = KillOnDrop::spawn(
        Command::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", gnss.display()))
            .arg(format!("pty,raw,echo=0,link={}", feed.display()))
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    )
    .unwrap();
    within("socat ptys", async {
        while !(gnss.exists() && feed.exists()) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    let spec = SourceSpec::parse(&format!("nmea-serial:{}@115200", gnss.display())).unwrap();
    let SourceSpec::NmeaSerial { device, baud } = spec else {
        unreachable!()
    };
    let mut src = LineSource::serial(&device, baud).unwrap();
    let mut w = std::fs::OpenOptions::new().write(true).open(&feed).unwrap();
    let gga =
        common::geo::nmea::frame("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
    // A half line first, then its rest and a good line: the reader must join across reads.
    w.write_all(b"$GPGGA,12").unwrap();
    w.flush().unwrap();
    w.write_all(b"3519,garbage*00\r\n").unwrap();
    w.write_all(format!("{gga}\r\n").as_bytes()).unwrap();
    w.flush().unwrap();
    let mut dec = NmeaDecoder::new();
    let fix = within("serial NMEA", async {
        loop {
            let line = src.next_line().await.unwrap().expect("port closed");
            if let Some(GnssEvent::Fix(f)) = dec.feed(&line, 0.0) {
                break f;
            }
        }
    })
    .await;
    assert_eq!(fix.status, FixStatus::Fix);
    assert!((fix.lat_deg - (48.0 + 7.038 / 60.0)).abs() < 1e-12);
    assert_eq!(dec.stats().refused_total(), 1);
}
