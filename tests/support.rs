//! Helpers for the cross-process tests: find the built binaries, the shared test data, free ports,
//! and run child processes that are killed when the test ends.
//!
//! The binaries are not built by `cargo test` for another package, so the README's test command
//! builds them first (`cargo build --release --bins`); [`bin`] finds them next to the test executable.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};

/// Root of the workspace.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ is inside the workspace")
        .to_path_buf()
}

/// `../shared/data` next to the project, or None (with a printed notice naming `what`) when absent.
/// Under CI (`CI=true`) the data must be there: a missing folder fails the test instead.
pub fn shared_data(what: &str) -> Option<PathBuf> {
    common::shared_data::locate(env!("CARGO_MANIFEST_DIR"), "", what)
}

/// Path of a workspace binary (`robot-agent`, `operator-station`) built in the same profile as the test.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test> -> target/<profile>/<name>
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("test executable lives in target/<profile>/deps");
    let p = dir.join(name);
    assert!(
        p.exists(),
        "{} not built: run `cargo build --release --bins` first (the README's test command does)",
        p.display()
    );
    p
}

/// Runs `robot-agent ARGS` in the workspace root, asserts it succeeded, and parses the last line
/// of its standard output as JSON (the `--json` / headless report).
pub fn robot_agent_json(args: &[&str]) -> serde_json::Value {
    let out = Command::new(bin("robot-agent"))
        .current_dir(workspace_root())
        .args(args)
        .output()
        .expect("run robot-agent");
    assert!(
        out.status.success(),
        "robot-agent {args:?} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().expect("a JSON line");
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

/// The number `k` of a JSON report, panicking with the report when it is missing.
pub fn num(v: &serde_json::Value, k: &str) -> f64 {
    v[k].as_f64()
        .unwrap_or_else(|| panic!("{k} missing in {v}"))
}

/// A TCP port that was free a moment ago on 127.0.0.1, never the same twice in one test binary:
/// the kernel may hand a port just released to the next bind, and two tests running side by side
/// once got the same one (the second's session then connected to the first's listener and heard
/// nothing of its own).
pub fn free_port() -> u16 {
    static GIVEN: std::sync::Mutex<Vec<u16>> = std::sync::Mutex::new(Vec::new());
    let mut given = GIVEN.lock().unwrap_or_else(|e| e.into_inner());
    loop {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("bind an ephemeral port");
        if !given.contains(&port) {
            given.push(port);
            return port;
        }
    }
}

/// A child process killed (and reaped) when dropped, so a failing test leaves nothing running.
pub struct KillOnDrop(pub Child);

impl KillOnDrop {
    /// Spawns `cmd`.
    pub fn spawn(cmd: &mut Command) -> anyhow::Result<Self> {
        Ok(Self(cmd.spawn()?))
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
