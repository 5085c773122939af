//! SLAM configuration. `Default` is the real robot's configuration from methods.md §3; each
//! stage receives only its own section.

use serde::Deserialize;

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
    /// Voxel grid: one point per cube of this size, metres (0 disables).
    pub voxel_size_m: f64,
    /// Neighbours used for surface normals (PCA).
    pub normal_knn: usize,
    /// Normal neighbours are searched only this far, metres (0: unbounded). Bounding the search
    /// makes it ~2x cheaper on dense clouds; points with fewer than 3 neighbours are dropped.
    pub normal_max_dist_m: f64,
    /// Max density, points per cubic metre (0 disables): denser points are thinned at random.
    pub max_density_per_m3: f64,
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
            voxel_size_m: 0.0,
            normal_knn: 12,
            normal_max_dist_m: 0.0,
            max_density_per_m3: 10.0,
        }
    }
}

/// ICP parameters.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct IcpConfig {
    /// Map neighbours per reading point.
    pub knn: usize,
    /// Max matching distance, metres.
    pub max_match_dist_m: f64,
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
    /// the update is then not applied along the weak directions (the prior is kept there).
    pub degenerate_eig_ratio: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        Self {
            knn: 7,
            max_match_dist_m: 1.1,
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
        }
    }
}

/// Map maintenance. Map normals are the reading's PCA normals (`filters.normal_knn`) taken at
/// insertion, rotated into the map frame.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MapConfig {
    /// A reading point joins the map only when farther than this from every map point, metres.
    pub min_dist_new_point_m: f64,
    /// Only reading points closer than this to the sensor join the map, metres.
    pub sensor_max_range_m: f64,
    /// Map points farther than this from the sensor are dropped, metres.
    pub distance_limit_m: f64,
    /// Radius of the map cloud handed to the traversability mapper, metres (0: no cloud).
    pub output_radius_m: f64,
    /// Spatial index of the map.
    pub index: MapIndexKind,
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
            min_dist_new_point_m: 0.07,
            sensor_max_range_m: 30.0,
            distance_limit_m: 30.0,
            output_radius_m: 20.0,
            index: MapIndexKind::KdTree,
        }
    }
}

/// Dynamic points (ray model, methods.md §3).
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
        }
    }
}
