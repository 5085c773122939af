//! The agent's configuration files: `config/robot.toml`, `slam.toml`, `mapper.toml`,
//! `planner.toml`, `control.toml` and `mission.toml`, each optional (every value has the
//! default in code, docs/algorithms.md), read here and nowhere else.

use agent::{AgentConfig, MissionFile};
use std::path::{Path, PathBuf};

/// Why the configuration could not be loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// A file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// A file has an unknown key or a bad value.
    #[error("{path}: {msg}")]
    Parse {
        /// File.
        path: String,
        /// What is wrong (names the key).
        msg: String,
    },
}

/// Reads one TOML file of `dir` into `T`; a missing file gives the defaults.
pub fn load<T: serde::de::DeserializeOwned + Default>(
    dir: &Path,
    name: &str,
) -> Result<T, ConfigError> {
    let path = dir.join(name);
    if !path.exists() {
        return Ok(T::default());
    }
    let text = std::fs::read_to_string(&path).map_err(|source| ConfigError::Io {
        path: path.display().to_string(),
        source,
    })?;
    toml::from_str(&text).map_err(|e| ConfigError::Parse {
        path: path.display().to_string(),
        msg: e.to_string(),
    })
}

/// The `config/` folder of the workspace, found from the current directory or the executable.
pub fn default_config_dir() -> PathBuf {
    let candidates = [
        std::env::current_dir().ok(),
        std::env::current_exe()
            .ok()
            .and_then(|e| e.parent().map(Path::to_path_buf)),
    ];
    for start in candidates.into_iter().flatten() {
        for dir in start.ancestors() {
            let c = dir.join("config");
            if c.join("robot.toml").exists() {
                return c;
            }
        }
    }
    PathBuf::from("config")
}

/// Sections of `robot.toml` that configure the runtime, not the robot's body.
const RUN_SECTIONS: [&str; 3] = ["io", "runtime", "bus"];

/// The robot file as a table (empty when the file is missing).
fn robot_table(path: &Path) -> Result<(String, toml::Table), ConfigError> {
    let shown = path.display().to_string();
    if !path.exists() {
        return Ok((shown, toml::Table::new()));
    }
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: shown.clone(),
        source,
    })?;
    let table = text
        .parse::<toml::Table>()
        .map_err(|e| ConfigError::Parse {
            path: shown.clone(),
            msg: e.to_string(),
        })?;
    Ok((shown, table))
}

fn section<T: serde::de::DeserializeOwned + Default>(
    path: &str,
    table: &toml::Table,
    name: &str,
) -> Result<T, ConfigError> {
    match table.get(name) {
        None => Ok(T::default()),
        Some(v) => v.clone().try_into().map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            msg: format!("[{name}]: {e}"),
        }),
    }
}

/// The robot profile: `robot.toml` without its runtime sections.
fn load_profile(robot_file: &Path) -> Result<common::robot::RobotProfile, ConfigError> {
    let (path, mut table) = robot_table(robot_file)?;
    for s in RUN_SECTIONS {
        table.remove(s);
    }
    toml::Value::Table(table)
        .try_into()
        .map_err(|e| ConfigError::Parse {
            path,
            msg: e.to_string(),
        })
}

/// The `[io]`, `[runtime]` and `[bus]` sections of the robot file (`robot-agent run`).
pub fn load_run_file(robot_file: &Path) -> Result<crate::run::io_config::RunFile, ConfigError> {
    let (path, table) = robot_table(robot_file)?;
    Ok(crate::run::io_config::RunFile {
        io: section(&path, &table, "io")?,
        runtime: section(&path, &table, "runtime")?,
        bus: section(&path, &table, "bus")?,
    })
}

/// Loads the agent's configuration from `dir` (missing files keep the defaults).
pub fn load_agent_config(dir: &Path) -> Result<AgentConfig, ConfigError> {
    load_agent_config_with(dir, &dir.join("robot.toml"))
}

/// As [`load_agent_config`], with the robot file at `robot_file` (another robot's profile next
/// to the shared algorithm files).
pub fn load_agent_config_with(dir: &Path, robot_file: &Path) -> Result<AgentConfig, ConfigError> {
    Ok(AgentConfig::from_parts(
        load_profile(robot_file)?,
        load(dir, "slam.toml")?,
        load(dir, "mapper.toml")?,
        load(dir, "planner.toml")?,
        load(dir, "control.toml")?,
        load::<MissionFile>(dir, "mission.toml")?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use agent::localiser::gnss::GnssConfig;
    use agent::mission::navigate::NavConfig;
    use agent::mission::repeat::RepeatConfig;
    use agent::mission::teach::TeachConfig;

    fn shipped() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
    }

    #[test]
    fn shipped_config_loads() {
        let c = load_agent_config(&shipped()).unwrap();
        assert_eq!(c.slam.sensor.lidar_xyz_m, c.profile.lidar.xyz_m);
        assert!((c.deadman_s - 0.3).abs() < 1e-12);
    }

    #[test]
    fn shipped_control_and_mission_files_are_the_code_defaults() {
        // The files document the defaults; a change to one must be made to both.
        let control: control::Config = load(&shipped(), "control.toml").unwrap();
        assert_eq!(control, control::Config::default());
        let mission: MissionFile = load(&shipped(), "mission.toml").unwrap();
        assert_eq!(mission.navigate, NavConfig::default());
        assert_eq!(mission.teach, TeachConfig::default());
        assert_eq!(mission.repeat, RepeatConfig::default());
        assert_eq!(mission.gnss, GnssConfig::default());
    }

    #[test]
    fn run_sections_load_and_refuse_unknown_keys() {
        let run = load_run_file(&shipped().join("robot.toml")).unwrap();
        assert_eq!(run.io, crate::run::io_config::IoConfig::default());
        assert_eq!(run.bus, crate::bus::BusFile::default());
        assert_eq!(
            run.runtime.limits().unwrap(),
            crate::runtime::RuntimeLimits::default()
        );
        let d = tempfile::tempdir().unwrap();
        let body = std::fs::read_to_string(shipped().join("robot.toml")).unwrap();
        std::fs::write(
            d.path().join("robot.toml"),
            body.replace("lidar_timeout_s = 0.5", "lidar_timeout_s = 0.8"),
        )
        .unwrap();
        let run = load_run_file(&d.path().join("robot.toml")).unwrap();
        assert_eq!(run.runtime.lidar_timeout_s, 0.8);
        // The profile still loads from the same file.
        assert_eq!(
            load_agent_config(d.path()).unwrap().profile.name,
            "husky-a200"
        );
        std::fs::write(d.path().join("robot.toml"), "[io]\nlidarr = \"x\"\n").unwrap();
        let e = load_run_file(&d.path().join("robot.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("robot.toml") && e.contains("lidarr"), "{e}");
    }

    #[test]
    fn unknown_keys_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("mission.toml"), "bogus = 1\n").unwrap();
        let e = load_agent_config(d.path()).unwrap_err().to_string();
        assert!(e.contains("mission.toml") && e.contains("bogus"), "{e}");
    }
}
