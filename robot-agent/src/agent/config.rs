//! The agent's configuration, assembled from the TOML files in `config/` (each optional; every
//! value has the methods.md default in code).

use crate::mission::gnss::GnssConfig;
use crate::mission::navigate::NavConfig;
use crate::mission::repeat::RepeatConfig;
use crate::mission::teach::TeachConfig;
use common::msg::Datum;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// `config/mission.toml`: the mission layer's parameters.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MissionFile {
    /// Go-to-goal.
    pub navigate: NavConfig,
    /// Teach.
    pub teach: TeachConfig,
    /// Repeat.
    pub repeat: RepeatConfig,
    /// GNSS handling.
    pub gnss: GnssConfig,
    /// Teleop deadman: silence longer than this stops the robot, seconds.
    pub deadman_s: Option<f64>,
    /// The safety stop trusts a sweep for this long, seconds.
    pub safety_scan_timeout_s: Option<f64>,
}

/// Everything one robot agent needs.
#[derive(Clone, Debug)]
pub struct AgentConfig {
    /// Body and sensor mounting.
    pub profile: sim::RobotProfile,
    /// SLAM.
    pub slam: slam::Config,
    /// Traversability mapping.
    pub mapper: mapping::Config,
    /// Planning.
    pub planner: planning::PlannerConfig,
    /// Path following and safety.
    pub control: control::Config,
    /// Go-to-goal mission.
    pub nav: NavConfig,
    /// Teach.
    pub teach: TeachConfig,
    /// Repeat.
    pub repeat: RepeatConfig,
    /// GNSS.
    pub gnss: GnssConfig,
    /// The operator-set datum shared by several robots; None: the first fix.
    pub datum: Option<Datum>,
    /// Primary GNSS antenna in base_link, metres.
    pub gnss_antenna_xyz_m: [f64; 3],
    /// Teleop deadman, seconds (architecture: 300 ms).
    pub deadman_s: f64,
    /// How long the safety stop trusts one sweep, seconds.
    pub safety_scan_timeout_s: f64,
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self::from_parts(
            sim::RobotProfile::default(),
            slam::Config::default(),
            mapping::Config::default(),
            planning::PlannerConfig::default(),
            control::Config::default(),
            MissionFile::default(),
        )
    }
}

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

fn load<T: serde::de::DeserializeOwned + Default>(
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

impl AgentConfig {
    /// Loads `robot.toml`, `slam.toml`, `mapper.toml`, `planner.toml`, `control.toml` and
    /// `mission.toml` from `dir` (missing files keep the defaults).
    pub fn load_dir(dir: &Path) -> Result<Self, ConfigError> {
        Ok(Self::from_parts(
            load(dir, "robot.toml")?,
            load(dir, "slam.toml")?,
            load(dir, "mapper.toml")?,
            load(dir, "planner.toml")?,
            load(dir, "control.toml")?,
            load(dir, "mission.toml")?,
        ))
    }

    /// Combines the parts, deriving what one part says about another (sensor mounting, body
    /// size) from the robot profile so it is written once.
    pub fn from_parts(
        profile: sim::RobotProfile,
        mut slam: slam::Config,
        mut mapper: mapping::Config,
        planner: planning::PlannerConfig,
        control: control::Config,
        mission: MissionFile,
    ) -> Self {
        slam.sensor.lidar_xyz_m = profile.lidar.xyz_m;
        slam.sensor.lidar_rpy_rad = profile.lidar.rpy_deg.map(f64::to_radians);
        mapper.sensor_height_m = profile.lidar.xyz_m[2];
        mapper.footprint_length_m = profile.length_m;
        mapper.footprint_width_m = profile.width_m;
        mapper.h_r_m = profile.height_m;
        // mapper.max_step_m stays the mapper's own: it is the step test's threshold, set below
        // the profile's unclimbable step so that a 10 cm curb measured at 9 cm still counts.
        Self {
            gnss_antenna_xyz_m: profile.gnss.primary_xyz_m,
            profile,
            slam,
            mapper,
            planner,
            control,
            nav: mission.navigate,
            teach: mission.teach,
            repeat: mission.repeat,
            gnss: mission.gnss,
            datum: None,
            deadman_s: mission.deadman_s.unwrap_or(0.3),
            safety_scan_timeout_s: mission.safety_scan_timeout_s.unwrap_or(0.35),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_config_loads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
        let c = AgentConfig::load_dir(&dir).unwrap();
        assert_eq!(c.slam.sensor.lidar_xyz_m, c.profile.lidar.xyz_m);
        assert!((c.deadman_s - 0.3).abs() < 1e-12);
    }

    #[test]
    fn shipped_control_and_mission_files_are_the_code_defaults() {
        // The files document the defaults; a change to one must be made to both.
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config");
        let control: control::Config = load(&dir, "control.toml").unwrap();
        assert_eq!(control, control::Config::default());
        let mission: MissionFile = load(&dir, "mission.toml").unwrap();
        assert_eq!(mission.navigate, NavConfig::default());
        assert_eq!(mission.teach, TeachConfig::default());
        assert_eq!(mission.repeat, RepeatConfig::default());
        assert_eq!(mission.gnss, GnssConfig::default());
    }

    #[test]
    fn unknown_keys_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("mission.toml"), "bogus = 1\n").unwrap();
        let e = AgentConfig::load_dir(d.path()).unwrap_err().to_string();
        assert!(e.contains("mission.toml") && e.contains("bogus"), "{e}");
    }
}
