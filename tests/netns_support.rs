//! Helpers of tests/netns.rs: hosts as Linux network namespaces joined by veth pairs, a robot's
//! link through a link emulator (or `tc netem` where the kernel has it), and the fleet's
//! processes started inside them.
//!
//! A site: namespace `robot` (10.0.1.1) - `link` (the emulator, no address) - `router` (10.0.1.2
//! towards the robot, 10.0.(1+i).1 towards station i) - `st<i>` (10.0.(1+i).2). The names carry
//! the process id and a per-test number, so tests run side by side (and beside another run of
//! this binary). Everything is removed on drop, after a panic too. The test reaches a station's
//! HTTP API on the station's own loopback from a thread that entered its namespace.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::process::{ChildStdin, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::{bin, workspace_root, KillOnDrop};

use crate::secure_support::{pki as pki_cmd, PosePump};
use crate::station_support::{strip_ansi, tail};

/// Zenoh port of the router and the stations (each namespace has its own ports).
pub const ZENOH_PORT: u16 = 7447;
/// The link scheme of every endpoint: the product's secure default (mutual TLS over QUIC).
pub const SCHEME: &str = common::security::SECURE_SCHEME;
/// HTTP port of the stations, on their own loopback.
pub const HTTP_PORT: u16 = 8080;

/// Runs `ip ARGS`; Err with its stderr when it fails.
pub fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {args:?}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

fn must(r: Result<(), String>) {
    if let Err(e) = r {
        panic!("{e}");
    }
}

/// Whether this process may make network namespaces (root with `ip netns`); prints why not.
pub fn namespaces_available() -> bool {
    static PROBE: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let r = PROBE.get_or_init(|| {
        let probe = format!("tnprobe-{}", std::process::id());
        ip(&["netns", "add", &probe])?;
        ip(&["netns", "del", &probe])
    });
    if let Err(e) = r {
        println!("skipping: network namespaces cannot be made here ({e})");
    }
    r.is_ok()
}

/// A network namespace, deleted on drop.
pub struct Netns(pub String);

impl Netns {
    /// Makes namespace `name` (a stale one of that name is removed first) with loopback up.
    pub fn new(name: String) -> Netns {
        let _ = ip(&["netns", "del", &name]);
        must(ip(&["netns", "add", &name]));
        let ns = Netns(name);
        must(ip(&["-n", &ns.0, "link", "set", "dev", "lo", "up"]));
        ns
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = ip(&["netns", "del", &self.0]);
    }
}

/// A veth pair `a` in namespace `na` and `b` in `nb` (names need only be unique in their own
/// namespace), both up, with optional addresses (`10.0.1.1/24`).
fn veth(na: &str, a: &str, addr_a: Option<&str>, nb: &str, b: &str, addr_b: Option<&str>) {
    must(ip(&[
        "link", "add", a, "netns", na, "type", "veth", "peer", "name", b, "netns", nb,
    ]));
    for (ns, dev, addr) in [(na, a, addr_a), (nb, b, addr_b)] {
        if let Some(addr) = addr {
            must(ip(&["-n", ns, "addr", "add", addr, "dev", dev]));
        }
        must(ip(&["-n", ns, "link", "set", "dev", dev, "up"]));
    }
}

/// Runs `f` on a thread inside namespace `ns` (sockets it opens live there).
pub fn in_ns<T: Send>(ns: &str, f: impl FnOnce() -> T + Send) -> T {
    std::thread::scope(|s| {
        s.spawn(|| {
            let file = std::fs::File::open(format!("/run/netns/{ns}"))
                .unwrap_or_else(|e| panic!("open namespace {ns}: {e}"));
            nix::sched::setns(file.as_raw_fd(), nix::sched::CloneFlags::CLONE_NEWNET)
                .unwrap_or_else(|e| panic!("enter namespace {ns}: {e}"));
            f()
        })
        .join()
        .expect("namespace thread")
    })
}

/// `cmd` run inside namespace `ns` (`ip netns exec`, which then becomes the program itself).
pub fn ns_command(ns: &str, program: &Path) -> Command {
    let mut c = Command::new("ip");
    c.args(["netns", "exec", ns]).arg(program);
    c.current_dir(workspace_root())
        .env("RUST_LOG", "info,zenoh=warn")
        .env("NO_COLOR", "1")
        .stdin(Stdio::null());
    c
}

/// How delay and loss are made on the robot's link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shaper {
    /// `tc netem` on both ends of the robot's link (the emulator only cuts).
    Netem,
    /// The userspace emulator does delay, loss and cut.
    Emulator,
}

/// The link emulator (`terranav-linkemu`) running in the link namespace.
pub struct Emulator {
    proc: KillOnDrop,
    stdin: ChildStdin,
    stdout: BufReader<std::process::ChildStdout>,
}

impl Emulator {
    fn start(ns: &str, a: &str, b: &str, log: &Path) -> Emulator {
        let mut p = KillOnDrop::spawn(
            ns_command(ns, &bin("terranav-linkemu"))
                .args([a, b])
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(log).expect("emulator log")),
        )
        .expect("start terranav-linkemu");
        let stdin = p.0.stdin.take().expect("emulator stdin");
        let mut stdout = BufReader::new(p.0.stdout.take().expect("emulator stdout"));
        let mut line = String::new();
        let _ = stdout.read_line(&mut line);
        assert_eq!(
            line.trim(),
            "ready",
            "link emulator did not start: {}",
            tail(log, 10)
        );
        Emulator {
            proc: p,
            stdin,
            stdout,
        }
    }

    /// Sends one command line (`delay_ms 150`, `loss 0.05`, `cut on`).
    pub fn send(&mut self, cmd: &str) {
        writeln!(self.stdin, "{cmd}").expect("emulator command");
        self.stdin.flush().expect("emulator command");
    }

    /// Frame counters per direction (`a_to_b` is robot to router).
    pub fn stats(&mut self) -> Value {
        self.send("stats");
        let mut line = String::new();
        self.stdout.read_line(&mut line).expect("emulator stats");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"))
    }
}

/// One site: robot, link, router and `stations` station namespaces, wired as in the module doc.
pub struct Site {
    /// Where the test's files go (PKI, databases, logs).
    pub dir: PathBuf,
    /// The fleet's PKI folder.
    pub pki: PathBuf,
    /// Namespace names.
    pub robot_ns: String,
    /// The link namespace.
    pub link_ns: String,
    /// The router's namespace.
    pub router_ns: String,
    /// The stations' namespaces.
    pub station_ns: Vec<String>,
    /// The second site's router namespace, if any.
    pub routerb_ns: Option<String>,
    /// The link emulator on the robot's link.
    pub emu: Emulator,
    /// How delay and loss are made.
    pub shaper: Shaper,
    // Dropped last (fields drop in order): processes are gone before their namespaces.
    namespaces: Vec<Netns>,
}

/// The router's address as the robot sees it.
pub const ROUTER_FOR_ROBOT: &str = "10.0.1.2";

/// The first router's address as the second site's router sees it.
pub const ROUTER_A_FOR_B: &str = "10.0.9.1";

/// The router's address as station `i` (0-based) sees it.
pub fn router_for_station(i: usize) -> String {
    format!("10.0.{}.1", i + 2)
}

impl Site {
    /// Builds the namespaces and links of test number `k` with `stations` stations, a fleet PKI
    /// with a certificate for each of `robots`, and the emulator on the robot's link.
    /// With `second_site`, the last station sits behind a second router (namespace `routerb`,
    /// 10.0.9.2) that connects to the first one (10.0.9.1): two sites joined router to router.
    pub fn new(k: u32, stations: usize, robots: &[&str], dir: &Path, second_site: bool) -> Site {
        let tag = format!("tn{}-{k}", std::process::id());
        let name = |s: &str| format!("{tag}-{s}");
        let (robot_ns, link_ns, router_ns) = (name("robot"), name("link"), name("router"));
        let station_ns: Vec<String> = (0..stations).map(|i| name(&format!("st{i}"))).collect();
        let routerb_ns = second_site.then(|| name("routerb"));
        let mut namespaces = Vec::new();
        for n in [&robot_ns, &link_ns, &router_ns]
            .into_iter()
            .chain(station_ns.iter())
            .chain(routerb_ns.iter())
        {
            namespaces.push(Netns::new(n.clone()));
        }
        if let Some(rb) = &routerb_ns {
            veth(
                &router_ns,
                "rb",
                Some(&format!("{ROUTER_A_FOR_B}/24")),
                rb,
                "ra",
                Some("10.0.9.2/24"),
            );
        }
        veth(&robot_ns, "eth0", Some("10.0.1.1/24"), &link_ns, "la", None);
        veth(
            &link_ns,
            "lb",
            None,
            &router_ns,
            "r0",
            Some(&format!("{ROUTER_FOR_ROBOT}/24")),
        );
        // The ends that send into the emulator hand it one MTU at a time, as a wire would.
        must(ip(&[
            "-n",
            &robot_ns,
            "link",
            "set",
            "eth0",
            "gso_max_segs",
            "1",
        ]));
        must(ip(&[
            "-n",
            &router_ns,
            "link",
            "set",
            "r0",
            "gso_max_segs",
            "1",
        ]));
        for (i, ns) in station_ns.iter().enumerate() {
            let behind = match &routerb_ns {
                Some(rb) if i + 1 == stations => rb,
                _ => &router_ns,
            };
            veth(
                behind,
                &format!("s{i}"),
                Some(&format!("{}/24", router_for_station(i))),
                ns,
                "eth0",
                Some(&format!("10.0.{}.2/24", i + 2)),
            );
        }
        let shaper = if Command::new("tc")
            .args([
                "-n", &robot_ns, "qdisc", "add", "dev", "eth0", "root", "netem", "delay", "0ms",
            ])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
        {
            let _ = Command::new("tc")
                .args([
                    "-n", &router_ns, "qdisc", "add", "dev", "r0", "root", "netem", "delay", "0ms",
                ])
                .status();
            Shaper::Netem
        } else {
            Shaper::Emulator
        };
        let emu = Emulator::start(&link_ns, "la", "lb", &dir.join(format!("linkemu-{k}.log")));
        // The router's certificate is the station's: it must name every address it is reached by.
        let pki = dir.join("pki");
        let mut init = vec![
            "init".to_string(),
            "--dir".into(),
            pki.display().to_string(),
            "--host".into(),
            ROUTER_FOR_ROBOT.into(),
            "--host".into(),
            ROUTER_A_FOR_B.into(),
        ];
        for i in 0..stations {
            init.extend(["--host".into(), router_for_station(i)]);
        }
        pki_cmd(&init.iter().map(String::as_str).collect::<Vec<_>>());
        for r in robots {
            pki_cmd(&["issue", "--robot", r, "--dir", &pki.display().to_string()]);
        }
        Site {
            dir: dir.to_path_buf(),
            pki,
            robot_ns,
            link_ns,
            router_ns,
            station_ns,
            routerb_ns,
            emu,
            shaper,
            namespaces,
        }
    }

    /// Sets one-way delay and loss on the robot's link (each direction), with netem where the
    /// kernel has it and the emulator otherwise. Returns what was used, for the report.
    pub fn shape(&mut self, one_way_delay_ms: u32, loss: f64) -> &'static str {
        match self.shaper {
            Shaper::Netem => {
                for (ns, dev) in [(&self.robot_ns, "eth0"), (&self.router_ns, "r0")] {
                    let ok = Command::new("tc")
                        .args(["-n", ns, "qdisc", "change", "dev", dev, "root", "netem"])
                        .args(["delay", &format!("{one_way_delay_ms}ms")])
                        .args(["loss", &format!("{}%", loss * 100.0)])
                        .status()
                        .is_ok_and(|s| s.success());
                    assert!(ok, "tc netem on {ns} {dev}");
                }
                "tc netem"
            }
            Shaper::Emulator => {
                self.emu.send(&format!("delay_ms {one_way_delay_ms}"));
                self.emu.send(&format!("loss {loss}"));
                "terranav-linkemu (no netem in this kernel)"
            }
        }
    }

    /// Starts the router (`operator-station router --pki`) on every address of its namespace.
    pub fn start_router(&self) -> Proc {
        Proc::start(
            "router",
            ns_command(&self.router_ns, &bin("operator-station")).args([
                "router",
                "--pki",
                &self.pki.display().to_string(),
                "--zenoh-listen",
                &format!("{SCHEME}/0.0.0.0:{ZENOH_PORT}"),
            ]),
            &self.dir,
        )
    }

    /// Starts the second site's router, connecting to the first router.
    pub fn start_router_b(&self) -> Proc {
        let ns = self
            .routerb_ns
            .as_ref()
            .expect("a site with a second router");
        Proc::start(
            "routerb",
            ns_command(ns, &bin("operator-station")).args([
                "router",
                "--pki",
                &self.pki.display().to_string(),
                "--zenoh-listen",
                &format!("{SCHEME}/0.0.0.0:{ZENOH_PORT}"),
                "--connect",
                &format!("{SCHEME}/{ROUTER_A_FOR_B}:{ZENOH_PORT}"),
            ]),
            &self.dir,
        )
    }

    /// Starts station `i` (own database) as a peer of the router; waits until it answers HTTP.
    pub fn start_station(&self, i: usize) -> NsStation {
        let ns = self.station_ns[i].clone();
        let db = self.dir.join(format!("station{i}.db"));
        let p = Proc::start(
            &format!("station{i}"),
            ns_command(&ns, &bin("operator-station"))
                .args(["serve", "--port", &HTTP_PORT.to_string(), "--pki"])
                .arg(&self.pki)
                .args([
                    "--connect",
                    &format!("{SCHEME}/{}:{ZENOH_PORT}", router_for_station(i)),
                ])
                .arg("--db")
                .arg(&db),
            &self.dir,
        );
        let mut st = NsStation { proc: p, ns, db };
        let t0 = Instant::now();
        while st.http("GET", "/api/health", "").is_none() {
            st.proc.assert_running();
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "station {i} did not start\n{}",
                st.proc.tail(30)
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        st
    }

    /// Starts a simulated robot (`robot-agent sim`, live) in the robot namespace as a client of
    /// the router (`config/zenoh/router-client.json5`), with its own certificates; it writes
    /// the simulator's true pose to `truth`.
    pub fn start_robot(&self, id: &str, scenario: &Path, start: &str, truth: &Path) -> Proc {
        Proc::start(
            id,
            ns_command(&self.robot_ns, &bin("robot-agent"))
                .arg("sim")
                .arg("--scenario")
                .arg(scenario)
                .args(["--robot", id, "--seed", "1"])
                .arg(format!("--start={start}"))
                .arg("--pki")
                .arg(self.pki.join("robots").join(id))
                .args(["--zenoh", "config/zenoh/router-client.json5", "--connect"])
                .arg(format!("{SCHEME}/{ROUTER_FOR_ROBOT}:{ZENOH_PORT}"))
                .arg("--truth-out")
                .arg(truth),
            &self.dir,
        )
    }

    /// Every tile robot `id` serves, asked from station `i`'s namespace through the router
    /// (`operator-station robot-tiles`), decoded.
    pub fn robot_tiles(&self, i: usize, id: &str) -> Vec<common::grid::Tile> {
        let out = self.dir.join(format!("robot-tiles-{id}-{i}"));
        let _ = std::fs::remove_dir_all(&out);
        let o = ns_command(&self.station_ns[i], &bin("operator-station"))
            .arg("robot-tiles")
            .arg("--pki")
            .arg(&self.pki)
            .args([
                "--connect",
                &format!("{SCHEME}/{}:{ZENOH_PORT}", router_for_station(i)),
            ])
            .args(["--robot", id, "--out"])
            .arg(&out)
            .output()
            .expect("run operator-station robot-tiles");
        assert!(
            o.status.success(),
            "robot-tiles: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let mut tiles = Vec::new();
        for e in std::fs::read_dir(&out).expect("robot tiles folder") {
            let bytes = std::fs::read(e.expect("entry").path()).expect("tile file");
            tiles.push(common::grid::decode_tile(&bytes).expect("robot tile decodes"));
        }
        tiles
    }
}

/// A process of the test with its stderr in a log file (printed when a test fails).
pub struct Proc {
    proc: Option<KillOnDrop>,
    name: String,
    log: PathBuf,
}

impl Proc {
    fn start(name: &str, cmd: &mut Command, dir: &Path) -> Proc {
        let log = dir.join(format!("{name}.log"));
        let err = std::fs::File::create(&log).expect("log file");
        let p = KillOnDrop::spawn(cmd.stdout(Stdio::null()).stderr(err))
            .unwrap_or_else(|e| panic!("start {name}: {e}"));
        Proc {
            proc: Some(p),
            name: name.into(),
            log,
        }
    }

    /// Panics with the log tail when the process has exited.
    pub fn assert_running(&mut self) {
        if let Some(p) = self.proc.as_mut() {
            if let Ok(Some(s)) = p.0.try_wait() {
                panic!("{} exited: {s}\n{}", self.name, tail(&self.log, 30));
            }
        }
    }

    /// Sends a signal (`-STOP`, `-CONT`).
    pub fn signal(&self, sig: &str) {
        if let Some(p) = &self.proc {
            let _ = Command::new("kill")
                .args([sig, &p.0.id().to_string()])
                .status();
        }
    }

    /// The last `n` lines of its log.
    pub fn tail(&self, n: usize) -> String {
        tail(&self.log, n)
    }

    /// Its log so far, without terminal colours.
    pub fn log_text(&self) -> String {
        strip_ansi(&std::fs::read_to_string(&self.log).unwrap_or_default())
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("--- {} log tail ---\n{}", self.name, tail(&self.log, 30));
        }
        // A stopped process gets the kill at once.
        self.signal("-CONT");
    }
}

/// A station in its namespace.
pub struct NsStation {
    /// The process.
    pub proc: Proc,
    /// Its namespace.
    pub ns: String,
    /// Its database.
    pub db: PathBuf,
}

impl NsStation {
    /// An HTTP request to the station's API on its own loopback.
    pub fn http(&self, method: &str, path: &str, body: &str) -> Option<(u16, String)> {
        in_ns(&self.ns, || {
            crate::station_support::http(HTTP_PORT, method, path, body)
        })
    }

    /// GET returning JSON (asserting 200).
    pub fn get_json(&self, path: &str) -> Value {
        let (st, body) = self.http("GET", path, "").expect("station answers");
        assert_eq!(st, 200, "{path}: {body}");
        serde_json::from_str(&body).expect("JSON body")
    }

    /// The station's entry for `robot` in `/api/robots`.
    pub fn robot(&self, robot: &str) -> Option<Value> {
        let (st, body) = self.http("GET", "/api/robots", "")?;
        if st != 200 {
            return None;
        }
        let v: Value = serde_json::from_str(&body).ok()?;
        v.as_array()?.iter().find(|r| r["robot"] == robot).cloned()
    }

    /// Tile indices and versions of a datum's merged map.
    pub fn tile_index(
        &self,
        datum: &str,
    ) -> std::collections::BTreeMap<common::grid::TileIndex, u64> {
        in_ns(&self.ns, || {
            crate::station_support::station_tile_index(HTTP_PORT, datum)
        })
    }
}

/// The simulator's last true pose (x, y) from a `--truth-out` file (`t_unix_ms x y yaw` lines).
pub fn last_truth(path: &Path) -> Option<(f64, f64)> {
    let text = std::fs::read_to_string(path).ok()?;
    let line = text.lines().rev().find(|l| !l.trim().is_empty())?;
    let v: Vec<f64> = line
        .split_whitespace()
        .filter_map(|s| s.parse().ok())
        .collect();
    (v.len() >= 3).then(|| (v[1], v[2]))
}

impl Site {
    /// Poses of robot `id` (which needs a certificate in the site's PKI) stamped with the wall
    /// clock at 10 Hz, published by the real robot bus (`robot_agent::bus`, secure, client of the
    /// router) from the robot's namespace until dropped: the simulated robot stamps its poses with
    /// simulated time, which falls behind the wall clock on a loaded machine, so its latency at
    /// the station is not the link's alone. This one's is. Its Zenoh session must be the first of
    /// this test process: Zenoh's runtime threads are made by the thread that first opens a
    /// session, and inherit its namespace.
    pub fn pose_probe(&self, id: &str) -> PosePump {
        let (ns, id) = (self.robot_ns.clone(), id.to_string());
        let files = common::security::CertFiles::robot(&self.pki.join("robots").join(&id));
        PosePump::start(0.0, move || {
            let file = std::fs::File::open(format!("/run/netns/{ns}")).expect("namespace");
            nix::sched::setns(file.as_raw_fd(), nix::sched::CloneFlags::CLONE_NEWNET)
                .expect("enter the robot namespace");
            let mut cfg = robot_agent::bus::BusConfig::new(
                common::keys::RobotId::new(id.as_str()).expect("robot id"),
            );
            cfg.zenoh = robot_agent::bus::ZenohSettings {
                mode: Some(robot_agent::bus::ZenohMode::Client),
                connect: vec![format!("{SCHEME}/{ROUTER_FOR_ROBOT}:{ZENOH_PORT}")],
                tls: Some(files),
                ..Default::default()
            };
            let bus = robot_agent::bus::BusHandle::start(cfg).expect("probe bus");
            move |p: &common::msg::Pose| bus.publish_pose(p)
        })
    }
}
