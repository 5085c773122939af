//! A read-only monitor station (issue 20), with real processes on loopback: a fleet PKI with a
//! robot and a monitor (`operator-station pki add-monitor`), a secure station, the real robot bus
//! (synthetic robot, so the test sees every command that reaches it), and `operator-station serve
//! --monitor` as a Zenoh client of the station. The monitor watches the robot (poses, tiles,
//! merged map); its API refuses commands with a stable code; a goal put on the Zenoh key with the
//! monitor's certificate, through the station or straight to the robot, never reaches the robot,
//! while the same put with the station's certificate does; a revoked monitor sees nothing more.

mod secure_support;
mod station_support;

use std::process::Command;
use std::time::{Duration, Instant};

use common::keys::{self, RobotId, Topic};
use common::security::{CertFiles, FleetDir};
use robot_agent::bus::{BusConfig, BusHandle, Command as BusCommand, ZenohMode, ZenohSettings};
use secure_support::{fleet, pki, pose, secure_ep};
use serde_json::Value;
use station_support::*;
use support::{bin, free_port, KillOnDrop};

const LIMIT: Duration = Duration::from_secs(20);

/// Puts a fresh goal, stamped by `s`, on `robot`'s goal key.
fn put_goal(s: &Observer, robot: &RobotId, goal_id: u32) {
    s.put(
        &keys::key(robot, Topic::CmdGoal),
        s.goal_bytes(goal_id, 3.0, 0.0),
    );
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
    let pki_dir = fleet(dir.path(), "pki", &["r1"]);
    let ps = pki_dir.to_str().unwrap();
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
    let rogue_via_station =
        Observer::open(&[secure_ep(sp.zenoh)], Tls::member(&monitor_files), true);
    assert_eq!(rogue_via_station.links_after(1, LIMIT), 1, "rogue's link");
    let rogue_direct = Observer::open(&[secure_ep(r1_port)], Tls::member(&monitor_files), false);
    // (Gossip may link it to the station as well: at least the robot's link.)
    assert!(
        rogue_direct.links_after(1, LIMIT) >= 1,
        "rogue's link to r1"
    );
    std::thread::sleep(Duration::from_millis(500));
    put_goal(&rogue_via_station, &r1, 501);
    put_goal(&rogue_direct, &r1, 502);
    // ... and neither goal reaches the robot.
    let got = goals_within(&bus, Duration::from_secs(3));
    assert!(
        got.is_empty(),
        "goals from the monitor's certificate: {got:?}"
    );
    assert_eq!(bus.counters().commands_refused, 0, "dropped by the rules");
    // The same put with the station's certificate, through the station, does.
    let station_files = fleet.station();
    let operator = Observer::open(&[secure_ep(sp.zenoh)], Tls::member(&station_files), true);
    assert_eq!(operator.links_after(1, LIMIT), 1, "operator's link");
    std::thread::sleep(Duration::from_millis(500));
    put_goal(&operator, &r1, 503);
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
    let mut revoked = Observer::open(&[secure_ep(sp.zenoh)], Tls::member(&monitor_files), false);
    let links = revoked.links_after(1, Duration::from_secs(3));
    let heard = revoked
        .samples_while("terranav/**", Duration::from_secs(2), || {
            seq += 1;
            bus.publish_pose(&pose(seq, 6.0));
        })
        .len();
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
    let pki_dir = fleet(dir.path(), "pki", &["r1"]);
    let ps = pki_dir.to_str().unwrap();
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
    let monitor_files = CertFiles::monitor(&fleet.monitor_dir("m1"));
    let mut monitor = loop {
        match Observer::try_open(&[secure_ep(rp)], Tls::member(&monitor_files), true) {
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
    let heard = monitor
        .samples_while("terranav/**", Duration::from_secs(2), || {
            seq += 1;
            bus.publish_pose(&pose(seq, 1.0));
        })
        .len();
    assert!(
        heard >= 5,
        "the monitor heard {heard} poses through the router"
    );
    // ... and its goal is dropped at the router, while the station certificate's passes.
    put_goal(&monitor, &r1, 601);
    let got = goals_within(&bus, Duration::from_secs(3));
    assert!(
        got.is_empty(),
        "goals from the monitor's certificate: {got:?}"
    );
    let operator = Observer::open(&[secure_ep(rp)], Tls::member(&fleet.station()), true);
    std::thread::sleep(Duration::from_millis(500));
    put_goal(&operator, &r1, 602);
    assert_eq!(goals_within(&bus, Duration::from_secs(5)), vec![602]);
    println!(
        "router test done in {:.1} s ({heard} poses heard by the monitor in 2 s)",
        t_start.elapsed().as_secs_f64()
    );
}
