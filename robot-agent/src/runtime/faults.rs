//! Sensor faults the runtime acts on: a sensor that falls silent. A silent LiDAR stops the base
//! (nothing vouches for the space ahead any more), silent odometry or IMU degrade localisation,
//! a silent GNSS leaves the robot on SLAM; each is named in the status so the operator sees why.

use super::stamps::Topic;
use serde::Serialize;

/// Silence limits (`[runtime]` in the robot config), seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SilenceLimits {
    /// LiDAR silence after which the base is stopped.
    pub lidar_timeout_s: f64,
    /// Odometry silence reported as a fault.
    pub odom_timeout_s: f64,
    /// IMU silence reported as a fault.
    pub imu_timeout_s: f64,
    /// GNSS silence after which the robot navigates on SLAM only.
    pub gnss_timeout_s: f64,
}

impl Default for SilenceLimits {
    fn default() -> Self {
        Self {
            lidar_timeout_s: 0.5,
            odom_timeout_s: 0.5,
            imu_timeout_s: 0.5,
            gnss_timeout_s: 3.0,
        }
    }
}

/// One sensor fault in force.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Fault {
    /// The silent input.
    pub topic: Topic,
    /// Silent for this long, seconds (`None`: never heard since start).
    pub silent_s: Option<f64>,
    /// The fault stops the base.
    pub stops_base: bool,
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.silent_s {
            Some(s) => write!(f, "{} silent for {s:.1} s", self.topic)?,
            None => write!(f, "no {} yet", self.topic)?,
        }
        if self.stops_base {
            f.write_str(", base stopped")?;
        }
        Ok(())
    }
}

/// Which inputs the robot is configured with, and when each was last heard.
#[derive(Clone, Debug)]
pub struct Watchdog {
    limits: SilenceLimits,
    expected: Vec<Topic>,
    started_s: Option<f64>,
    last: [Option<f64>; Topic::COUNT],
}

impl Watchdog {
    /// Watches the `expected` inputs (an input the robot does not have is never a fault).
    pub fn new(limits: SilenceLimits, expected: &[Topic]) -> Self {
        Self {
            limits,
            expected: expected.to_vec(),
            started_s: None,
            last: [None; Topic::COUNT],
        }
    }

    /// `topic` was heard at `t_s` (agent clock).
    pub fn heard(&mut self, topic: Topic, t_s: f64) {
        self.started_s.get_or_insert(t_s);
        let slot = &mut self.last[topic as usize];
        *slot = Some(slot.map_or(t_s, |l| l.max(t_s)));
    }

    fn timeout_s(&self, topic: Topic) -> f64 {
        match topic {
            Topic::Lidar => self.limits.lidar_timeout_s,
            Topic::Depth => self.limits.lidar_timeout_s,
            Topic::Odom => self.limits.odom_timeout_s,
            Topic::Imu => self.limits.imu_timeout_s,
            Topic::Gnss | Topic::Heading => self.limits.gnss_timeout_s,
        }
    }

    /// The faults in force at `now_s` (agent clock), LiDAR first.
    pub fn faults(&self, now_s: f64) -> Vec<Fault> {
        let Some(start) = self.started_s else {
            return Vec::new();
        };
        self.expected
            .iter()
            .filter_map(|&topic| {
                let timeout = self.timeout_s(topic);
                let silent_s = match self.last[topic as usize] {
                    Some(l) if now_s - l > timeout => Some(now_s - l),
                    Some(_) => return None,
                    // Never heard: a fault once the others have run for the timeout.
                    None if now_s - start > timeout => None,
                    None => return None,
                };
                Some(Fault {
                    topic,
                    silent_s,
                    stops_base: topic == Topic::Lidar,
                })
            })
            .collect()
    }

    /// The base must stand still at `now_s`.
    pub fn base_stopped(&self, now_s: f64) -> bool {
        self.faults(now_s).iter().any(|f| f.stops_base)
    }
}

/// The faults that came and went over a run, per input: how often each began and the longest
/// silence, for the run's summary (the status shows only the faults in force).
#[derive(Clone, Debug, Default, Serialize)]
pub struct FaultLog {
    /// Per input that had a fault, in order of first appearance.
    pub inputs: Vec<FaultEpisodes>,
    #[serde(skip)]
    active: Vec<Topic>,
}

/// The episodes of one input's fault.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaultEpisodes {
    /// The input.
    pub topic: Topic,
    /// How often the fault began.
    pub episodes: u32,
    /// The longest silence seen, seconds (0 for an input never heard at all).
    pub longest_silent_s: f64,
    /// The fault stopped the base.
    pub stopped_base: bool,
}

impl FaultLog {
    /// Takes the faults in force now; returns the inputs whose fault began, and those whose
    /// fault ended, since the last call.
    pub fn note(&mut self, faults: &[Fault]) -> (Vec<Topic>, Vec<Topic>) {
        let mut began = Vec::new();
        for f in faults {
            let i = match self.inputs.iter().position(|e| e.topic == f.topic) {
                Some(i) => i,
                None => {
                    self.inputs.push(FaultEpisodes {
                        topic: f.topic,
                        episodes: 0,
                        longest_silent_s: 0.0,
                        stopped_base: false,
                    });
                    self.inputs.len() - 1
                }
            };
            let e = &mut self.inputs[i];
            if !self.active.contains(&f.topic) {
                e.episodes += 1;
                began.push(f.topic);
            }
            e.longest_silent_s = e.longest_silent_s.max(f.silent_s.unwrap_or(0.0));
            e.stopped_base |= f.stops_base;
        }
        let now: Vec<Topic> = faults.iter().map(|f| f.topic).collect();
        let ended = self
            .active
            .iter()
            .filter(|t| !now.contains(t))
            .copied()
            .collect();
        self.active = now;
        (began, ended)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_log_counts_episodes_and_the_longest_silence() {
        let mut w = Watchdog::new(SilenceLimits::default(), &[Topic::Lidar, Topic::Odom]);
        let mut log = FaultLog::default();
        // Odometry falls silent twice (0.8 s, then 1.5 s); the LiDAR never.
        let mut t = 0.0;
        while t < 6.0 {
            w.heard(Topic::Lidar, t);
            if !((1.0..1.8).contains(&t) || (3.0..4.5).contains(&t)) {
                w.heard(Topic::Odom, t);
            }
            let (began, _) = log.note(&w.faults(t));
            assert!(began.is_empty() || began == [Topic::Odom], "{began:?}");
            t += 0.05;
        }
        assert_eq!(log.inputs.len(), 1, "{log:?}");
        let e = &log.inputs[0];
        assert_eq!(
            (e.topic, e.episodes, e.stopped_base),
            (Topic::Odom, 2, false)
        );
        assert!((e.longest_silent_s - 1.5).abs() < 0.1, "{e:?}");
    }

    #[test]
    fn a_silent_lidar_stops_the_base_within_its_timeout_and_releases_it() {
        let mut w = Watchdog::new(SilenceLimits::default(), &[Topic::Lidar, Topic::Odom]);
        for i in 0..=10 {
            let t = f64::from(i) * 0.1;
            w.heard(Topic::Lidar, t);
            w.heard(Topic::Odom, t);
        }
        assert!(!w.base_stopped(1.4));
        assert!(w.base_stopped(1.51));
        let f = &w.faults(1.51)[0];
        assert_eq!(f.topic, Topic::Lidar);
        assert!(f.to_string().contains("lidar silent"), "{f}");
        w.heard(Topic::Lidar, 3.0);
        assert!(!w.base_stopped(3.05));
    }

    #[test]
    fn inputs_the_robot_lacks_are_never_faults_and_missing_ones_are() {
        let mut w = Watchdog::new(SilenceLimits::default(), &[Topic::Lidar, Topic::Gnss]);
        w.heard(Topic::Lidar, 0.0);
        w.heard(Topic::Lidar, 4.0);
        let f = w.faults(4.0);
        assert_eq!(f.len(), 1);
        assert_eq!(f[0].topic, Topic::Gnss);
        assert_eq!(f[0].silent_s, None);
        assert!(!f[0].stops_base);
    }
}
