//! The operator's day in a real browser (issue 21): `operator-station serve` with a synthetic
//! background map, one simulated robot in `station-field` writing the simulator's truth, nine
//! synthetic robots (ten in all), and Debian's chromium driven by `node web/tests/ops.mjs`.
//!
//! The script checks each UI bug of the issue (card clicks, STOP scope, teleop state, refused
//! goal toasts, the speed slider's limit, routes appearing without a reload, a finished route
//! that is not "Stopped", its name in the progress, no path keeping the goal and raising an
//! alert, stale cards while the station is down and online markers after its restart, the
//! overlaps at 800x600), then draws and runs a 4-waypoint mission, a keep-out zone across the
//! straight line to a goal and a slow zone, judged against the simulator's truth, and a robot
//! that makes no progress raising an alert. A README screenshot of a mission in progress with
//! a zone and the background map is written to `artifacts/ui-ops/`.
//!
//! `TERRANAV_OPS_BASELINE=DIR` runs the bug checks against an older build (`DIR/operator-station`,
//! `DIR/robot-agent`, `DIR/web`): how the checks were shown to fail before the fixes.
//!
//! The station is restarted once in the middle: the script asks for it on its stdout
//! (`@@ctl kill-station`, `@@ctl start-station`) and this harness answers `ok` on its stdin.

mod browser_support;

use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context};
use browser_support::browser_unavailable;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, Datum, FixState, MapFrame, Pose, Session};
use support::{bin, free_port, workspace_root, KillOnDrop};

/// Upper bound for the whole script; its own steps time out well before this.
const SCRIPT_LIMIT: Duration = Duration::from_secs(600);
/// The scenario's datum (config/scenarios/station-field.toml).
const DATUM: Datum = Datum {
    lat_deg: 47.3769,
    lon_deg: 8.5417,
    h_m: 408.0,
};

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// The binaries and web folder under test: this build's, or a baseline's.
struct Build {
    station: PathBuf,
    agent: PathBuf,
    web: Option<PathBuf>,
    baseline: bool,
}

impl Build {
    fn from_env() -> Build {
        match std::env::var_os("TERRANAV_OPS_BASELINE") {
            Some(d) => {
                let d = PathBuf::from(d);
                Build {
                    station: d.join("operator-station"),
                    agent: d.join("robot-agent"),
                    web: Some(d.join("web")),
                    baseline: true,
                }
            }
            None => Build {
                station: bin("operator-station"),
                agent: bin("robot-agent"),
                web: None,
                baseline: false,
            },
        }
    }
}

/// `operator-station serve` on fixed ports (a restart keeps them).
struct StationProc {
    proc: Option<KillOnDrop>,
    http: u16,
    zenoh: u16,
    db: PathBuf,
    basemap: PathBuf,
    log: PathBuf,
    n: u32,
}

impl StationProc {
    fn start(&mut self, b: &Build) -> anyhow::Result<()> {
        self.n += 1;
        let log = self.log.with_extension(format!("{}.log", self.n));
        let mut cmd = Command::new(&b.station);
        cmd.current_dir(workspace_root())
            .args(["serve", "--port", &self.http.to_string()])
            .args(["--zenoh-listen", &format!("tcp/127.0.0.1:{}", self.zenoh)])
            .arg("--db")
            .arg(&self.db)
            .env("RUST_LOG", "info,zenoh=warn")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(File::create(&log)?);
        if let Some(w) = &b.web {
            cmd.arg("--web").arg(w);
        }
        if !b.baseline {
            cmd.arg("--basemap")
                .arg(&self.basemap)
                .args(["--stuck-after-s", "6"]);
        }
        self.proc = Some(KillOnDrop::spawn(&mut cmd).context("start operator-station")?);
        let t0 = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", self.http)).is_err() {
            if t0.elapsed() > Duration::from_secs(30) {
                bail!(
                    "station did not serve within 30 s:\n{}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        Ok(())
    }

    fn kill(&mut self) {
        self.proc.take();
    }
}

/// Nine robots that are only a liveliness token, a session and a pose each second: enough for
/// the robot list and the map to hold ten. `schema`: the wire schema the station speaks.
fn synthetic_fleet(
    endpoint: String,
    schema: u8,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async move {
            let zc = robot_agent::bus::ZenohSettings::connect_to(endpoint)
                .to_config()
                .expect("zenoh config");
            let s = zenoh::open(zc).await.expect("zenoh session");
            let ids: Vec<RobotId> = (1..=9)
                .map(|i| RobotId::new(format!("r-{i:02}")).expect("id"))
                .collect();
            let mut tokens = Vec::new();
            for id in &ids {
                tokens.push(
                    s.liveliness()
                        .declare_token(keys::key(id, Topic::Alive))
                        .await
                        .expect("token"),
                );
            }
            let t0 = unix_ms();
            let enc = |b: Vec<u8>| {
                let mut b = b;
                b[0] = schema;
                b
            };
            let mut seq = 0u32;
            while !stop.load(Ordering::Relaxed) {
                for (i, id) in ids.iter().enumerate() {
                    let session = Session {
                        session_id: format!("{id}-{t0}"),
                        robot: id.to_string(),
                        start_unix_ms: t0,
                        frame: MapFrame::EnuAtDatum,
                        datum: Some(DATUM),
                        cell_size_m: 0.2,
                        tile_cells: 64,
                        source: "synthetic".into(),
                        agent_version: "test".into(),
                    };
                    let (x, y) = (-10.0 + 2.0 * i as f64, 14.0);
                    let pose = Pose {
                        t_unix_ms: unix_ms(),
                        seq,
                        x_m: x,
                        y_m: y,
                        z_m: 0.0,
                        yaw_rad: 0.0,
                        pitch_rad: 0.0,
                        roll_rad: 0.0,
                        v_mps: 0.0,
                        omega_rps: 0.0,
                        fix: FixState::RtkFixed,
                        lat_lon_deg: None,
                    };
                    let _ = s
                        .put(keys::key(id, Topic::Session), enc(msg::encode(&session)))
                        .await;
                    let _ = s
                        .put(keys::key(id, Topic::Pose), enc(msg::encode(&pose)))
                        .await;
                }
                seq += 1;
                tokio::time::sleep(Duration::from_millis(1000)).await;
            }
            drop(tokens);
            let _ = s.close().await;
        });
    })
}

/// A small background map of the field: grass, the two lanes as gravel paths, dark squares
/// where the boxes are and a 5 m grid, as Web Mercator XYZ PNG tiles (zoom 18-20), so the
/// screenshot shows it in the right place under the traversability map.
fn synthetic_basemap(dir: &Path) -> anyhow::Result<usize> {
    let mut n = 0;
    for z in 18u8..=20 {
        let (x0, y0) = operator_station::basemap::tile_of(
            common::geo::enu_to_lla(&DATUM, &nalgebra::Vector3::new(-16.0, 22.0, 0.0)).lat_deg,
            common::geo::enu_to_lla(&DATUM, &nalgebra::Vector3::new(-16.0, 22.0, 0.0)).lon_deg,
            z,
        );
        let se = common::geo::enu_to_lla(&DATUM, &nalgebra::Vector3::new(31.0, -16.0, 0.0));
        let (x1, y1) = operator_station::basemap::tile_of(se.lat_deg, se.lon_deg, z);
        for tx in x0..=x1 {
            for ty in y0..=y1 {
                let (la0, lo0) = operator_station::basemap::tile_corner(z, tx, ty);
                let (la1, lo1) = operator_station::basemap::tile_corner(z, tx + 1, ty + 1);
                let mut px = vec![0u8; 256 * 256 * 3];
                for r in 0..256usize {
                    for c in 0..256usize {
                        // Linear within a tile is far below a pixel at these zooms.
                        let lat = la0 + (la1 - la0) * (r as f64 + 0.5) / 256.0;
                        let lon = lo0 + (lo1 - lo0) * (c as f64 + 0.5) / 256.0;
                        let e = common::geo::lla_to_enu(
                            &DATUM,
                            &Datum {
                                lat_deg: lat,
                                lon_deg: lon,
                                h_m: DATUM.h_m,
                            },
                        );
                        let (x, y) = (e.x, e.y);
                        let noise = ((x * 7.3).sin() * (y * 5.1).cos() * 10.0) as i32;
                        let lane = |yc: f64| (y - yc).abs() < 0.9;
                        let boxed = |cx: f64, cy: f64, hx: f64, hy: f64| {
                            (x - cx).abs() < hx && (y - cy).abs() < hy
                        };
                        let grid = (x.rem_euclid(5.0) < 0.08) || (y.rem_euclid(5.0) < 0.08);
                        let rgb: [i32; 3] =
                            if boxed(7.0, 3.0, 0.5, 0.5) || boxed(16.0, 3.0, 1.0, 0.4) {
                                [70, 55, 40]
                            } else if lane(0.0) || lane(6.0) {
                                [176, 164, 138]
                            } else if grid {
                                [60, 90, 55]
                            } else {
                                [86, 128, 70]
                            };
                        let i = (r * 256 + c) * 3;
                        for k in 0..3 {
                            px[i + k] = (rgb[k] + noise).clamp(0, 255) as u8;
                        }
                    }
                }
                let p = dir.join(format!("{z}/{tx}"));
                std::fs::create_dir_all(&p)?;
                let f = File::create(p.join(format!("{ty}.png")))?;
                let mut e = png::Encoder::new(std::io::BufWriter::new(f), 256, 256);
                e.set_color(png::ColorType::Rgb);
                e.set_depth(png::BitDepth::Eight);
                e.write_header()?.write_image_data(&px)?;
                n += 1;
            }
        }
    }
    Ok(n)
}

#[test]
fn operator_day_in_the_browser() -> anyhow::Result<()> {
    let root = workspace_root();
    if let Some(why) = browser_unavailable(&root) {
        println!("skipping the browser test: {why}");
        return Ok(());
    }
    let build = Build::from_env();
    let artifacts = root.join(if build.baseline {
        "artifacts/ui-ops-baseline"
    } else {
        "artifacts/ui-ops"
    });
    std::fs::create_dir_all(&artifacts)?;
    let tmp = tempfile::tempdir()?;
    let basemap = tmp.path().join("basemap");
    let tiles = synthetic_basemap(&basemap)?;
    println!("synthetic basemap: {tiles} tiles");

    let mut station = StationProc {
        proc: None,
        http: free_port(),
        zenoh: free_port(),
        db: tmp.path().join("ops.sqlite"),
        basemap,
        log: artifacts.join("station"),
        n: 0,
    };
    station.start(&build)?;
    let endpoint = format!("tcp/127.0.0.1:{}", station.zenoh);
    let truth = artifacts.join("husky-1.truth");
    let _robot = KillOnDrop::spawn(
        Command::new(&build.agent)
            .current_dir(&root)
            .arg("sim")
            .arg("--scenario")
            .arg(root.join("config/scenarios/station-field.toml"))
            .args([
                "--robot",
                "husky-1",
                "--connect",
                &endpoint,
                "--start=0,0,0",
            ])
            .args(if build.baseline {
                vec![]
            } else {
                vec!["--truth-out".to_string(), truth.display().to_string()]
            })
            .arg("--exit-with-parent")
            .env("RUST_LOG", "info,zenoh=warn")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(File::create(artifacts.join("husky-1.log"))?),
    )
    .context("start the simulated robot")?;
    let stop_fleet = Arc::new(AtomicBool::new(false));
    let fleet = synthetic_fleet(
        endpoint.clone(),
        if build.baseline {
            1
        } else {
            msg::SCHEMA_VERSION as u8
        },
        stop_fleet.clone(),
    );

    let url = format!("http://127.0.0.1:{}/", station.http);
    let mut args = vec![
        root.join("web/tests/ops.mjs").display().to_string(),
        url,
        "--truth".into(),
        truth.display().to_string(),
    ];
    if build.baseline {
        args.push("--bugs-only".into());
        args.push("--keep-going".into());
    }
    let mut node = KillOnDrop::spawn(
        Command::new("node")
            .args(&args)
            .current_dir(&root)
            .env("TERRANAV_ARTIFACTS", &artifacts)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(File::create(artifacts.join("ops.stderr.log"))?),
    )
    .context("run node web/tests/ops.mjs (is node installed?)")?;
    let mut to_node = node.0.stdin.take().context("node stdin")?;
    let from_node = BufReader::new(node.0.stdout.take().context("node stdout")?);
    let mut out_log = File::create(artifacts.join("ops.stdout.log"))?;
    let started = Instant::now();
    // The script's control requests arrive on its stdout; everything else is its log.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for line in from_node.lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut all = String::new();
    let status = loop {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(line) => {
                writeln!(out_log, "{line}")?;
                println!("{line}");
                all.push_str(&line);
                all.push('\n');
                match line.trim() {
                    "@@ctl kill-station" => {
                        station.kill();
                        writeln!(to_node, "ok")?;
                    }
                    "@@ctl start-station" => {
                        station.start(&build)?;
                        writeln!(to_node, "ok")?;
                    }
                    _ => {}
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                break node.0.wait()?;
            }
        }
        if started.elapsed() > SCRIPT_LIMIT {
            bail!("web/tests/ops.mjs did not finish within {SCRIPT_LIMIT:?}");
        }
    };
    let _ = reader.join();
    stop_fleet.store(true, Ordering::Relaxed);
    let _ = fleet.join();
    let stderr = std::fs::read_to_string(artifacts.join("ops.stderr.log")).unwrap_or_default();
    println!("{stderr}");
    println!("browser test took {:.0} s", started.elapsed().as_secs_f64());
    if build.baseline {
        // The baseline is expected to fail; the script's summary lines say which checks did.
        return Ok(());
    }
    if !status.success() {
        bail!(
            "browser test failed ({status}); screenshots in {}:\n{stderr}",
            artifacts.display()
        );
    }
    assert!(all.contains("PASS"), "the script did not report PASS");
    Ok(())
}
