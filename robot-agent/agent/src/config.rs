//! The agent's configuration: one struct of the parts' own configurations (each part receives only
//! its own), every value with its default in code (docs/algorithms.md). The robot agent's binary
//! reads them from the TOML files in `config/`.

use crate::localiser::gnss::GnssConfig;
use crate::mission::navigate::NavConfig;
use crate::mission::repeat::RepeatConfig;
use crate::mission::teach::TeachConfig;
use common::msg::Datum;
use serde::Deserialize;

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
    pub profile: common::robot::RobotProfile,
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
    /// Teleop deadman, seconds (architecture: 300 ms).
    pub deadman_s: f64,
    /// How long the safety stop trusts one sweep, seconds.
    pub safety_scan_timeout_s: f64,
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self::from_parts(
            common::robot::RobotProfile::default(),
            slam::Config::default(),
            mapping::Config::default(),
            planning::PlannerConfig::default(),
            control::Config::default(),
            MissionFile::default(),
        )
    }
}

impl AgentConfig {
    /// Combines the parts, deriving what one part says about another (sensor mounting, body
    /// size) from the robot profile so it is written once.
    pub fn from_parts(
        profile: common::robot::RobotProfile,
        slam: slam::Config,
        mapper: mapping::Config,
        planner: planning::PlannerConfig,
        control: control::Config,
        mission: MissionFile,
    ) -> Self {
        let mut c = Self {
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
        };
        c.derive_from_profile();
        c
    }

    /// The same configuration with another mapper configuration (`map eval --config`).
    pub fn with_mapper(mut self, mapper: mapping::Config) -> Self {
        self.mapper = mapper;
        self.derive_from_profile();
        self
    }

    /// Writes what the robot profile says about the other parts into them, so it is written
    /// once: the lidar mount (SLAM, mapper) and the body (mapper).
    fn derive_from_profile(&mut self) {
        let p = &self.profile;
        self.slam.sensor.lidar_xyz_m = p.lidar.xyz_m;
        self.slam.sensor.lidar_rpy_rad = p.lidar.rpy_deg.map(f64::to_radians);
        self.mapper.sensor_height_m = p.lidar.xyz_m[2];
        self.mapper.footprint_length_m = p.length_m;
        self.mapper.footprint_width_m = p.width_m;
        self.mapper.h_r_m = p.height_m;
        // mapper.max_step_m stays the mapper's own: it is the step test's threshold, set below
        // the profile's unclimbable step so that a 10 cm curb measured at 9 cm still counts.
    }
}
