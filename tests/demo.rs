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
