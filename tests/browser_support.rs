//! What the browser tests share: whether chromium and the web modules are here, and running one of
//! the `web/tests/*.mjs` scripts against a station, its output kept as artifacts.
#![allow(dead_code)]

use std::fs::File;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

use support::KillOnDrop;

/// Debian's chromium, which `.ci/run` installs and the scripts drive through playwright-core.
pub const CHROMIUM: &str = "/usr/bin/chromium";

/// Why the browser tests cannot run on this machine (a notice to print), or `None` when they can.
pub fn browser_unavailable(root: &Path) -> Option<String> {
    if !Path::new(CHROMIUM).exists() {
        return Some(format!("{CHROMIUM} is missing (apt-get install chromium)"));
    }
    let modules = root.join("web/node_modules");
    if !modules.join("playwright-core").is_dir() || !modules.join("leaflet").is_dir() {
        return Some("web/node_modules is missing (cd web && npm ci)".into());
    }
    None
}

/// Runs `node web/tests/<script> <args>` from the workspace root with `TERRANAV_ARTIFACTS` set,
/// its stdout and stderr kept in `artifacts/<stem>.stdout.log` and `.stderr.log` and printed
/// through the harness (so `cargo test` shows them on failure). Fails when the script fails or
/// runs longer than `limit`, with its stderr in the error.
pub fn run_ui_script(
    root: &Path,
    script: &str,
    args: &[String],
    artifacts: &Path,
    limit: Duration,
) -> anyhow::Result<()> {
    let stem = Path::new(script)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("ui");
    let out = artifacts.join(format!("{stem}.stdout.log"));
    let err = artifacts.join(format!("{stem}.stderr.log"));
    let mut ui = KillOnDrop::spawn(
        Command::new("node")
            .arg(root.join("web/tests").join(script))
            .args(args)
            .current_dir(root)
            .env("TERRANAV_ARTIFACTS", artifacts)
            .stdin(Stdio::null())
            .stdout(File::create(&out)?)
            .stderr(File::create(&err)?),
    )
    .with_context(|| format!("run node web/tests/{script} (is node installed?)"))?;
    let started = Instant::now();
    let status = loop {
        if let Some(s) = ui.0.try_wait()? {
            break Some(s);
        }
        if started.elapsed() > limit {
            break None;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    println!("{}", std::fs::read_to_string(&out).unwrap_or_default());
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    println!("{stderr}");
    match status {
        None => bail!("web/tests/{script} did not finish within {limit:?}"),
        Some(s) if !s.success() => bail!(
            "web/tests/{script} failed ({s}); screenshots in {}:\n{stderr}",
            artifacts.display()
        ),
        Some(_) => Ok(()),
    }
}
