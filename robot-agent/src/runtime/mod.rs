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
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RuntimeLimits {
    /// The stamp gate.
    pub stamps: StampLimits,
    /// The watchdog.
    pub silence: SilenceLimits,
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
}

/// Control period, seconds (20 Hz, methods.md §6).
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
        let agent = Agent::new(
            cfg,
            Identity {
                robot: robot.to_string(),
                session_id: format!("{robot}-{start_unix_ms}"),
                start_unix_ms,
            },
        )
        .map_err(|e| anyhow::anyhow!("mapper configuration: {e}"))?;
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
        })
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
        match &input {
            Input::Scan(s) => {
                let mut s = s.clone();
                let dropped = s.retain_finite();
                if dropped > 0 {
                    tracing::trace!("{dropped} non-finite points dropped");
                }
                let rep = self.agent.on_scan(&s);
                self.slam_fallbacks += u64::from(rep.slam_failed);
                scan = true;
            }
            Input::Depth(s) => {
                if let Err(e) = self.agent.on_depth(s) {
                    tracing::warn!("{e}");
                }
                scan = true;
            }
            Input::Odom(o) => self.agent.on_odom(*o),
            Input::Imu(i) => self.agent.on_imu(i),
            Input::Gnss(g) => self.agent.on_gnss(g),
            Input::Fix(f) => self.agent.on_gnss_fix(f),
            Input::Heading(h) => self.agent.on_gnss_heading(h),
        }
        Admitted::Yes { scan }
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
        }
    }

    /// Bad inputs of every kind so far (refused stamps and undecodable messages).
    pub fn bad_inputs(&self) -> u64 {
        self.gate.refused_total() + self.undecodable.iter().sum::<u64>()
    }
}
