//! `operator-station demo` stops its simulated robots however it ends: SIGTERM (a `kill`) the same
//! way as Ctrl-C, and even SIGKILL, which gives the station no chance to clean up, leaves no
//! robot-agent simulating and publishing behind it. Real processes, found through `/proc`
//! (Linux).

use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use support::{bin, free_port, workspace_root, KillOnDrop};

/// Process ids whose parent is `parent`, with their command lines.
fn children_of(parent: u32) -> Vec<(u32, String)> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for e in dir.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // pid (comm) state ppid ...: the command name may hold spaces, so read after its ')'.
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
            continue;
        };
        let mut f = rest.split_whitespace();
        let (_state, ppid) = (f.next(), f.next().and_then(|p| p.parse::<u32>().ok()));
        if ppid == Some(parent) {
            let cmd = std::fs::read(format!("/proc/{pid}/cmdline"))
                .map(|b| String::from_utf8_lossy(&b).replace('\0', " "))
                .unwrap_or_default();
            out.push((pid, cmd));
        }
    }
    out
}

/// Whether a process still runs (a zombie or a vanished pid does not).
fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            s.rsplit_once(')')
                .and_then(|(_, r)| r.split_whitespace().next().map(|st| st != "Z"))
        })
        .unwrap_or(false)
}

/// Starts a one-robot demo and returns it with its robot's two pids (the simulated world serving
/// ROS 2 topics, and `robot-agent run` on them) once the station serves.
fn start_demo() -> (KillOnDrop, Vec<u32>) {
    let port = free_port();
    let mut demo = KillOnDrop::spawn(
        Command::new(bin("operator-station"))
            .args(["demo", "--robots", "1", "--port", &port.to_string()])
            .current_dir(workspace_root())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null()),
    )
    .expect("start operator-station demo");
    let t0 = Instant::now();
    loop {
        assert!(
            demo.0.try_wait().expect("wait").is_none(),
            "demo exited early"
        );
        let robots: Vec<u32> = children_of(demo.0.id())
            .into_iter()
            .filter(|(_, cmd)| {
                cmd.contains("robot-agent") && (cmd.contains(" sim ") || cmd.contains(" run "))
            })
            .map(|(pid, _)| pid)
            .collect();
        if TcpStream::connect(("127.0.0.1", port)).is_ok() && robots.len() == 2 {
            return (demo, robots);
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "demo did not serve with one robot (world and agent) within 60 s (processes {robots:?})"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "kill {sig} {pid}");
}

/// Waits up to `limit` for `pid` to stop running.
fn gone_within(pid: u32, limit: Duration) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if !running(pid) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    !running(pid)
}

/// Whether `/proc` is there to find processes by (with a printed notice when not).
fn have_proc() -> bool {
    let ok = std::path::Path::new("/proc/self/stat").exists();
    if !ok {
        println!("skipping: no /proc");
    }
    ok
}

#[test]
fn a_killed_demo_leaves_no_robot_running() {
    if !have_proc() {
        return;
    }
    let (mut demo, robots) = start_demo();
    assert!(robots.iter().all(|p| running(*p)));
    signal(demo.0.id(), "-KILL");
    let _ = demo.0.wait();
    for robot in robots {
        assert!(
            gone_within(robot, Duration::from_secs(10)),
            "robot-agent {robot} still runs 10 s after its station was killed"
        );
    }
}

#[test]
fn a_terminated_demo_stops_its_robots_and_exits_cleanly() {
    if !have_proc() {
        return;
    }
    let (mut demo, robots) = start_demo();
    signal(demo.0.id(), "-TERM");
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = demo.0.try_wait().expect("wait") {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "demo still runs 20 s after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "demo exited with {status} on SIGTERM");
    for robot in robots {
        assert!(
            gone_within(robot, Duration::from_secs(5)),
            "robot-agent {robot} outlived its terminated station"
        );
    }
}

/// The station binary under test (`TERRANAV_OPS_BASELINE=DIR`: an older build's, to show the
/// checks failing before the fix).
fn station_bin() -> std::path::PathBuf {
    match std::env::var_os("TERRANAV_OPS_BASELINE") {
        Some(d) => std::path::PathBuf::from(d).join("operator-station"),
        None => bin("operator-station"),
    }
}

/// The demo prints its Zenoh endpoint and its database; on the default port `operator-station
/// robots` finds its robot without options (it printed nothing: the demo picked a random port);
/// and a temporary database folder is gone when the demo ends (it was left behind).
#[test]
fn the_demo_says_where_it_is_and_removes_its_temporary_folder() {
    use std::io::{BufRead, BufReader};
    if !have_proc() {
        return;
    }
    let port = free_port();
    let mut demo = KillOnDrop::spawn(
        Command::new(station_bin())
            .args(["demo", "--robots", "1", "--port", &port.to_string()])
            .current_dir(workspace_root())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null()),
    )
    .expect("start operator-station demo");
    let out = demo.0.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    let mut text = String::new();
    let t0 = Instant::now();
    while !text.contains("database") && t0.elapsed() < Duration::from_secs(30) {
        if let Ok(l) = rx.recv_timeout(Duration::from_millis(200)) {
            text.push_str(&l);
            text.push('\n');
        }
    }
    println!("{text}");
    let endpoint = text
        .split_whitespace()
        .find(|w| w.starts_with("tcp/127.0.0.1:"))
        .map(|w| w.trim_end_matches([';', ')', ',']).to_string())
        .expect("the demo prints its Zenoh endpoint");
    let db = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("database "))
        .map(|l| std::path::PathBuf::from(l.split(" (").next().unwrap_or(l).trim()))
        .expect("the demo prints its database path");
    assert!(db.exists(), "{} does not exist", db.display());
    let default_port = endpoint == "tcp/127.0.0.1:7447";
    if !default_port {
        println!("port 7447 was taken on this machine: the demo chose {endpoint}");
    }
    // `robots` as the README gives it: no options on the default port.
    let t0 = Instant::now();
    let listed = loop {
        let mut cmd = Command::new(station_bin());
        cmd.args(["robots", "--wait-s", "1.5"]);
        if !default_port {
            cmd.args(["--connect", &endpoint]);
        }
        let o = cmd.output().expect("operator-station robots");
        let s = String::from_utf8_lossy(&o.stdout).to_string();
        if s.contains("\"husky-1\"") || t0.elapsed() > Duration::from_secs(30) {
            break s;
        }
        std::thread::sleep(Duration::from_millis(500));
    };
    assert!(
        listed.contains("\"husky-1\""),
        "`operator-station robots` did not list the demo's robot: {listed:?}"
    );
    signal(demo.0.id(), "-TERM");
    let t0 = Instant::now();
    while demo.0.try_wait().expect("wait").is_none() {
        assert!(t0.elapsed() < Duration::from_secs(20), "demo still runs");
        std::thread::sleep(Duration::from_millis(50));
    }
    let folder = db.parent().expect("db folder");
    assert!(
        !folder.exists(),
        "the demo left its temporary folder {} behind",
        folder.display()
    );
}
