//! Secure links (issue 17), with real processes on loopback: `operator-station pki` makes a fleet,
//! `operator-station serve --pki` listens on `quic/127.0.0.1:PORT` (mutual TLS over QUIC), robots join with their own
//! certificates (`robot-agent sim --pki`, or the real robot bus with certificates for what a
//! simulated robot cannot do on cue). Intruders are Zenoh sessions of the test itself with no
//! certificate, a certificate of another fleet's CA, or another robot's certificate; each one is
//! also shown to get its link up where it should, so what stops it is the rule under test and not
//! a broken harness.

mod secure_support;
mod station_support;

use std::path::Path;
use std::process::Command;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use common::command::CommandStamper;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, Pose};
use common::security::{CertFiles, FleetDir};
use robot_agent::bus::{BusConfig, BusHandle, ZenohSettings};
use secure_support::{fleet, pki, pose, secure_ep, PosePump};
use serde_json::Value;
use station_support::*;
use support::{bin, free_port, workspace_root};

const LIMIT: Duration = Duration::from_secs(10);
const ROBOT_UP: Duration = Duration::from_secs(40);
const DRIVE: Duration = Duration::from_secs(120);

/// A secure station on `ports.zenoh`.
fn secure_station(ports: Ports, pki_dir: &Path, db: &Path) -> Station {
    Station::start_with(
        ports,
        db,
        &[
            "--pki".into(),
            pki_dir.display().to_string(),
            "--zenoh-listen".into(),
            secure_ep(ports.zenoh),
        ],
    )
}

/// The real robot bus with certificates from `files`, connecting to `connect` and listening on
/// `listen` (so others can link to it directly).
fn secure_bus(id: &str, files: CertFiles, connect: &str, listen: Option<&str>) -> BusHandle {
    let mut cfg = BusConfig::new(RobotId::new(id).expect("robot id"));
    cfg.zenoh = ZenohSettings {
        connect: vec![connect.into()],
        listen: listen.iter().map(|s| s.to_string()).collect(),
        tls: Some(files),
        ..ZenohSettings::default()
    };
    BusHandle::start(cfg).expect("open the secure robot bus")
}

/// The bus is not `Sync` (its command receiver), so the pose thread and the test share it locked.
fn lock(bus: &Mutex<BusHandle>) -> MutexGuard<'_, BusHandle> {
    bus.lock().unwrap_or_else(|p| p.into_inner())
}

fn robot_files(pki_dir: &Path, id: &str) -> CertFiles {
    CertFiles::robot(&FleetDir::new(pki_dir).robot_dir(&RobotId::new(id).unwrap()))
}

fn online(port: u16, robot: &str) -> bool {
    robot_entry(port, robot).is_some_and(|r| r["online"] == true)
}

fn post(port: u16, path: &str, body: &str) -> (u16, String) {
    http(port, "POST", path, body).expect("station answers")
}

#[test]
fn authorised_station_commands_a_secure_robot_and_a_replay_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pki_dir = fleet(dir.path(), "pki", &["r1"]);
    let ports = Ports::new();
    let _station = secure_station(ports, &pki_dir, &dir.path().join("s.db"));
    let r1_port = free_port();
    let mut r1 = Robot::start_with(
        "r1",
        &field_scenario(),
        &secure_ep(ports.zenoh),
        "0,0,0",
        1,
        dir.path(),
        &[
            "--pki".into(),
            pki_dir.join("robots/r1").display().to_string(),
            "--listen".into(),
            secure_ep(r1_port),
        ],
    );
    let up = wait_for(ROBOT_UP, || {
        r1.assert_running();
        robot_entry(ports.http, "r1").is_some_and(|r| r["online"] == true && !r["pose"].is_null())
    });
    assert!(up, "secure robot never came up");

    // An authorised session (the station's certificate) linked to the station and to the robot
    // captures the operator's goal as it goes out.
    let station_files = FleetDir::new(&pki_dir).station();
    let mut eyes = Observer::open(
        &[secure_ep(ports.zenoh), secure_ep(r1_port)],
        Tls::member(&station_files),
        false,
    );
    assert_eq!(eyes.links_after(2, LIMIT), 2, "station-certificate links");
    let rid = RobotId::new("r1").unwrap();
    let capture = std::thread::scope(|s| {
        let h = s.spawn(|| eyes.samples(&keys::key(&rid, Topic::CmdGoal), Duration::from_secs(4)));
        std::thread::sleep(Duration::from_millis(1000));
        let (st, body) = post(ports.http, "/api/robots/r1/goal", r#"{"x": 8, "y": 0}"#);
        assert_eq!(st, 202, "{body}");
        h.join().unwrap()
    });
    assert_eq!(capture.len(), 1, "the goal was captured");
    let t0 = Instant::now();
    let mut last = Value::Null;
    let reached = wait_for(DRIVE, || {
        r1.assert_running();
        last = robot_entry(ports.http, "r1").unwrap_or(Value::Null);
        last["status"]["mission"] == "Reached"
    });
    assert!(
        reached,
        "secure robot did not reach its goal: {}",
        last["status"]
    );
    let (x, y) = (
        last["pose"]["x_m"].as_f64().unwrap(),
        last["pose"]["y_m"].as_f64().unwrap(),
    );
    println!(
        "secure goal (8, 0) reached in {:.1} s at ({x:.2}, {y:.2})",
        t0.elapsed().as_secs_f64()
    );
    assert!((x - 8.0).hypot(y) <= 0.5);

    // A keep-out zone drawn at the station reaches the secure robot (the zone set is not a
    // command, so it has its own rules on both sessions).
    let datum = robot_entry(ports.http, "r1").unwrap()["datum_id"]
        .as_str()
        .unwrap()
        .to_string();
    let fc = r#"{"type":"FeatureCollection","features":[{"type":"Feature","properties":{"kind":"keep_out","name":"pond"},"geometry":{"type":"Polygon","coordinates":[[[20,20],[24,20],[24,24],[20,24],[20,20]]]}}]}"#;
    let (st, body) = post(
        ports.http,
        &format!("/api/zones?frame=map&datum_id={datum}"),
        fc,
    );
    assert_eq!(st, 201, "{body}");
    let zoned = wait_for(LIMIT, || {
        robot_entry(ports.http, "r1")
            .is_some_and(|r| r["status"]["zones_version"].as_u64() > Some(0))
    });
    assert!(
        zoned,
        "zones never reached the secure robot: {}",
        robot_entry(ports.http, "r1").unwrap()["status"]
    );

    // The operator stops it; the captured goal, sent again over the authorised link straight to
    // the robot, is refused and counted: the stopped robot stays stopped.
    let (st, _) = post(ports.http, "/api/robots/r1/stop", "{}");
    assert_eq!(st, 202);
    assert!(wait_for(LIMIT, || robot_entry(ports.http, "r1")
        .is_some_and(|r| r["status"]["mission"] == "Stopped")));
    eyes.put(&capture[0].key, capture[0].payload.clone());
    let counted = wait_for(LIMIT, || {
        robot_entry(ports.http, "r1").is_some_and(|r| r["status"]["commands_replayed"] == 1)
    });
    let s = robot_entry(ports.http, "r1").unwrap()["status"].clone();
    assert!(counted, "replay not counted: {s}");
    std::thread::sleep(Duration::from_secs(2));
    let s = robot_entry(ports.http, "r1").unwrap()["status"].clone();
    assert_eq!(s["mission"], "Stopped", "{s}");
    assert!(
        s["last_error"].as_str().unwrap_or("").contains("replay"),
        "{s}"
    );
    println!("replayed goal refused: {}", s["last_error"]);
}

#[test]
fn strangers_cannot_connect_and_another_robot_can_neither_command_nor_read_nor_impersonate() {
    let dir = tempfile::tempdir().unwrap();
    let pki_dir = fleet(dir.path(), "pki", &["r1", "r2"]);
    let other = fleet(dir.path(), "other-fleet", &[]);
    let ports = Ports::new();
    let station = secure_station(ports, &pki_dir, &dir.path().join("s.db"));
    let r1_port = free_port();
    let bus = Arc::new(Mutex::new(secure_bus(
        "r1",
        robot_files(&pki_dir, "r1"),
        &secure_ep(ports.zenoh),
        Some(&secure_ep(r1_port)),
    )));
    let pump_bus = bus.clone();
    let _pump = PosePump::start(1.0, move || move |p: &Pose| lock(&pump_bus).publish_pose(p));
    assert!(wait_for(LIMIT, || online(ports.http, "r1")), "r1 online");
    let targets = [secure_ep(ports.zenoh), secure_ep(r1_port)];
    let ca = FleetDir::new(&pki_dir).ca_cert();

    // No certificate at all, over TLS and over plain TCP to the TLS ports: no link.
    let mut none = Observer::open(
        &targets,
        Tls {
            ca: Some(&ca),
            identity: None,
        },
        false,
    );
    assert_eq!(
        none.links_after(1, Duration::from_secs(3)),
        0,
        "no-cert TLS client linked"
    );
    assert!(none
        .samples("terranav/**", Duration::from_secs(1))
        .is_empty());
    let plain: Vec<String> = [ports.zenoh, r1_port]
        .iter()
        .map(|p| format!("tcp/127.0.0.1:{p}"))
        .collect();
    let plain = Observer::open(&plain, Tls::default(), false);
    assert_eq!(
        plain.links_after(1, Duration::from_secs(2)),
        0,
        "plain TCP linked"
    );

    // The station's name, but from another fleet's CA: no link (the CA certificate is public,
    // so the intruder trusts ours; its own certificate does not chain to it).
    let foreign = FleetDir::new(&other).station();
    let forged = Observer::open(
        &targets,
        Tls {
            ca: Some(&ca),
            identity: Some((&foreign.cert, &foreign.key)),
        },
        false,
    );
    assert_eq!(
        forged.links_after(1, Duration::from_secs(3)),
        0,
        "foreign CA linked"
    );
    forged.put(
        &keys::key(&RobotId::new("r1").unwrap(), Topic::CmdGoal),
        forged.goal_bytes(77, 3.0, 0.0),
    );

    // Robot r2's own certificate: its links come up (it is of this fleet) ...
    let r2 = robot_files(&pki_dir, "r2");
    let mut thief = Observer::open(&targets, Tls::member(&r2), false);
    assert_eq!(
        thief.links_after(2, LIMIT),
        2,
        "r2's links to station and r1"
    );
    // ... but it reads nothing of r1 (r1 publishes 10 poses a second),
    let seen = thief.samples("terranav/**", Duration::from_secs(3));
    assert!(
        seen.is_empty(),
        "r2 read {} samples: {:?}",
        seen.len(),
        seen.first().map(|s| &s.key)
    );
    // cannot command r1 (straight to r1's listener, and via the station),
    let r1 = RobotId::new("r1").unwrap();
    thief.put(
        &keys::key(&r1, Topic::CmdGoal),
        thief.goal_bytes(77, 3.0, 0.0),
    );
    let stop = msg::encode_cmd(
        CommandStamper::new(99).next(now_ms()),
        &msg::StopCmd::default(),
    );
    thief.put(&keys::key(&r1, Topic::CmdStop), stop);
    // cannot publish under r1's prefix,
    thief.put(
        &keys::key(&r1, Topic::Pose),
        msg::encode(&pose(9999, 777.0)),
    );
    // and may publish under its own.
    let r2id = RobotId::new("r2").unwrap();
    thief.put(&keys::key(&r2id, Topic::Pose), msg::encode(&pose(1, 42.0)));
    assert!(
        wait_for(LIMIT, || robot_entry(ports.http, "r2")
            .is_some_and(|r| r["pose"]["x_m"] == 42.0)),
        "r2's own pose reached the station"
    );
    std::thread::sleep(Duration::from_secs(2));
    let mut got = Vec::new();
    while let Some(c) = lock(&bus).try_recv() {
        got.push(c);
    }
    assert!(got.is_empty(), "r1 received {got:?}");
    assert_eq!(
        lock(&bus).counters().commands_refused,
        0,
        "dropped by the rules, before the robot's checks"
    );
    let e = robot_entry(ports.http, "r1").unwrap();
    assert_eq!(
        e["pose"]["x_m"], 1.0,
        "a forged pose reached the station: {}",
        e["pose"]
    );
    let log = station.log_text();
    assert!(!log.contains("panicked"), "{log}");
}

#[test]
fn revoked_robot_is_refused_at_its_next_connection() {
    let dir = tempfile::tempdir().unwrap();
    let pki_dir = fleet(dir.path(), "pki", &["r1", "r2"]);
    let ps = pki_dir.display().to_string();
    let ports = Ports::new();
    let _station = secure_station(ports, &pki_dir, &dir.path().join("s.db"));
    // A stolen copy of r1's files, taken before the revocation.
    let stolen = dir.path().join("stolen-r1");
    std::fs::create_dir_all(&stolen).unwrap();
    for f in ["ca.crt", "robot.crt", "robot.key"] {
        std::fs::copy(pki_dir.join("robots/r1").join(f), stolen.join(f)).unwrap();
    }
    let ep = secure_ep(ports.zenoh);
    let r1 = secure_bus("r1", CertFiles::robot(&stolen), &ep, None);
    let r2 = secure_bus("r2", robot_files(&pki_dir, "r2"), &ep, None);
    assert!(wait_for(LIMIT, || online(ports.http, "r1")
        && online(ports.http, "r2")));

    let rev = pki(&["revoke", "--robot", "r1", "--dir", &ps]);
    assert_eq!(rev["revoked"], 1, "{rev}");
    let t0 = Instant::now();
    assert!(
        wait_for(LIMIT, || !online(ports.http, "r1")),
        "the running station dropped the revoked robot"
    );
    println!(
        "revoked robot offline after {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    // Its links keep coming back (it retries every second) and are refused each time; r2, still
    // admitted, is back at once.
    assert!(wait_for(LIMIT, || online(ports.http, "r2")), "r2 back");
    std::thread::sleep(Duration::from_secs(4));
    assert!(!online(ports.http, "r1"), "revoked robot back online");
    // A restart of the revoked robot is a next connection too.
    drop(r1);
    let r1 = secure_bus("r1", CertFiles::robot(&stolen), &ep, None);
    std::thread::sleep(Duration::from_secs(4));
    assert!(
        !online(ports.http, "r1"),
        "restarted revoked robot admitted"
    );
    // The operator issues r1 anew (a replacement unit): the new certificate is admitted, the
    // stolen one still is not.
    let again = pki(&["issue", "--robot", "r1", "--dir", &ps]);
    assert_eq!(again["serial"], 2, "{again}");
    assert!(
        wait_for(LIMIT, || online(ports.http, "r2")),
        "r2 back after the reload for the new issue"
    );
    std::thread::sleep(Duration::from_secs(3));
    assert!(
        !online(ports.http, "r1"),
        "stolen certificate admitted after the re-issue"
    );
    drop(r1);
    let _new = secure_bus("r1", robot_files(&pki_dir, "r1"), &ep, None);
    assert!(
        wait_for(LIMIT, || online(ports.http, "r1")),
        "the re-issued certificate is admitted"
    );
    drop(r2);
}

/// Runs a binary that must refuse to start; its stderr.
fn refused(bin_name: &str, args: &[&str]) -> String {
    let mut child = Command::new(bin(bin_name))
        .current_dir(workspace_root())
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{bin_name} {args:?} did not refuse to start");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = child.wait_with_output().unwrap();
    assert!(!status.success(), "{bin_name} {args:?} started");
    String::from_utf8_lossy(&out.stderr).to_string()
}

#[test]
fn plain_links_off_loopback_are_refused_at_start_with_how_to_set_up() {
    let port = free_port().to_string();
    let scen = field_scenario().display().to_string();
    let e = refused(
        "operator-station",
        &[
            "serve",
            "--port",
            &port,
            "--zenoh-listen",
            "tcp/0.0.0.0:7447",
        ],
    );
    assert!(
        e.contains("refusing to listen on tcp/0.0.0.0:7447")
            && e.contains("operator-station pki init")
            && e.contains("--pki"),
        "{e}"
    );
    let e = refused(
        "operator-station",
        &[
            "goal",
            "--robot",
            "r1",
            "--xy",
            "1,1",
            "--connect",
            "tcp/192.0.2.1:7447",
        ],
    );
    assert!(
        e.contains("refusing to connect to tcp/192.0.2.1:7447"),
        "{e}"
    );
    let e = refused(
        "robot-agent",
        &[
            "sim",
            "--scenario",
            &scen,
            "--robot",
            "r1",
            "--connect",
            "tcp/192.0.2.1:7447",
        ],
    );
    assert!(
        e.contains("refusing to connect to tcp/192.0.2.1:7447") && e.contains("pki issue"),
        "{e}"
    );
    let e = refused(
        "robot-agent",
        &[
            "sim",
            "--scenario",
            &scen,
            "--robot",
            "r1",
            "--listen",
            "tcp/0.0.0.0:0",
        ],
    );
    assert!(e.contains("refusing to listen on tcp/0.0.0.0:0"), "{e}");
    // The HTTP API off loopback: the token alone is not enough, it needs TLS.
    let e = refused(
        "operator-station",
        &[
            "serve",
            "--listen",
            &format!("0.0.0.0:{port}"),
            "--token",
            "t",
        ],
    );
    assert!(e.contains("without TLS") && e.contains("--tls-cert"), "{e}");
    // A robot certificate given to another robot id is refused before anything starts.
    let dir = tempfile::tempdir().unwrap();
    let pki_dir = fleet(dir.path(), "pki", &["r1"]);
    let e = refused(
        "robot-agent",
        &[
            "sim",
            "--scenario",
            &scen,
            "--robot",
            "r9",
            "--pki",
            &pki_dir.join("robots/r1").display().to_string(),
        ],
    );
    assert!(e.contains("issued to robot r1, not r9"), "{e}");
}

#[test]
fn http_api_over_tls_keeps_its_token() {
    let dir = tempfile::tempdir().unwrap();
    let pki_dir = fleet(dir.path(), "pki", &[]);
    let s = FleetDir::new(&pki_dir).station();
    let ports = Ports::new();
    let log = dir.path().join("https.log");
    let _station = support::KillOnDrop::spawn(
        Command::new(bin("operator-station"))
            .args([
                "serve",
                "--port",
                &ports.http.to_string(),
                "--token",
                "sesame",
            ])
            .args(["--pki", &pki_dir.display().to_string()])
            .args(["--zenoh-listen", &secure_ep(ports.zenoh)])
            .arg("--tls-cert")
            .arg(&s.cert)
            .arg("--tls-key")
            .arg(&s.key)
            .arg("--db")
            .arg(dir.path().join("s.db"))
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap()),
    )
    .unwrap();
    let get = |path: &str| https(ports.http, &s.ca, path);
    assert!(
        wait_for(Duration::from_secs(20), || get("/api/health?token=sesame")
            .is_some()),
        "no HTTPS: {}",
        tail(&log, 20)
    );
    let (st, body) = get("/api/health?token=sesame").unwrap();
    assert_eq!(st, 200, "{body}");
    assert!(body.contains("\"ok\":true"), "{body}");
    assert_eq!(
        get("/api/health").unwrap().0,
        401,
        "the token is still required"
    );
    // The UI's WebSocket upgrades over TLS.
    let (st, _) = https_raw(
        ports.http,
        &s.ca,
        "GET /api/ws?token=sesame HTTP/1.1\r\nHost: localhost\r\nConnection: Upgrade\r\n\
         Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n",
    )
    .unwrap();
    assert_eq!(st, 101);
    // Plain HTTP on the HTTPS port gets no answer.
    assert!(http(ports.http, "GET", "/api/health?token=sesame", "").is_none_or(|(st, _)| st != 200));
}

/// GET over TLS, trusting `ca`, by the name `localhost`.
fn https(port: u16, ca: &Path, path: &str) -> Option<(u16, String)> {
    https_raw(
        port,
        ca,
        &format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"),
    )
}

fn https_raw(port: u16, ca: &Path, request: &str) -> Option<(u16, String)> {
    use rustls::pki_types::pem::PemObject;
    use std::io::{Read, Write};
    let mut roots = rustls::RootCertStore::empty();
    for c in rustls::pki_types::CertificateDer::pem_file_iter(ca).ok()? {
        roots.add(c.ok()?).ok()?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .ok()?
        .with_root_certificates(roots)
        .with_no_client_auth();
    let name = rustls::pki_types::ServerName::try_from("localhost").ok()?;
    let conn = rustls::ClientConnection::new(Arc::new(config), name).ok()?;
    let tcp = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    tcp.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    let mut tls = rustls::StreamOwned::new(conn, tcp);
    tls.write_all(request.as_bytes()).ok()?;
    let mut buf = Vec::new();
    // A 101 keeps the connection open: read what came until the timeout.
    let mut chunk = [0u8; 4096];
    loop {
        match tls.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => {
                buf.extend_from_slice(&chunk[..n]);
                if request.contains("Upgrade: websocket")
                    && buf.windows(4).any(|w| w == b"\r\n\r\n")
                {
                    break;
                }
            }
            Err(_) => break,
        }
    }
    let text = String::from_utf8_lossy(&buf).to_string();
    let status: u16 = text.split_whitespace().nth(1)?.parse().ok()?;
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    Some((status, body))
}
