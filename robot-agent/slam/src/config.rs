//! SLAM configuration. `Default` is the real robot's configuration (docs/algorithms.md §3); each
//! stage receives only its own section.

use serde::{Deserialize, Deserializer};

/// A parameter that is either set (a number in the TOML) or derived from the data as it comes
/// (`"auto"`, or the key absent): see [`crate::adaptive`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Auto<T> {
    /// Derived from the data.
    #[default]
    Auto,
    /// Set by the configuration.
    Fixed(T),
}

impl<T: Copy> Auto<T> {
    /// The fixed value, `None` when automatic.
    pub fn fixed(&self) -> Option<T> {
        match self {
            Auto::Auto => None,
            Auto::Fixed(v) => Some(*v),
        }
    }
}

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Auto<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw<T> {
            Value(T),
            Word(String),
        }
        match Raw::<T>::deserialize(d)? {
            Raw::Value(v) => Ok(Auto::Fixed(v)),
            Raw::Word(w) if w == "auto" => Ok(Auto::Auto),
            Raw::Word(w) => Err(serde::de::Error::custom(format!(
                "expected a number or \"auto\", got {w:?}"
            ))),
        }
    }
}

/// All SLAM parameters, one TOML table per stage (see `config/slam.toml`).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Sensor mounting.
    pub sensor: SensorConfig,
    /// Reading (input scan) filters.
    pub filters: FilterConfig,
    /// ICP matcher, outlier rejection, minimiser and checkers.
    pub icp: IcpConfig,
    /// Map maintenance.
    pub map: MapConfig,
    /// Dynamic-point model.
    pub dynamic: DynamicConfig,
    /// The frame's roll and pitch from the IMU's accelerometer.
    pub gravity: crate::gravity::GravityConfig,
    /// The pose graph behind the odometry (used by the agent, not by [`crate::Slam`]).
    pub graph: crate::graph::GraphConfig,
    /// How the `"auto"` keys are derived from the data.
    pub adaptive: crate::adaptive::AdaptiveConfig,
}

/// Where the LiDAR sits on the robot.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// Position of the lidar frame in base_link, metres.
    pub lidar_xyz_m: [f64; 3],
    /// Orientation of the lidar frame in base_link (roll, pitch, yaw), radians.
    pub lidar_rpy_rad: [f64; 3],
    /// De-skew swept scans with per-point time stamps (skipped anyway when all are zero).
    pub deskew: bool,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            lidar_xyz_m: [0.0; 3],
            lidar_rpy_rad: [0.0; 3],
            deskew: true,
        }
    }
}

/// Reading filters, applied in this order.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct FilterConfig {
    /// Keep every n-th point (1 keeps all).
    pub keep_every_n: usize,
    /// Robot body box in base_link, metres: points inside are removed.
    pub robot_box_min_m: [f64; 3],
    /// Upper corner of the robot body box, metres.
    pub robot_box_max_m: [f64; 3],
    /// Points closer than this to the sensor are dropped, metres.
    pub min_range_m: f64,
    /// Points farther than this from the sensor are dropped, metres.
    pub max_range_m: f64,
    /// Random sampling: probability to keep a point.
    pub keep_probability: f64,
    /// Seed of the sampling RNG (deterministic replays).
    pub seed: u64,
    /// Voxel grid: one point per cube of this size, metres (0 disables; `"auto"`: from the scan's
    /// extent when it has more points than `adaptive.point_budget`).
    pub voxel_size_m: Auto<f64>,
    /// Neighbours used for surface normals (PCA).
    pub normal_knn: usize,
    /// Normal neighbours are searched only this far, metres (0: unbounded). Bounding the search
    /// makes it ~2x cheaper on dense clouds; points with fewer than 3 neighbours are dropped.
    pub normal_max_dist_m: f64,
    /// Max density, points per cubic metre (0 disables): denser points are thinned at random.
    pub max_density_per_m3: f64,
    /// A normal is trusted only when its neighbourhood spreads in two directions: second / largest
    /// PCA variance at least this (a lone lidar ring is a line and its PCA "normal" is noise).
    pub normal_min_spread: f32,
    /// ...and is thin: smallest / second PCA variance at most this.
    pub normal_max_thickness: f32,
}

impl Default for FilterConfig {
    fn default() -> Self {
        Self {
            keep_every_n: 3,
            robot_box_min_m: [-0.5, -0.3, -0.3],
            robot_box_max_m: [0.5, 0.3, 0.3],
            min_range_m: 0.0,
            max_range_m: 100.0,
            keep_probability: 0.7,
            seed: 1,
            voxel_size_m: Auto::Auto,
            normal_knn: 12,
            normal_max_dist_m: 2.0,
            max_density_per_m3: 10.0,
            normal_min_spread: 0.05,
            normal_max_thickness: 0.25,
        }
    }
}

/// ICP parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct IcpConfig {
    /// Map neighbours per reading point.
    pub knn: usize,
    /// Max matching distance, metres (`"auto"`: from the recent motion-prediction error, see
    /// `[adaptive]`).
    pub max_match_dist_m: Auto<f64>,
    /// Cauchy scale `k` on residuals divided by their robust scale.
    pub cauchy_k: f64,
    /// Lower bound of the robust residual scale, metres (keeps converged scans from over-trusting).
    pub min_residual_scale_m: f64,
    /// Reject pairs whose normals differ by more than this, radians.
    pub max_normal_angle_rad: f64,
    /// Differential checker: stop when the step rotates less than this, radians...
    pub min_step_rot_rad: f64,
    /// ...and translates less than this, metres.
    pub min_step_trans_m: f64,
    /// Counter checker: max iterations.
    pub max_iterations: usize,
    /// Bound checker: fail when the correction from the prior exceeds this rotation, radians...
    pub max_correction_rot_rad: f64,
    /// ...or this translation, metres.
    pub max_correction_trans_m: f64,
    /// Failure when fewer reading points than this found a partner.
    pub min_matched_points: usize,
    /// Failure when the weighted share of matched reading points falls below this.
    pub min_inlier_ratio: f64,
    /// Degenerate geometry when the smallest/largest Hessian eigenvalue ratio is below this;
    /// the update is then not applied along directions under this share of the largest
    /// eigenvalue (the prior is kept there).
    pub degenerate_eig_ratio: f64,
    /// Directions with an eigenvalue under this share of the largest (and over
    /// `degenerate_eig_ratio`) are weak: followed, but only so far in one registration...
    pub weak_eig_ratio: f64,
    /// ...as this many of the data's own standard deviations along them (the robust residual
    /// scale over the square root of the eigenvalue).
    pub weak_max_sigmas: f64,
}

impl IcpConfig {
    /// The matching distance in metres; an unresolved `"auto"` (a caller that keeps no adaptive
    /// state, e.g. a single registration) is the adaptive initial gate.
    pub fn match_dist_m(&self) -> f64 {
        self.max_match_dist_m
            .fixed()
            .unwrap_or_else(|| crate::adaptive::AdaptiveConfig::default().initial_match_dist_m)
    }
}

impl Default for IcpConfig {
    fn default() -> Self {
        Self {
            knn: 7,
            max_match_dist_m: Auto::Auto,
            cauchy_k: 3.0,
            min_residual_scale_m: 0.02,
            max_normal_angle_rad: 0.42,
            min_step_rot_rad: 0.001,
            min_step_trans_m: 0.01,
            max_iterations: 40,
            max_correction_rot_rad: 0.9,
            max_correction_trans_m: 10.0,
            min_matched_points: 30,
            min_inlier_ratio: 0.2,
            degenerate_eig_ratio: 1e-3,
            weak_eig_ratio: 1e-2,
            weak_max_sigmas: 3.0,
        }
    }
}

/// Map maintenance. Map normals are PCA fits over the map's own points (the source's "map filters:
/// surface normals", docs/algorithms.md §3.4), refreshed where new points arrive: the map has seen
/// the ground from many poses, a single sparse scan only along its rings.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MapConfig {
    /// A reading point joins the map only when farther than this from every map point, metres
    /// (`"auto"`: a share of the reading's voxel, see `[adaptive]`).
    pub min_dist_new_point_m: Auto<f64>,
    /// Only reading points closer than this to the sensor join the map, metres.
    pub sensor_max_range_m: f64,
    /// Map points farther than this from the sensor are dropped, metres.
    pub distance_limit_m: f64,
    /// Radius of the map cloud handed to the traversability mapper, metres (0: no cloud).
    pub output_radius_m: f64,
    /// Spatial index of the map.
    pub index: MapIndexKind,
    /// A scan updates the map once the sensor moved this far since the last update, metres...
    pub update_min_travel_m: f64,
    /// ...or turned this much, radians...
    pub update_min_rotation_rad: f64,
    /// ...or this much time passed, seconds. Every scan is localised; only these update the map
    /// (the source robot mapped at 0.65 Hz and localised at 6.5 Hz, docs/algorithms.md §3.1).
    pub update_max_interval_s: f64,
    /// Map neighbours per surface normal.
    pub normal_knn: usize,
    /// Map normal neighbours are searched only this far, metres.
    pub normal_max_dist_m: f64,
    /// Planarity test of map normals, as `filters.normal_min_spread` (untrusted normals are zero
    /// and the point is not used as a plane).
    pub normal_min_spread: f32,
    /// As `filters.normal_max_thickness`.
    pub normal_max_thickness: f32,
}

/// Spatial index used for the map (both measured; see the crate docs for the numbers).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum MapIndexKind {
    /// kiddo KD-tree rebuilt after each map update.
    #[default]
    KdTree,
    /// Voxel hash with cubes of the matching distance.
    Voxel,
}

impl Default for MapConfig {
    fn default() -> Self {
        Self {
            min_dist_new_point_m: Auto::Auto,
            sensor_max_range_m: 30.0,
            distance_limit_m: 30.0,
            output_radius_m: 20.0,
            index: MapIndexKind::KdTree,
            update_min_travel_m: 0.5,
            update_min_rotation_rad: 0.15,
            update_max_interval_s: 1.5,
            normal_knn: 12,
            normal_max_dist_m: 1.5,
            normal_min_spread: 0.05,
            normal_max_thickness: 0.25,
        }
    }
}

/// Dynamic points (ray model, docs/algorithms.md §3.5).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct DynamicConfig {
    /// Run the dynamic-point update.
    pub enabled: bool,
    /// Beam half angle `theta_max`, radians.
    pub beam_half_angle_rad: f64,
    /// P(static stays static).
    pub alpha: f64,
    /// P(dynamic stays dynamic).
    pub beta: f64,
    /// Range noise, proportional part.
    pub eps_a: f64,
    /// Range noise, constant part, metres.
    pub eps_d_m: f64,
    /// P(dynamic) of a new map point.
    pub prior: f64,
    /// Map points above this P(dynamic) are removed.
    pub threshold: f64,
    /// Only map points within this range of the sensor are checked, metres.
    pub max_range_m: f64,
    /// The update runs on every n-th localised scan, and on every scan that updates the map
    /// (1: all). Ten looks a second through a place a person left are more than the model needs;
    /// every second scan halves the cost.
    pub every_n_scans: usize,
    /// Weight of the range-image look (ring-structured scans, per-point `ring`): a map point
    /// whose two bracketing lasers both ended beyond it was seen through at the sensor's
    /// resolution (0 disables).
    pub range_image_weight: f64,
    /// Azimuth bin of that range image, radians (about the sensor's horizontal step).
    pub range_image_bin_rad: f64,
    /// Lasers farther apart in elevation than this do not bracket a point, radians.
    pub range_image_max_gap_rad: f64,
    /// Lasers of the sensor (rings, `Point::ring` 0..n): lasers that got no return at all in a
    /// scan still looked through free space (16 for the VLP-16; 0: only rings seen in the scan).
    pub lasers: usize,
    /// A laser at least this high in the sensor frame that fired and got no return saw free
    /// space out to the sensor's range, radians. Steeper ones count as unknown: they may be
    /// blocked by the robot's own body inside the minimum range, or absorbed by wet ground. The
    /// default lets shallow downward beams count (a VLP-16 on top of the robot cannot see its
    /// body below -6 deg), as beams over a drop-off or past the end of the terrain.
    pub no_return_min_elevation_rad: f64,
}

impl Default for DynamicConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            beam_half_angle_rad: 0.003,
            alpha: 0.8,
            beta: 0.9,
            eps_a: 0.01,
            eps_d_m: 0.01,
            prior: 0.5,
            threshold: 0.75,
            max_range_m: 30.0,
            every_n_scans: 2,
            range_image_weight: 0.5,
            range_image_bin_rad: 0.0035,
            range_image_max_gap_rad: 0.06,
            lasers: 16,
            no_return_min_elevation_rad: -0.1,
        }
    }
}
