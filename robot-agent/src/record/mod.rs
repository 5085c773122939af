//! Recording a session to MCAP at the runtime's boundary, and replaying it through the runtime.
//!
//! - [`channels`]: the recording's channels and schemas.
//! - [`inputs`]: the runtime's inputs as messages and back, bit for bit.
//! - [`session`]: the recorder the loops call (inputs, commands, control periods, outputs).
//! - [`digest`]: what proves a replay reproduced the run.
//! - [`replay`]: `robot-agent run --replay`: a recording (or a ROS 2 bag, [`rosbag`]) through the
//!   runtime.
//!
//! A recording is self-contained: its `terranav.session` metadata holds the session's identity
//! and clock origin, its `terranav.config` the configuration files the agent ran with, and
//! `terranav.digest` (written at a clean end) the run's digest.

pub mod channels;
pub mod digest;
pub mod inputs;
pub mod replay;
pub mod rosbag;
pub mod session;

pub use digest::{Digest, RunDigest};
pub use session::{RecordSummary, SessionRecorder};

use crate::runtime::stamps::Topic;
use agent::{AgentConfig, Identity};
use common::msg::Datum;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Metadata record with the run's digest.
pub const DIGEST_METADATA: &str = "terranav.digest";
/// Metadata record with the configuration files.
pub const CONFIG_METADATA: &str = "terranav.config";

/// The configuration files an agent was built from.
pub const CONFIG_FILES: [&str; 6] = [
    "robot.toml",
    "slam.toml",
    "mapper.toml",
    "planner.toml",
    "control.toml",
    "mission.toml",
];

/// Where and how to record (`--mcap`, `--mcap-split-mb`, `--mcap-split-s`).
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// The file (or, split, the folder).
    pub path: PathBuf,
    /// Rotation.
    pub split: record::Split,
    /// The configuration files' texts by name (kept in the recording so that it replays alone).
    pub config_files: BTreeMap<String, String>,
}

impl RecordOptions {
    /// Recording to `path` of an agent configured from `dir` (robot file `robot_file`).
    pub fn new(path: PathBuf, split: record::Split, dir: &Path, robot_file: &Path) -> Self {
        Self {
            path,
            split,
            config_files: config_files(dir, robot_file),
        }
    }
}

/// The texts of the configuration files in `dir` (the robot file from `robot_file`); missing
/// files are left out (the agent took their defaults).
pub fn config_files(dir: &Path, robot_file: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for name in CONFIG_FILES {
        let path = if name == "robot.toml" {
            robot_file.to_path_buf()
        } else {
            dir.join(name)
        };
        if let Ok(text) = std::fs::read_to_string(&path) {
            out.insert(name.to_string(), text);
        }
    }
    out
}

/// A fingerprint of a configuration (every value, exactly): a replay with another one warns.
pub fn config_digest(cfg: &AgentConfig) -> String {
    use sha2::{Digest as _, Sha256};
    Sha256::digest(format!("{cfg:?}").as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// What a replay needs to know about the recorded session.
#[derive(Clone, Debug)]
pub struct SessionMeta {
    /// Robot, session id, start.
    pub identity: Identity,
    /// The header stamp of session time 0.
    pub t0_s: f64,
    /// The session record's `source`.
    pub source: String,
    /// The inputs the robot had (for the watchdog).
    pub inputs: Vec<Topic>,
    /// The configuration files.
    pub config_files: BTreeMap<String, String>,
    /// The datum the agent was given (not in the files: `--datum`, or the simulated world's).
    pub datum: Option<Datum>,
    /// [`config_digest`] of the agent's configuration.
    pub config_digest: String,
}

fn topic_name(t: Topic) -> String {
    t.to_string()
}

fn topic_of(s: &str) -> Option<Topic> {
    Topic::ALL.into_iter().find(|t| t.to_string() == s)
}

impl SessionMeta {
    /// The metadata records (name, values).
    pub fn to_metadata(&self) -> Vec<(String, BTreeMap<String, String>)> {
        let mut s = BTreeMap::new();
        s.insert("robot".into(), self.identity.robot.clone());
        s.insert("session_id".into(), self.identity.session_id.clone());
        s.insert(
            "start_unix_ms".into(),
            self.identity.start_unix_ms.to_string(),
        );
        // Rust prints an f64 in the shortest form that parses back to the same bits.
        s.insert("t0_s".into(), self.t0_s.to_string());
        s.insert("source".into(), self.source.clone());
        s.insert(
            "inputs".into(),
            self.inputs
                .iter()
                .map(|t| topic_name(*t))
                .collect::<Vec<_>>()
                .join(","),
        );
        s.insert(
            "datum".into(),
            self.datum
                .map(|d| format!("{},{},{}", d.lat_deg, d.lon_deg, d.h_m))
                .unwrap_or_default(),
        );
        s.insert("config_digest".into(), self.config_digest.clone());
        s.insert("agent_version".into(), env!("CARGO_PKG_VERSION").into());
        vec![
            (record::SESSION_METADATA.to_string(), s),
            (CONFIG_METADATA.to_string(), self.config_files.clone()),
        ]
    }

    /// Reads the session record back (the config files come from their own record).
    pub fn from_metadata(s: &BTreeMap<String, String>) -> anyhow::Result<Self> {
        let get = |k: &str| {
            s.get(k)
                .ok_or_else(|| anyhow::anyhow!("terranav.session metadata has no {k}"))
        };
        let datum = match get("datum")?.as_str() {
            "" => None,
            d => {
                let v: Vec<f64> = d
                    .split(',')
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .map_err(|_| anyhow::anyhow!("terranav.session: bad datum {d:?}"))?;
                anyhow::ensure!(v.len() == 3, "terranav.session: bad datum {d:?}");
                Some(Datum {
                    lat_deg: v[0],
                    lon_deg: v[1],
                    h_m: v[2],
                })
            }
        };
        Ok(Self {
            identity: Identity {
                robot: get("robot")?.clone(),
                session_id: get("session_id")?.clone(),
                start_unix_ms: get("start_unix_ms")?
                    .parse()
                    .map_err(|_| anyhow::anyhow!("terranav.session: bad start_unix_ms"))?,
            },
            t0_s: get("t0_s")?
                .parse()
                .map_err(|_| anyhow::anyhow!("terranav.session: bad t0_s"))?,
            source: get("source")?.clone(),
            inputs: get("inputs")?
                .split(',')
                .filter(|s| !s.is_empty())
                .map(|s| topic_of(s).ok_or_else(|| anyhow::anyhow!("unknown input {s:?}")))
                .collect::<anyhow::Result<_>>()?,
            config_files: BTreeMap::new(),
            datum,
            config_digest: get("config_digest")?.clone(),
        })
    }
}

/// The agent configuration of recorded configuration files (written to a temporary folder and
/// loaded as from disk, so that it is the same values) with `datum`.
pub fn config_from_files(
    files: &BTreeMap<String, String>,
    datum: Option<Datum>,
) -> anyhow::Result<(AgentConfig, crate::run::io_config::RunFile)> {
    let dir = tempfile_dir()?;
    for (name, text) in files {
        anyhow::ensure!(
            CONFIG_FILES.contains(&name.as_str()),
            "recorded configuration has an unknown file {name:?}"
        );
        std::fs::write(dir.join(name), text)?;
    }
    let robot = dir.join("robot.toml");
    let mut cfg = crate::config::load_agent_config_with(&dir, &robot)?;
    let run = crate::config::load_run_file(&robot)?;
    let _ = std::fs::remove_dir_all(&dir);
    cfg.datum = datum;
    Ok((cfg, run))
}

fn tempfile_dir() -> std::io::Result<PathBuf> {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let d = std::env::temp_dir().join(format!(
        "terranav-replay-config-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}

/// `--mcap-split-mb` and `--mcap-split-s` as a [`record::Split`].
pub fn split(mb: Option<f64>, s: Option<f64>) -> anyhow::Result<record::Split> {
    for (name, v) in [("--mcap-split-mb", mb), ("--mcap-split-s", s)] {
        if let Some(v) = v {
            anyhow::ensure!(v.is_finite() && v > 0.0, "{name} must be > 0");
        }
    }
    Ok(record::Split {
        max_bytes: mb.map(|m| (m * 1e6) as u64),
        max_duration_s: s,
    })
}

/// Recording flags shared by `run` and `sim`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct McapArgs {
    /// Record the session to this MCAP file (with --mcap-split-*: a folder of files).
    #[arg(long, value_name = "PATH")]
    pub mcap: Option<PathBuf>,
    /// Start a new file of the recording every this many megabytes.
    #[arg(long, value_name = "MB", requires = "mcap")]
    pub mcap_split_mb: Option<f64>,
    /// Start a new file of the recording every this many seconds.
    #[arg(long, value_name = "S", requires = "mcap")]
    pub mcap_split_s: Option<f64>,
}

impl McapArgs {
    /// The options, for an agent configured from `dir` with robot file `robot_file`.
    pub fn options(&self, dir: &Path, robot_file: &Path) -> anyhow::Result<Option<RecordOptions>> {
        let Some(path) = &self.mcap else {
            return Ok(None);
        };
        Ok(Some(RecordOptions::new(
            path.clone(),
            split(self.mcap_split_mb, self.mcap_split_s)?,
            dir,
            robot_file,
        )))
    }
}
