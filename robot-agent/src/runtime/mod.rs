//! The real-robot runtime's core: sensor messages in (with their header stamps), base commands
//! out, the [`Agent`] in between, behind the stamp gate and the sensor watchdog. It reads no
//! clock and does no I/O: the loop around it (`run/robot.rs`) receives messages from the
//! drivers, tells it the time, and sends its commands to the base, so the same core runs a real
//! robot, the simulator served as ROS 2 topics, and a replay.
//!
//! Time: the agent counts seconds from the session's first accepted stamp; the identity's
//! `start_unix_ms` is that stamp when it is a Unix time (ROS headers), else the wall clock the
//! loop gives at start.

pub mod faults;
pub mod outputs;
pub mod stamps;

use agent::{Agent, AgentConfig, Cmd, Identity};
use faults::{Fault, SilenceLimits, Watchdog};
use sensing::{GnssFixSample, GnssHeadingSample, GnssSentence, ImuSample, OdomSample, Scan};
use serde::Serialize;
use stamps::{StampFault, StampGate, StampLimits, Topic};

/// One message from a driver, stamped with its header time (seconds; Unix time for ROS 2).
#[derive(Clone, Debug)]
pub enum Input {
    /// A LiDAR sweep in the LiDAR frame (`Point::t_s` relative to the stamp).
    Scan(Scan),
    /// A depth-camera frame in the camera frame.
    Depth(Scan),
    /// Wheel odometry.
    Odom(OdomSample),
    /// An IMU accelerometer reading.
    Imu(ImuSample),
    /// One NMEA sentence.
    Gnss(GnssSentence),
    /// A fix a driver decoded (ROS `NavSatFix`, gpsd).
    Fix(GnssFixSample),
    /// A true heading from its own stream.
    Heading(GnssHeadingSample),
}

impl Input {
    /// The input's stream.
    pub fn topic(&self) -> Topic {
        match self {
            Input::Scan(_) => Topic::Lidar,
            Input::Depth(_) => Topic::Depth,
            Input::Odom(_) => Topic::Odom,
            Input::Imu(_) => Topic::Imu,
            Input::Gnss(_) | Input::Fix(_) => Topic::Gnss,
            Input::Heading(_) => Topic::Heading,
        }
    }

    /// The header stamp, seconds.
    pub fn stamp_s(&self) -> f64 {
        match self {
            Input::Scan(s) | Input::Depth(s) => s.stamp_s,
            Input::Odom(o) => o.t_s,
            Input::Imu(i) => i.t_s,
            Input::Gnss(g) => g.t_s,
            Input::Fix(f) => f.t_s,
            Input::Heading(h) => h.t_s,
        }
    }

    fn shift_time(&mut self, by_s: f64) {
        match self {
            Input::Scan(s) | Input::Depth(s) => s.stamp_s -= by_s,
            Input::Odom(o) => o.t_s -= by_s,
            Input::Imu(i) => i.t_s -= by_s,
            Input::Gnss(g) => g.t_s -= by_s,
            Input::Fix(f) => f.t_s -= by_s,
            Input::Heading(h) => h.t_s -= by_s,
        }
    }
}

/// The runtime's limits (`[runtime]` in the robot config).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RuntimeLimits {
    /// The stamp gate.
    pub stamps: StampLimits,
    /// The watchdog.
    pub silence: SilenceLimits,
    /// A robot with GNSS holds its first sweeps this long (session time) for an RTK fixed fix
    /// with a heading, so the map is anchored in ENU at the datum; then it maps in the first
    /// pose's frame, seconds.
    pub anchor_wait_s: f64,
}

impl Default for RuntimeLimits {
    fn default() -> Self {
        Self {
            stamps: StampLimits::default(),
            silence: SilenceLimits::default(),
            anchor_wait_s: 10.0,
        }
    }
}

/// What the runtime counted.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RuntimeCounts {
    /// Messages accepted per topic.
    pub accepted: Vec<(Topic, u64)>,
    /// Messages refused for their stamp, per topic and reason.
    pub stamp_refused: Vec<(Topic, StampFault, u64)>,
    /// Messages a driver could not decode, per topic.
    pub undecodable: Vec<(Topic, u64)>,
    /// Sweeps whose SLAM fell back to the prior.
    pub slam_fallbacks: u64,
    /// Sweeps held back while waiting for GNSS to anchor the map.
    pub scans_before_anchor: u64,
    /// GNSS fixes the agent took.
    pub gnss: GnssCounts,
}

/// One GNSS fix as the agent took it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FixTaken {
    /// Session time, seconds.
    pub t_s: f64,
    /// The message's stamp (Unix time for ROS, NMEA and gpsd sources), seconds.
    pub stamp_s: f64,
    /// Latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees.
    pub lon_deg: f64,
    /// Height above the ellipsoid, metres.
    pub h_m: f64,
    /// GGA quality (1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float).
    pub quality: u8,
    /// Satellites used, when the source says.
    pub satellites: Option<u8>,
}

/// GNSS fixes the agent took, by quality, and the last one.
#[derive(Clone, Debug, Default, Serialize)]
pub struct GnssCounts {
    /// Fixes taken.
    pub fixes: u64,
    /// (GGA quality, fixes), only the non-zero ones.
    pub by_quality: Vec<(u8, u64)>,
    /// The last fix taken.
    pub last_fix: Option<FixTaken>,
}

/// What happened to one input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Admitted {
    /// Passed to the agent.
    Yes {
        /// A sweep was processed (tiles may have changed).
        scan: bool,
    },
    /// Refused for its stamp (counted).
    No(StampFault),
}

/// See the module docs.
pub struct Runtime {
    agent: Agent,
    gate: StampGate,
    watchdog: Watchdog,
    t0_s: f64,
    accepted: [u64; Topic::COUNT],
    undecodable: [u64; Topic::COUNT],
    slam_fallbacks: u64,
    next_control_s: f64,
    cmd: Cmd,
    fixes_by_quality: [u64; 10],
    last_fix: Option<FixTaken>,
    new_fix: Option<FixTaken>,
    /// Session time until which the first sweep waits for GNSS (`None`: no GNSS, or done).
    anchor_wait_until_s: Option<f64>,
    scans_before_anchor: u64,
}

/// A command as it reaches the agent, with its time on the agent's clock: one to carry out, or
/// one the bus refused (shown in the status). What a recording keeps and a replay re-applies.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentCommand {
    /// Carry it out.
    Do(agent::Command),
    /// Refused by the bus's checks.
    Refused {
        /// When, seconds on the agent's clock.
        t_s: f64,
        /// Why.
        refusal: common::command::Refusal,
    },
}

impl AgentCommand {
    /// A command from the bus at session time `t_s` (`None`: one the agent has no use for).
    pub fn from_bus(t_s: f64, cmd: crate::bus::Command) -> Option<Self> {
        match cmd {
            crate::bus::Command::Refused(refusal) => Some(Self::Refused { t_s, refusal }),
            cmd => crate::bus::translate::command_to_agent(cmd)
                .map(|kind| Self::Do(agent::Command::at(t_s, kind))),
        }
    }

    /// Its time, seconds on the agent's clock.
    pub fn t_s(&self) -> f64 {
        match self {
            Self::Do(c) => c.t_s,
            Self::Refused { t_s, .. } => *t_s,
        }
    }

    /// Hands it to the agent (a refusal is counted and logged by the agent).
    pub fn apply(&self, agent: &mut Agent) {
        match self {
            Self::Do(c) => {
                let _ = agent.on_command(c.clone());
            }
            Self::Refused { refusal, .. } => agent.note_refusal(refusal),
        }
    }
}

/// What [`deliver`] did with one input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Delivered {
    /// A sweep or depth frame was processed (tiles may have changed).
    pub scan: bool,
    /// SLAM fell back to its prior on this sweep.
    pub slam_failed: bool,
}

/// Hands one input, on the agent's clock, to the agent. The runtime calls it for every input its
/// gate admits, and the simulator rig for each of its sensor outputs: the same calls in the same
/// order, so a recording of either replays through the runtime call for call.
pub fn deliver(agent: &mut Agent, input: &Input) -> Delivered {
    let mut d = Delivered::default();
    match input {
        Input::Scan(s) => {
            let rep = if s.points.iter().all(sensing::Point::is_finite) {
                agent.on_scan(s)
            } else {
                let mut s = s.clone();
                let dropped = s.retain_finite();
                tracing::trace!("{dropped} non-finite points dropped");
                agent.on_scan(&s)
            };
            d.slam_failed = rep.slam_failed;
            d.scan = true;
        }
        Input::Depth(s) => {
            if let Err(e) = agent.on_depth(s) {
                tracing::warn!("{e}");
            }
            d.scan = true;
        }
        Input::Odom(o) => agent.on_odom(*o),
        Input::Imu(i) => agent.on_imu(i),
        Input::Gnss(g) => agent.on_gnss(g),
        Input::Fix(f) => agent.on_gnss_fix(f),
        Input::Heading(h) => agent.on_gnss_heading(h),
    }
    d
}

/// Control period, seconds (20 Hz, docs/algorithms.md §6).
pub const CONTROL_DT_S: f64 = 0.05;

/// Stamps above this are Unix times (2001 on); below, a session or simulator clock.
const UNIX_TIME_FLOOR_S: f64 = 1.0e9;

impl Runtime {
    /// The runtime for one session of `robot`. `first_stamp_s` is the first message's stamp
    /// (the session's time 0), `wall_unix_ms` the wall clock now, used when stamps are not Unix
    /// times. `inputs` are the topics the robot is configured with.
    pub fn new(
        cfg: AgentConfig,
        limits: RuntimeLimits,
        robot: &str,
        inputs: &[Topic],
        first_stamp_s: f64,
        wall_unix_ms: u64,
    ) -> anyhow::Result<Self> {
        // Half a second of slack: another sensor's first message may be a little older.
        let t0_s = (first_stamp_s - 0.5).max(0.0);
        let start_unix_ms = if first_stamp_s > UNIX_TIME_FLOOR_S {
            (t0_s * 1000.0) as u64
        } else {
            wall_unix_ms
        };
        let identity = Identity {
            robot: robot.to_string(),
            session_id: format!("{robot}-{start_unix_ms}"),
            start_unix_ms,
        };
        Self::resume(cfg, limits, identity, inputs, t0_s)
    }

    /// The runtime of a session whose identity and clock origin are known already (a replay:
    /// the recorded ones, so that every stamp and tile comes out as it did). `t0_s` is the
    /// header stamp of session time 0.
    pub fn resume(
        cfg: AgentConfig,
        limits: RuntimeLimits,
        identity: Identity,
        inputs: &[Topic],
        t0_s: f64,
    ) -> anyhow::Result<Self> {
        let agent =
            Agent::new(cfg, identity).map_err(|e| anyhow::anyhow!("mapper configuration: {e}"))?;
        Ok(Self {
            agent,
            gate: StampGate::new(limits.stamps),
            watchdog: Watchdog::new(limits.silence, inputs),
            t0_s,
            accepted: [0; Topic::COUNT],
            undecodable: [0; Topic::COUNT],
            slam_fallbacks: 0,
            next_control_s: 0.0,
            cmd: Cmd::default(),
            fixes_by_quality: [0; 10],
            last_fix: None,
            new_fix: None,
            // Time 0 is half a second before the first message.
            anchor_wait_until_s: inputs
                .contains(&Topic::Gnss)
                .then_some(0.5 + limits.anchor_wait_s),
            scans_before_anchor: 0,
        })
    }

    /// The header stamp of session time 0, seconds.
    pub fn t0_s(&self) -> f64 {
        self.t0_s
    }

    /// The agent.
    pub fn agent(&self) -> &Agent {
        &self.agent
    }

    /// The agent, to give it commands.
    pub fn agent_mut(&mut self) -> &mut Agent {
        &mut self.agent
    }

    /// Session time (agent clock) of a header stamp, seconds.
    pub fn session_time_s(&self, stamp_s: f64) -> f64 {
        stamp_s - self.t0_s
    }

    /// The newest accepted stamp as session time, seconds.
    pub fn newest_s(&self) -> Option<f64> {
        self.gate.newest_s().map(|t| self.session_time_s(t))
    }

    /// One message: checked, put on the session clock, passed to the agent.
    pub fn on_input(&mut self, mut input: Input) -> Admitted {
        let topic = input.topic();
        if let Err(f) = self.gate.admit(topic, input.stamp_s()) {
            tracing::debug!("{topic} message refused: {f}");
            return Admitted::No(f);
        }
        input.shift_time(self.t0_s);
        let t = input.stamp_s();
        self.watchdog.heard(topic, t);
        self.accepted[topic as usize] += 1;
        let mut scan = false;
        if matches!(input, Input::Scan(_)) && self.holds_for_anchor(t) {
            self.scans_before_anchor += 1;
        } else {
            let d = deliver(&mut self.agent, &input);
            self.slam_fallbacks += u64::from(d.slam_failed);
            scan = d.scan;
        }
        if topic == Topic::Gnss {
            self.note_fix(t);
        }
        Admitted::Yes { scan }
    }

    /// Whether the sweep at `t_s` must wait for GNSS: the first sweep anchors the map, in ENU
    /// at the datum only with an RTK fixed fix and a heading, and a robot's sensors start in any
    /// order (a sweep may well come before the receiver's first epoch).
    fn holds_for_anchor(&mut self, t_s: f64) -> bool {
        let Some(until) = self.anchor_wait_until_s else {
            return false;
        };
        if self.agent.localiser().can_anchor(t_s) {
            self.anchor_wait_until_s = None;
            return false;
        }
        if t_s < until {
            return true;
        }
        tracing::warn!(
            "no RTK fixed fix with a heading within {:.0} s: mapping in the first pose's frame",
            until - 0.5
        );
        self.anchor_wait_until_s = None;
        false
    }

    /// Counts the fix the agent took from the message at `t_s`, if it took one.
    fn note_fix(&mut self, t_s: f64) {
        let Some(f) = self.agent.localiser().fix(t_s).filter(|f| f.t_s == t_s) else {
            return;
        };
        if self.last_fix.is_some_and(|l| l.t_s == t_s) {
            return;
        }
        let taken = FixTaken {
            t_s,
            stamp_s: t_s + self.t0_s,
            lat_deg: f.lla.lat_deg,
            lon_deg: f.lla.lon_deg,
            h_m: f.lla.h_m,
            quality: f.quality,
            satellites: f.satellites,
        };
        self.fixes_by_quality[usize::from(f.quality.min(9))] += 1;
        self.last_fix = Some(taken);
        self.new_fix = Some(taken);
    }

    /// The fix the agent took since the last call, if any.
    pub fn take_new_fix(&mut self) -> Option<FixTaken> {
        self.new_fix.take()
    }

    /// A driver could not decode a message of `topic` (counted).
    pub fn count_undecodable(&mut self, topic: Topic) {
        self.undecodable[topic as usize] += 1;
    }

    /// The base command at session time `now_s`, when a control period fell due since the last
    /// call (plans first when one is due). A LiDAR fault stops the base whatever the mission.
    pub fn control(&mut self, now_s: f64) -> Option<Cmd> {
        if now_s + 1e-9 < self.next_control_s {
            return None;
        }
        self.next_control_s = (self.next_control_s + CONTROL_DT_S).max(now_s);
        self.agent.plan_if_due(now_s);
        let cmd = self.agent.control(now_s);
        self.cmd = if self.watchdog.base_stopped(now_s) {
            Cmd::default()
        } else {
            cmd
        };
        Some(self.cmd)
    }

    /// The command last sent.
    pub fn cmd(&self) -> Cmd {
        self.cmd
    }

    /// The sensor faults in force at `now_s`.
    pub fn faults(&self, now_s: f64) -> Vec<Fault> {
        self.watchdog.faults(now_s)
    }

    /// The counts so far.
    pub fn counts(&self) -> RuntimeCounts {
        let per_topic = |a: &[u64; Topic::COUNT]| {
            Topic::ALL
                .iter()
                .filter(|t| a[**t as usize] > 0)
                .map(|t| (*t, a[*t as usize]))
                .collect()
        };
        RuntimeCounts {
            accepted: per_topic(&self.accepted),
            stamp_refused: self.gate.counts().refused,
            undecodable: per_topic(&self.undecodable),
            slam_fallbacks: self.slam_fallbacks,
            scans_before_anchor: self.scans_before_anchor,
            gnss: GnssCounts {
                fixes: self.fixes_by_quality.iter().sum(),
                by_quality: (0u8..10)
                    .zip(self.fixes_by_quality)
                    .filter(|(_, n)| *n > 0)
                    .collect(),
                last_fix: self.last_fix,
            },
        }
    }

    /// Bad inputs of every kind so far (refused stamps and undecodable messages).
    pub fn bad_inputs(&self) -> u64 {
        self.gate.refused_total() + self.undecodable.iter().sum::<u64>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sensing::{GnssFixSample, GnssHeadingSample, Point};

    /// A sweep of a flat floor and four walls around the sensor.
    fn sweep(stamp_s: f64) -> Scan {
        let mut points = Vec::new();
        for i in 0..720 {
            let a = f64::from(i) * std::f64::consts::TAU / 720.0;
            let (s, c) = a.sin_cos();
            let r = (8.0 / c.abs().max(s.abs())) as f32;
            for z in [-0.5f32, 0.0, 0.5, 1.0] {
                points.push(Point::xyz(r * c as f32, r * s as f32, z));
            }
            points.push(Point::xyz(3.0 * c as f32, 3.0 * s as f32, -0.9));
        }
        Scan { stamp_s, points }
    }

    fn runtime(inputs: &[Topic]) -> Runtime {
        let cfg = AgentConfig {
            datum: Some(common::msg::Datum {
                lat_deg: 48.0,
                lon_deg: 11.0,
                h_m: 500.0,
            }),
            ..AgentConfig::default()
        };
        Runtime::new(cfg, RuntimeLimits::default(), "t", inputs, 1000.0, 0).unwrap()
    }

    #[test]
    fn the_first_sweep_waits_for_gnss_to_anchor_the_map() {
        let mut rt = runtime(&[Topic::Lidar, Topic::Gnss, Topic::Heading]);
        rt.on_input(Input::Scan(sweep(1000.0)));
        rt.on_input(Input::Scan(sweep(1000.1)));
        assert_eq!(
            (rt.agent().scans(), rt.counts().scans_before_anchor),
            (0, 2)
        );
        assert!(rt.agent().map_frame().is_none());
        rt.on_input(Input::Fix(GnssFixSample {
            t_s: 1000.15,
            lat_deg: 48.0,
            lon_deg: 11.0,
            h_m: 500.0,
            quality: 4,
            satellites: None,
        }));
        rt.on_input(Input::Heading(GnssHeadingSample {
            t_s: 1000.16,
            heading_deg: 90.0,
        }));
        assert!(rt.take_new_fix().is_some_and(|f| f.quality == 4));
        rt.on_input(Input::Scan(sweep(1000.2)));
        assert_eq!(rt.agent().scans(), 1);
        assert_eq!(
            rt.agent().map_frame().map(|f| f.0),
            Some(agent::localiser::FrameKind::EnuAtDatum)
        );
        assert_eq!(rt.counts().gnss.fixes, 1);
    }

    #[test]
    fn without_gnss_or_after_the_wait_the_first_sweep_anchors_at_once() {
        let mut rt = runtime(&[Topic::Lidar]);
        rt.on_input(Input::Scan(sweep(1000.0)));
        assert_eq!(rt.agent().scans(), 1);
        // 10 s of sweeps at 10 Hz wait (time 0 is 0.5 s before the first message); then the
        // map is the first pose's frame.
        let mut rt = runtime(&[Topic::Lidar, Topic::Gnss]);
        for k in 0..=110 {
            rt.on_input(Input::Scan(sweep(1000.0 + f64::from(k) * 0.1)));
        }
        let (mapped, held) = (
            u64::from(rt.agent().scans()),
            rt.counts().scans_before_anchor,
        );
        assert!(
            mapped + held == 111 && (99..=101).contains(&held),
            "{mapped} {held}"
        );
        assert_eq!(
            rt.agent().map_frame().map(|f| f.0),
            Some(agent::localiser::FrameKind::FirstPose)
        );
    }
}
