//! One simulated robot in a world: plant plus sensors, stepped by the caller.

use crate::plant::{Collision, Plant};
use crate::scenario::Scenario;
use crate::sensors::{
    depth_frame, DepthConfig, Gnss, GnssConfig, GnssFix, Imu, ImuConfig, Lidar, LidarConfig,
    OdomConfig, Odometry,
};
use crate::world::{Obstacle, Solid, WalkerState, World};
use common::geom::Pose2;
use common::robot::RobotProfile;
use nalgebra::Isometry3;
use rand::rngs::SmallRng;
use rand::SeedableRng;
use sensing::{GnssSentence, ImuSample, OdomSample, Scan};
use serde::Deserialize;

/// Longest internal sub-step, seconds: bounds walker motion within one LiDAR chunk and keeps the
/// plant's collision checks fine-grained whatever `dt` the caller uses.
const MAX_SUBSTEP_S: f64 = 0.02;

/// How far back [`Simulation::truth_pose_at`] reaches, seconds.
const HISTORY_S: f64 = 2.0;

/// Simulation settings.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Seed of every random stream (sensor noise, GNSS errors).
    pub seed: u64,
    /// Start pose; `None` = the scenario's first `[[start]]`.
    #[serde(skip)]
    pub start: Option<Pose2>,
    /// The robot.
    pub robot: RobotProfile,
    /// VLP-16.
    pub lidar: LidarConfig,
    /// SR4000 depth camera.
    pub depth: DepthConfig,
    /// Wheel odometry.
    pub odom: OdomConfig,
    /// GNSS receiver.
    pub gnss: GnssConfig,
    /// IMU accelerometer.
    pub imu: ImuConfig,
    /// Walkers wait while walking on for `walker_lookahead_s` would bring them within this gap
    /// of the robot's footprint (people step around or wait for a robot; they do not walk into
    /// it). 0 turns yielding off: walkers then follow their scripts blindly, metres.
    pub walker_yield_gap_m: f64,
    /// How far ahead in time a walker looks for the robot, seconds.
    pub walker_lookahead_s: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            start: None,
            robot: RobotProfile::default(),
            lidar: LidarConfig::default(),
            depth: DepthConfig::default(),
            odom: OdomConfig::default(),
            gnss: GnssConfig::default(),
            imu: ImuConfig::default(),
            walker_yield_gap_m: 0.4,
            walker_lookahead_s: 1.0,
        }
    }
}

/// What one [`Simulation::step`] produced.
#[derive(Clone, Debug, Default)]
pub struct StepOutput {
    /// A VLP-16 scan completed in this step (sensor frame, per-point times; swept while moving).
    pub scan: Option<Scan>,
    /// A depth-camera frame captured in this step (camera frame).
    pub depth: Option<Scan>,
    /// The newest odometry sample, when one fell due.
    pub odom: Option<OdomSample>,
    /// GNSS sentences (GGA then `$PTNL,AVR` per epoch), without line endings.
    pub gnss: Vec<GnssSentence>,
    /// IMU samples that fell due in this step, oldest first.
    pub imu: Vec<ImuSample>,
    /// Collisions that began in this step.
    pub collisions: Vec<Collision>,
}

/// The simulated robot in its world.
pub struct Simulation {
    world: World,
    cfg: SimConfig,
    plant: Plant,
    lidar: Lidar,
    odom: Odometry,
    gnss: Gnss,
    imu: Imu,
    next_depth_t_s: f64,
    t_s: f64,
    rng_lidar: SmallRng,
    rng_depth: SmallRng,
    rng_odom: SmallRng,
    rng_gnss: SmallRng,
    rng_imu: SmallRng,
    scenario_name: String,
    datum: common::msg::Datum,
    dropped_scans: u64,
    /// Recent base poses (time, map <- base_link), for poses at past stamps.
    history: std::collections::VecDeque<(f64, Isometry3<f64>)>,
    /// Each walker's own clock (seconds of its script walked): behind `t_s` by the time it
    /// waited for the robot.
    walker_clock: Vec<f64>,
    /// Total seconds walkers spent waiting for the robot.
    walker_wait_s: f64,
}

impl Simulation {
    /// A robot standing at the start pose at time 0.
    pub fn new(scenario: &Scenario, cfg: SimConfig) -> Self {
        let world = World::new(scenario);
        let start = cfg.start.unwrap_or_else(|| scenario.start_pose());
        let plant = Plant::new(&cfg.robot, start, &world);
        let plant_pose0 = plant.pose3();
        let lidar = Lidar::new(&cfg.lidar, cfg.robot.lidar.isometry());
        let odom = Odometry::new(&cfg.odom);
        let datum = scenario.datum();
        let gnss = Gnss::new(
            &cfg.gnss,
            datum,
            cfg.robot.gnss.primary_xyz_m,
            cfg.robot.gnss.secondary_xyz_m,
        )
        .with_denied_areas(&scenario.gnss_denied);
        // One independent stream per sensor: switching one sensor off leaves the others' noise as it was.
        let rng =
            |k: u64| SmallRng::seed_from_u64(cfg.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k);
        let mut rng_imu = rng(5);
        let imu = Imu::new(&cfg.imu, &mut rng_imu, rng(8));
        Self {
            plant,
            lidar,
            odom,
            gnss,
            imu,
            next_depth_t_s: 0.0,
            t_s: 0.0,
            rng_lidar: rng(1),
            rng_depth: rng(2),
            rng_odom: rng(3),
            rng_gnss: rng(4),
            rng_imu,
            scenario_name: scenario.name.clone(),
            datum,
            dropped_scans: 0,
            history: std::collections::VecDeque::from([(0.0, plant_pose0)]),
            walker_clock: vec![0.0; world.walker_count()],
            walker_wait_s: 0.0,
            world,
            cfg,
        }
    }

    /// Advances the simulation by `dt_s` under the command (forward speed, turn rate).
    /// Any `dt_s` works (it is cut into sub-steps of at most 20 ms); with `dt_s` above one LiDAR
    /// period, only the newest scan is returned and the others are counted in `dropped_scans`.
    pub fn step(&mut self, dt_s: f64, cmd_v_mps: f64, cmd_omega_rps: f64) -> StepOutput {
        let mut out = StepOutput::default();
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return out;
        }
        let n = (dt_s / MAX_SUBSTEP_S).ceil().max(1.0) as usize;
        let h = dt_s / n as f64;
        for _ in 0..n {
            let t0 = self.t_s;
            let t1 = t0 + h;
            let base0 = self.plant.pose3();
            let clocks0 = self.walker_clock.clone();
            self.advance_walkers(h);
            let walkers1 = self.world.walkers_at_clocks(&self.walker_clock);
            let clocks_at = |f: f64| -> Vec<f64> {
                clocks0
                    .iter()
                    .zip(&self.walker_clock)
                    .map(|(a, b)| a + (b - a) * f)
                    .collect()
            };
            out.collisions.extend(self.plant.step(
                &self.world,
                &walkers1,
                t1,
                h,
                cmd_v_mps,
                cmd_omega_rps,
            ));
            let base1 = self.plant.pose3();
            if self.cfg.lidar.enabled {
                let mid: Vec<Solid> = self
                    .world
                    .walkers_at_clocks(&clocks_at(0.5))
                    .iter()
                    .map(WalkerState::solid)
                    .collect();
                if let Some(scan) = self.lidar.sweep(
                    &self.world,
                    &mid,
                    t0,
                    t1,
                    &base0,
                    &base1,
                    &mut self.rng_lidar,
                ) {
                    if out.scan.replace(scan).is_some() {
                        self.dropped_scans += 1;
                    }
                }
            }
            if self.cfg.depth.enabled
                && t1 + 1e-9 >= self.next_depth_t_s
                && self.next_depth_t_s >= t0 - 1e-9
            {
                let f = ((self.next_depth_t_s - t0) / h).clamp(0.0, 1.0);
                let cam = base0.lerp_slerp(&base1, f) * self.cfg.robot.depth_camera.isometry();
                let ws: Vec<Solid> = self
                    .world
                    .walkers_at_clocks(&clocks_at(f))
                    .iter()
                    .map(WalkerState::solid)
                    .collect();
                out.depth = Some(depth_frame(
                    &self.cfg.depth,
                    &self.world,
                    &ws,
                    &cam,
                    self.next_depth_t_s,
                    &mut self.rng_depth,
                ));
                self.next_depth_t_s += 1.0 / self.cfg.depth.rate_hz;
            }
            if self.cfg.odom.enabled {
                if let Some(o) = self.odom.step(
                    t1,
                    h,
                    self.plant.v_mps(),
                    self.plant.omega_rps(),
                    &mut self.rng_odom,
                ) {
                    out.odom = Some(o);
                }
            }
            if self.cfg.imu.enabled {
                out.imu
                    .extend(self.imu.step(t1, h, &base0, &base1, &mut self.rng_imu));
            }
            if self.cfg.gnss.enabled {
                out.gnss
                    .extend(self.gnss.step(&self.world, t1, &base1, &mut self.rng_gnss));
            }
            self.t_s = t1;
            self.history.push_back((t1, base1));
            while self.history.front().is_some_and(|h| h.0 < t1 - HISTORY_S) {
                self.history.pop_front();
            }
        }
        out
    }

    /// Simulation time, seconds.
    pub fn time_s(&self) -> f64 {
        self.t_s
    }

    /// `map <- base_link` (map = ENU at the datum).
    pub fn truth_pose(&self) -> Isometry3<f64> {
        self.plant.pose3()
    }

    /// `map <- base_link` at a past time within the last 2 s (interpolated between sub-steps);
    /// `None` outside that window. Scans are stamped at their first column, 0.1 s before they are
    /// returned, so this is how a recorder gets the truth at a scan's stamp.
    pub fn truth_pose_at(&self, t_s: f64) -> Option<Isometry3<f64>> {
        let k = self.history.partition_point(|h| h.0 < t_s);
        if k == self.history.len() {
            return (t_s <= self.t_s + 1e-9).then(|| self.plant.pose3());
        }
        let (tb, pb) = self.history[k];
        if k == 0 {
            return ((tb - t_s).abs() < 1e-9).then_some(pb);
        }
        let (ta, pa) = self.history[k - 1];
        let f = if tb - ta > 1e-12 {
            (t_s - ta) / (tb - ta)
        } else {
            1.0
        };
        Some(pa.lerp_slerp(&pb, f))
    }

    /// Planar truth pose of `base_link`.
    pub fn truth_pose2(&self) -> Pose2 {
        self.plant.pose2()
    }

    /// Current forward speed and turn rate (truth), m/s and rad/s.
    pub fn truth_velocity(&self) -> (f64, f64) {
        (self.plant.v_mps(), self.plant.omega_rps())
    }

    /// `base_link <- lidar`.
    pub fn lidar_extrinsic(&self) -> Isometry3<f64> {
        self.cfg.robot.lidar.isometry()
    }

    /// `base_link <- depth camera` (camera frame x forward, y left, z up).
    pub fn depth_extrinsic(&self) -> Isometry3<f64> {
        self.cfg.robot.depth_camera.isometry()
    }

    /// The world.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The robot profile in use.
    pub fn robot(&self) -> &RobotProfile {
        &self.cfg.robot
    }

    /// The settings in use.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Adds obstacles now (teach and repeat: a parked car or fallen tree on the route).
    pub fn add_obstacles(&mut self, obstacles: &[Obstacle]) {
        self.world.add_obstacles(obstacles);
    }

    /// Walkers at the current time.
    pub fn walkers(&self) -> Vec<WalkerState> {
        self.world.walkers_at_clocks(&self.walker_clock)
    }

    /// Total seconds walkers have waited for the robot so far.
    pub fn walker_wait_s(&self) -> f64 {
        self.walker_wait_s
    }

    /// Moves every walker on by `h` seconds of its script, unless walking on would bring it
    /// within `walker_yield_gap_m` of the robot (closer than it is now): then it waits.
    fn advance_walkers(&mut self, h: f64) {
        let gap = self.cfg.walker_yield_gap_m;
        let p = self.plant.pose2();
        let foot = crate::world::Obb {
            cx: p.x_m,
            cy: p.y_m,
            hx: 0.5 * self.cfg.robot.length_m,
            hy: 0.5 * self.cfg.robot.width_m,
            yaw: p.yaw_rad,
        };
        for (i, c) in self.walker_clock.iter_mut().enumerate() {
            if gap > 0.0 {
                let Some(now) = self.world.walker_position(i, *c) else {
                    continue;
                };
                let d_now = foot.distance_to(now[0], now[1]);
                // The closest the next `walker_lookahead_s` of the script comes to the robot,
                // not just where it ends: a walker passing the robot's side at 1.3 m/s covers
                // more than the body's length in a second and would brush it on the way.
                const SAMPLES: usize = 10;
                let la = self.cfg.walker_lookahead_s;
                let d_ahead = (1..=SAMPLES)
                    .filter_map(|k| {
                        let q = self
                            .world
                            .walker_position(i, *c + la * k as f64 / SAMPLES as f64)?;
                        Some(foot.distance_to(q[0], q[1]))
                    })
                    .fold(f64::INFINITY, f64::min);
                let r = self.world.walker_radius(i);
                if d_ahead - r < gap && d_ahead < d_now {
                    self.walker_wait_s += h;
                    continue;
                }
            }
            *c += h;
        }
    }

    /// Collisions reported since the start.
    pub fn collision_count(&self) -> u64 {
        self.plant.collisions_total()
    }

    /// Scans lost because one `step` spanned more than one LiDAR period.
    pub fn dropped_scans(&self) -> u64 {
        self.dropped_scans
    }

    /// Current GNSS fix state (what the last epoch reported).
    pub fn gnss_fix(&self) -> GnssFix {
        self.gnss.fix
    }

    /// The scenario's name.
    pub fn scenario_name(&self) -> &str {
        &self.scenario_name
    }

    /// The datum of the map frame.
    pub fn datum(&self) -> common::msg::Datum {
        self.datum
    }
}

#[cfg(test)]
mod tests;
