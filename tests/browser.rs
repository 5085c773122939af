//! Browser test of the operator UI: `operator-station demo --robots 1` (station plus one simulated
//! robot over Zenoh on loopback) and Debian's chromium driven by `node web/tests/ui.mjs`
//! (playwright-core). The page must show tiles and the robot within 10 s of the demo start, send a
//! goal on a map click and draw the planned path, and stop the robot with the STOP button.
//! Screenshots and the demo's log land in `artifacts/ui/` (git-ignored, uploaded by CI).
//!
//! Skips with a notice only when `/usr/bin/chromium` or `web/node_modules` is missing; CI installs
//! both, so there a missing piece never hides a failure.

mod browser_support;

use std::fs::File;
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context};
use browser_support::{browser_unavailable, run_ui_script};
use support::{bin, free_port, workspace_root, KillOnDrop};

/// Upper bound for the whole node script; its own steps time out well before this.
const UI_TEST_LIMIT: Duration = Duration::from_secs(150);
/// How long the station may take to accept connections.
const STATION_START_LIMIT: Duration = Duration::from_secs(30);

fn unix_ms() -> u128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis())
        .unwrap_or(0)
}

fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

#[test]
fn operator_ui_shows_map_and_robot_sends_goal_and_stops() -> anyhow::Result<()> {
    let root = workspace_root();
    if let Some(why) = browser_unavailable(&root) {
        println!("skipping browser test: {why}");
        return Ok(());
    }
    let artifacts = root.join("artifacts/ui");
    std::fs::create_dir_all(&artifacts)?;
    let demo_log = artifacts.join("demo.log");

    let port = free_port();
    let since_ms = unix_ms();
    let mut demo = KillOnDrop::spawn(
        Command::new(bin("operator-station"))
            .args(["demo", "--robots", "1", "--port", &port.to_string()])
            .current_dir(&root)
            .stdin(Stdio::null())
            .stdout(File::create(&demo_log)?)
            .stderr(File::create(artifacts.join("demo.stderr.log"))?),
    )
    .context("start operator-station demo")?;

    // The station must accept connections; a demo that dies early fails here with its log.
    let start = Instant::now();
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        if let Some(status) = demo.0.try_wait()? {
            bail!(
                "operator-station demo exited with {status} before serving:\n{}\n{}",
                tail(&demo_log, 20),
                tail(&artifacts.join("demo.stderr.log"), 20)
            );
        }
        if start.elapsed() > STATION_START_LIMIT {
            bail!(
                "operator-station demo did not accept connections on port {port} within {STATION_START_LIMIT:?}:\n{}",
                tail(&artifacts.join("demo.stderr.log"), 20)
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }

    let url = format!("http://127.0.0.1:{port}/");
    run_ui_script(
        &root,
        "ui.mjs",
        &[url, "--since-ms".into(), since_ms.to_string()],
        &artifacts,
        UI_TEST_LIMIT,
    )
    .with_context(|| format!("demo log tail:\n{}", tail(&demo_log, 15)))?;
    // The demo must still be running: the UI test passing against a dying station proves little.
    assert!(
        demo.0.try_wait()?.is_none(),
        "operator-station demo exited during the browser test"
    );
    Ok(())
}

/// The UI's WGS-84 helpers (`web/geo.js`) against the reference vectors: run through node so that
/// `cargo test` covers them too. Needs only node, not the browser or `node_modules`.
#[test]
fn web_geo_helpers_match_reference_vectors() -> anyhow::Result<()> {
    let root = workspace_root();
    let out = match Command::new("node")
        .args(["--test", "web/tests/geo.test.mjs"])
        .current_dir(&root)
        .stdin(Stdio::null())
        .output()
    {
        Ok(out) => out,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            println!("skipping web_geo_helpers_match_reference_vectors: node is not installed");
            return Ok(());
        }
        Err(e) => return Err(e).context("run node --test"),
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        out.status.success(),
        "node --test web/tests/geo.test.mjs failed"
    );
    // node:test reports a skip (no ../shared/data) as a pass; say which one happened.
    assert!(stdout.contains("# pass"), "unexpected node --test output");
    Ok(())
}
