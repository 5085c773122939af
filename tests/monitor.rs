//! A read-only monitor station (issue 20), with real processes on loopback: a fleet PKI with a
//! robot and a monitor (`operator-station pki add-monitor`), a secure station, the real robot bus
//! (synthetic robot, so the test sees every command that reaches it), and `operator-station serve
//! --monitor` as a Zenoh client of the station. The monitor watches the robot (poses, tiles,
//! merged map); its API refuses commands with a stable code; a goal put on the Zenoh key with the
//! monitor's certificate, through the station or straight to the robot, never reaches the robot,
//! while the same put with the station's certificate does; a revoked monitor sees nothing more.

mod station_support;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use common::command::CommandStamper;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, GoalCmd, GoalTarget, Pose};
use common::security::{CertFiles, FleetDir};
use robot_agent::bus::{BusConfig, BusHandle, Command as BusCommand, ZenohMode, ZenohSettings};
use serde_json::Value;
use station_support::*;
use support::{bin, free_port, KillOnDrop};

const LIMIT: Duration = Duration::from_secs(20);

/// The secure endpoint of a loopback port: the one place the scheme is chosen.
fn secure_ep(port: u16) -> String {
    format!("{}/127.0.0.1:{port}", common::security::SECURE_SCHEME)
}

/// `operator-station pki ARGS`, asserting success; its JSON line.
fn pki(args: &[&str]) -> Value {
    let out = Command::new(bin("operator-station"))
        .arg("pki")
        .args(args)
        .output()
        .expect("run operator-station pki");
    assert!(
        out.status.success(),
        "pki {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

fn pose(seq: u32, x_m: f64) -> Pose {
    Pose {
        t_unix_ms: now_ms(),
        seq,
        x_m,
        y_m: 0.0,
        z_m: 0.0,
        yaw_rad: 0.0,
        pitch_rad: 0.0,
        roll_rad: 0.0,
        v_mps: 0.0,
        omega_rps: 0.0,
        fix: Default::default(),
        lat_lon_deg: None,
    }
}

/// A Zenoh session of the test with a fleet certificate, as a client (served by what it connects
/// to) or a peer (linked straight to each endpoint).
struct Raw {
    rt: tokio::runtime::Runtime,
    session: zenoh::Session,
}

impl Raw {
    fn open(connect: &[String], files: &CertFiles, client: bool) -> Raw {
        Self::try_open(connect, files, client).expect("open zenoh")
    }

    /// As [`Raw::open`]; a client that cannot link fails to open.
    fn try_open(connect: &[String], files: &CertFiles, client: bool) -> Result<Raw, String> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        let mut c = operator_station::station::zenoh_config(None, None, &[], connect)
            .expect("zenoh config");
        let mut set = |k: &str, v: String| c.insert_json5(k, &v).expect(k);
        set("listen/endpoints", "[]".into());
        if client {
            set("mode", "\"client\"".into());
        }
        let path = |p: &Path| serde_json::to_string(&p.display().to_string()).unwrap();
        set("transport/link/tls/root_ca_certificate", path(&files.ca));
        set("transport/link/tls/enable_mtls", "true".into());
        set("transport/link/tls/connect_certificate", path(&files.cert));
        set("transport/link/tls/connect_private_key", path(&files.key));
        let session = rt
            .block_on(async { zenoh::open(c).await })
            .map_err(|e| e.to_string())?;
        Ok(Raw { rt, session })
    }

    /// Links (peers or routers) up after up to `wait`.
    fn links_after(&self, want: usize, wait: Duration) -> usize {
        let t0 = Instant::now();
        loop {
            let n = self.rt.block_on(async {
                let info = self.session.info();
                info.peers_zid().await.count() + info.routers_zid().await.count()
            });
            if n >= want || t0.elapsed() > wait {
                return n;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Samples under `terranav/**` received within `d`, calling `poke` every 100 ms meanwhile.
    fn samples_while(&self, d: Duration, mut poke: impl FnMut()) -> usize {
        let sub = self
            .rt
            .block_on(async { self.session.declare_subscriber("terranav/**").await })
            .expect("subscribe");
        let end = Instant::now() + d;
        while Instant::now() < end {
            poke();
            std::thread::sleep(Duration::from_millis(100));
        }
        let mut n = 0;
        while let Ok(Some(_)) = sub.try_recv() {
            n += 1;
        }
        n
    }

    /// Puts a fresh goal, stamped by this session, on `robot`'s goal key.
    fn put_goal(&self, robot: &RobotId, goal_id: u32) {
        let st = CommandStamper::new(operator_station::station::sender_id(&self.session));
        let g = GoalCmd {
            goal_id,
            target: GoalTarget::Map { x_m: 3.0, y_m: 0.0 },
            tolerance_m: 0.0,
        };
        let bytes = msg::encode_cmd(st.next(now_ms()), &g);
        self.rt.block_on(async {
            self.session
                .put(keys::key(robot, Topic::CmdGoal), bytes)
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .await
                .expect("put")
        });
    }
}

impl Drop for Raw {
    fn drop(&mut self) {
        let s = self.session.clone();
        let _ = self.rt.block_on(async { s.close().await });
    }
}

/// The goals (by id) that reached the robot bus within `d`; zone sets and the like are skipped.
fn goals_within(bus: &BusHandle, d: Duration) -> Vec<u32> {
    let end = Instant::now() + d;
    let mut out = Vec::new();
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        match bus.recv_timeout(left) {
            Some(BusCommand::Goal(g)) => out.push(g.goal_id),
            Some(_) => {}
            None => break,
        }
    }
    out
}

fn health(port: u16) -> Value {
    get_json(port, "/api/health")
}

#[test]
fn a_monitor_watches_the_fleet_and_cannot_command_it() {
    let t_start = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let pki_dir: PathBuf = dir.path().join("pki");
    let ps = pki_dir.to_str().unwrap();
    pki(&["init", "--dir", ps]);
    pki(&["issue", "--robot", "r1", "--dir", ps]);
    let m = pki(&["add-monitor", "--name", "m1", "--dir", ps]);
    assert_eq!(m["cn"], "terranav:monitor:m1:1");
    let fleet = FleetDir::new(&pki_dir);
    let monitor_files = CertFiles::monitor(&fleet.monitor_dir("m1"));

    // The station, and the robot (the real robot bus, TLS with its own certificate, also
    // listening so a peer can link to it directly).
    let sp = Ports::new();
    let _station = Station::start_with(
        sp,
        &dir.path().join("s.db"),
        &[
            "--pki".into(),
            ps.into(),
            "--zenoh-listen".into(),
            secure_ep(sp.zenoh),
        ],
    );
    let r1 = RobotId::new("r1").unwrap();
    let r1_port = free_port();
    let mut cfg = BusConfig::new(r1.clone());
    cfg.zenoh = ZenohSettings {
        connect: vec![secure_ep(sp.zenoh)],
        listen: vec![secure_ep(r1_port)],
        tls: Some(CertFiles::robot(&fleet.robot_dir(&r1))),
        ..ZenohSettings::default()
    };
    let bus = BusHandle::start(cfg).expect("open the secure robot bus");
    bus.publish_session(&session("r1", now_ms()));
    publish_tiles(&bus, 0..3, 100);
    bus.publish_pose(&pose(1, 1.0));
    assert!(
        wait_for(LIMIT, || {
            bus.publish_pose(&pose(2, 1.0));
            robot_entry(sp.http, "r1").is_some_and(|r| r["online"] == true)
                && station_tiles(sp.http) == 3
        }),
        "the station sees r1 and its 3 tiles"
    );

    // The monitor: a Zenoh client of the station with the monitor's certificate.
    let mp = Ports::new();
    let _monitor = Station::start_with(
        mp,
        &dir.path().join("m.db"),
        &[
            "--pki".into(),
            fleet.monitor_dir("m1").display().to_string(),
            "--monitor".into(),
            "m1".into(),
            "--connect".into(),
            secure_ep(sp.zenoh),
        ],
    );
    let h = health(mp.http);
    assert_eq!(
        (&h["role"], &h["monitor"]),
        (&"monitor".into(), &"m1".into())
    );
    assert_eq!(health(sp.http)["role"], "station");
    // It gets the robot's live poses, and its tiles: the 3 published before it started (through
    // the robot's resync queryable, asked through the station) and one published after.
    let mut seq = 10;
    let watched = wait_for(LIMIT, || {
        seq += 1;
        bus.publish_pose(&pose(seq, 2.5));
        robot_entry(mp.http, "r1").is_some_and(|r| r["online"] == true && r["pose"]["x_m"] == 2.5)
            && station_tiles(mp.http) >= 3
    });
    assert!(
        watched,
        "the monitor does not watch r1: {:?}, {} tiles",
        robot_entry(mp.http, "r1"),
        station_tiles(mp.http)
    );
    publish_tiles(&bus, 3..4, 101);
    assert!(
        wait_for(LIMIT, || station_tiles(mp.http) == 4),
        "live tile at the monitor: {}",
        station_tiles(mp.http)
    );
    println!(
        "monitor watching r1 (pose, 4 tiles) {:.1} s after the test started",
        t_start.elapsed().as_secs_f64()
    );

    // Its API refuses commands with a stable code, and counts them; reads still answer.
    let (st, body) = http(
        mp.http,
        "POST",
        "/api/robots/r1/goal",
        r#"{"x": 3, "y": 0}"#,
    )
    .unwrap();
    assert_eq!(st, 403, "{body}");
    let v: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(v["code"], "monitor_read_only", "{body}");
    let (st, _) = http(mp.http, "POST", "/api/robots/r1/stop", "{}").unwrap();
    assert_eq!(st, 403);
    assert_eq!(health(mp.http)["commands_refused_read_only"], 2);
    assert_eq!(http(mp.http, "GET", "/api/robots", "").unwrap().0, 200);

    // A modified monitor: the monitor's certificate in a session of the test, putting goals on
    // the Zenoh key, as a client of the station and as a peer linked straight to the robot. Its
    // links come up (so what stops it is the rules, not a broken harness) ...
    let rogue_via_station = Raw::open(&[secure_ep(sp.zenoh)], &monitor_files, true);
    assert_eq!(rogue_via_station.links_after(1, LIMIT), 1, "rogue's link");
    let rogue_direct = Raw::open(&[secure_ep(r1_port)], &monitor_files, false);
    // (Gossip may link it to the station as well: at least the robot's link.)
    assert!(
        rogue_direct.links_after(1, LIMIT) >= 1,
        "rogue's link to r1"
    );
    std::thread::sleep(Duration::from_millis(500));
    rogue_via_station.put_goal(&r1, 501);
    rogue_direct.put_goal(&r1, 502);
    // ... and neither goal reaches the robot.
    let got = goals_within(&bus, Duration::from_secs(3));
    assert!(
        got.is_empty(),
        "goals from the monitor's certificate: {got:?}"
    );
    assert_eq!(bus.counters().commands_refused, 0, "dropped by the rules");
    // The same put with the station's certificate, through the station, does.
    let station_files = fleet.station();
    let operator = Raw::open(&[secure_ep(sp.zenoh)], &station_files, true);
    assert_eq!(operator.links_after(1, LIMIT), 1, "operator's link");
    std::thread::sleep(Duration::from_millis(500));
    operator.put_goal(&r1, 503);
    let got = goals_within(&bus, Duration::from_secs(5));
    assert_eq!(got, vec![503], "the station certificate's goal");

    // Revoked: the station re-reads the register and re-opens its session; the monitor sees the
    // robot go offline and nothing of it after, while the station still does.
    pki(&["revoke-monitor", "--name", "m1", "--dir", ps]);
    let t_revoked = Instant::now();
    let blind = wait_for(LIMIT, || {
        seq += 1;
        bus.publish_pose(&pose(seq, 4.0));
        robot_entry(mp.http, "r1").is_some_and(|r| r["online"] == false)
    });
    assert!(blind, "revoked monitor: {:?}", robot_entry(mp.http, "r1"));
    println!(
        "revoked monitor shows r1 offline {:.1} s after pki revoke-monitor",
        t_revoked.elapsed().as_secs_f64()
    );
    assert!(
        wait_for(LIMIT, || {
            seq += 1;
            bus.publish_pose(&pose(seq, 5.0));
            robot_entry(sp.http, "r1")
                .is_some_and(|r| r["online"] == true && r["pose"]["x_m"] == 5.0)
        }),
        "the station still sees r1"
    );
    for _ in 0..20 {
        seq += 1;
        bus.publish_pose(&pose(seq, 5.0));
        std::thread::sleep(Duration::from_millis(100));
    }
    let m = robot_entry(mp.http, "r1").unwrap();
    assert!(
        m["online"] == false && m["pose"]["x_m"] != 5.0,
        "the revoked monitor still sees r1: {m}"
    );
    // The revoked certificate (a peer here: a client that cannot link fails to open) is sent
    // nothing, whether or not the station lets its link come up.
    let revoked = Raw::open(&[secure_ep(sp.zenoh)], &monitor_files, false);
    let links = revoked.links_after(1, Duration::from_secs(3));
    let heard = revoked.samples_while(Duration::from_secs(2), || {
        seq += 1;
        bus.publish_pose(&pose(seq, 6.0));
    });
    assert_eq!(heard, 0, "samples sent to a revoked monitor certificate");
    println!("revoked monitor certificate: {links} link(s), {heard} samples");
    println!(
        "monitor test done in {:.1} s",
        t_start.elapsed().as_secs_f64()
    );
}

#[test]
fn a_router_lets_a_monitor_watch_and_not_command() {
    let t_start = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let pki_dir: PathBuf = dir.path().join("pki");
    let ps = pki_dir.to_str().unwrap();
    pki(&["init", "--dir", ps]);
    pki(&["issue", "--robot", "r1", "--dir", ps]);
    pki(&["add-monitor", "--name", "m1", "--dir", ps]);
    let fleet = FleetDir::new(&pki_dir);

    // `operator-station router` (the station's certificate and rules, read from the register),
    // the robot a client of it.
    let rp = free_port();
    let log = std::fs::File::create(dir.path().join("router.log")).unwrap();
    let _router = KillOnDrop::spawn(
        Command::new(bin("operator-station"))
            .args(["router", "--pki", ps, "--zenoh-listen", &secure_ep(rp)])
            .env("RUST_LOG", "info,zenoh=warn")
            .stdout(std::process::Stdio::null())
            .stderr(log),
    )
    .expect("start the router");
    // The monitor's certificate, a client of the router (retried until the router listens).
    let t0 = Instant::now();
    let monitor = loop {
        match Raw::try_open(
            &[secure_ep(rp)],
            &CertFiles::monitor(&fleet.monitor_dir("m1")),
            true,
        ) {
            Ok(r) => break r,
            Err(e) if t0.elapsed() > LIMIT => panic!("the router never took the monitor: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    };
    let r1 = RobotId::new("r1").unwrap();
    let mut cfg = BusConfig::new(r1.clone());
    cfg.zenoh = ZenohSettings {
        mode: Some(ZenohMode::Client),
        connect: vec![secure_ep(rp)],
        tls: Some(CertFiles::robot(&fleet.robot_dir(&r1))),
        ..ZenohSettings::default()
    };
    let bus = BusHandle::start(cfg).expect("open the robot bus");

    // The monitor reads the robot's poses ...
    let mut seq = 0;
    let heard = monitor.samples_while(Duration::from_secs(2), || {
        seq += 1;
        bus.publish_pose(&pose(seq, 1.0));
    });
    assert!(
        heard >= 5,
        "the monitor heard {heard} poses through the router"
    );
    // ... and its goal is dropped at the router, while the station certificate's passes.
    monitor.put_goal(&r1, 601);
    let got = goals_within(&bus, Duration::from_secs(3));
    assert!(
        got.is_empty(),
        "goals from the monitor's certificate: {got:?}"
    );
    let operator = Raw::open(&[secure_ep(rp)], &fleet.station(), true);
    std::thread::sleep(Duration::from_millis(500));
    operator.put_goal(&r1, 602);
    assert_eq!(goals_within(&bus, Duration::from_secs(5)), vec![602]);
    println!(
        "router test done in {:.1} s ({heard} poses heard by the monitor in 2 s)",
        t_start.elapsed().as_secs_f64()
    );
}
