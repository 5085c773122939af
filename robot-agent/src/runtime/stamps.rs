//! The gate every sensor message passes before it reaches the agent: its header time must be
//! finite, move forward on its own topic, and agree with the robot's other clocks. A driver that
//! restarts, a sensor stamping with its boot time, or a bag replayed into a live robot would
//! otherwise move the localiser's clock backwards or years ahead; such messages are refused and
//! counted per topic and reason, never passed on.

use serde::Serialize;

/// The runtime's inputs, each with its own stamp stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Topic {
    /// LiDAR sweeps.
    Lidar,
    /// Depth-camera frames.
    Depth,
    /// Wheel odometry.
    Odom,
    /// IMU.
    Imu,
    /// GNSS (NMEA sentences or fixes).
    Gnss,
    /// A true heading on its own stream (a ROS heading topic; NMEA headings come with `Gnss`).
    Heading,
}

impl Topic {
    /// Every topic, in a fixed order.
    pub const ALL: [Topic; Topic::COUNT] = [
        Topic::Lidar,
        Topic::Depth,
        Topic::Odom,
        Topic::Imu,
        Topic::Gnss,
        Topic::Heading,
    ];

    /// How many topics there are.
    pub const COUNT: usize = 6;

    fn index(self) -> usize {
        self as usize
    }

    /// Several messages of this topic may share one stamp (a GNSS epoch's GGA and heading).
    fn stamps_may_repeat(self) -> bool {
        matches!(self, Topic::Gnss | Topic::Heading)
    }
}

impl std::fmt::Display for Topic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Topic::Lidar => "lidar",
            Topic::Depth => "depth",
            Topic::Odom => "odom",
            Topic::Imu => "imu",
            Topic::Gnss => "gnss",
            Topic::Heading => "heading",
        })
    }
}

/// Why a stamp was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StampFault {
    /// NaN, infinite or negative.
    #[error("stamp is not a time")]
    NotATime,
    /// The same stamp as the topic's previous message.
    #[error("stamp repeats the previous message's")]
    Repeated,
    /// Older than the topic's previous message.
    #[error("stamp goes backwards")]
    Backwards,
    /// Further ahead of the robot's clock than any sensor latency explains.
    #[error("stamp jumps ahead of the robot's clock")]
    Jumped,
    /// Far behind the robot's clock: another clock (a sensor's boot time, a replayed bag).
    #[error("stamp is from another clock")]
    OtherClock,
}

impl StampFault {
    const ALL: [StampFault; 5] = [
        StampFault::NotATime,
        StampFault::Repeated,
        StampFault::Backwards,
        StampFault::Jumped,
        StampFault::OtherClock,
    ];
}

/// Limits of the gate (`[runtime]` in the robot config).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampLimits {
    /// How far a stamp may lead the newest accepted stamp of any topic, seconds.
    pub max_lead_s: f64,
    /// How far a stamp may trail it, seconds (sensor latency plus transport).
    pub max_lag_s: f64,
}

impl Default for StampLimits {
    fn default() -> Self {
        Self {
            max_lead_s: 1.0,
            max_lag_s: 2.0,
        }
    }
}

/// Refused stamps per topic and reason.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StampCounts {
    /// (topic, reason, count), only the non-zero ones.
    pub refused: Vec<(Topic, StampFault, u64)>,
}

/// See the module docs.
#[derive(Clone, Debug)]
pub struct StampGate {
    limits: StampLimits,
    last: [Option<f64>; Topic::COUNT],
    newest: Option<f64>,
    refused: [[u64; 5]; Topic::COUNT],
}

impl StampGate {
    /// A gate that has seen nothing yet.
    pub fn new(limits: StampLimits) -> Self {
        Self {
            limits,
            last: [None; Topic::COUNT],
            newest: None,
            refused: [[0; 5]; Topic::COUNT],
        }
    }

    /// Admits `stamp_s` on `topic` (and remembers it), or says why not (and counts it).
    pub fn admit(&mut self, topic: Topic, stamp_s: f64) -> Result<(), StampFault> {
        let r = self.judge(topic, stamp_s);
        match r {
            Ok(()) => {
                self.last[topic.index()] = Some(stamp_s);
                self.newest = Some(self.newest.map_or(stamp_s, |n| n.max(stamp_s)));
            }
            Err(f) => {
                let k = StampFault::ALL.iter().position(|x| *x == f).unwrap_or(0);
                self.refused[topic.index()][k] += 1;
            }
        }
        r
    }

    fn judge(&self, topic: Topic, t: f64) -> Result<(), StampFault> {
        if !t.is_finite() || t < 0.0 {
            return Err(StampFault::NotATime);
        }
        if let Some(last) = self.last[topic.index()] {
            if t < last {
                return Err(StampFault::Backwards);
            }
            if t == last && !topic.stamps_may_repeat() {
                return Err(StampFault::Repeated);
            }
        }
        if let Some(newest) = self.newest {
            if t > newest + self.limits.max_lead_s && self.last[topic.index()].is_some() {
                return Err(StampFault::Jumped);
            }
            if t < newest - self.limits.max_lag_s {
                return Err(StampFault::OtherClock);
            }
        }
        // A topic's first message may lead the others (a sensor that starts later than the
        // rest), but not by more than the lag window the others are then held to, or it would
        // make every other sensor look like another clock.
        if let Some(newest) = self.newest {
            if self.last[topic.index()].is_none() && t > newest + self.limits.max_lag_s {
                return Err(StampFault::OtherClock);
            }
        }
        Ok(())
    }

    /// The newest accepted stamp of any topic, seconds.
    pub fn newest_s(&self) -> Option<f64> {
        self.newest
    }

    /// The refusals so far.
    pub fn counts(&self) -> StampCounts {
        let mut refused = Vec::new();
        for topic in Topic::ALL {
            for (k, fault) in StampFault::ALL.iter().enumerate() {
                let n = self.refused[topic.index()][k];
                if n > 0 {
                    refused.push((topic, *fault, n));
                }
            }
        }
        StampCounts { refused }
    }

    /// All refusals so far.
    pub fn refused_total(&self) -> u64 {
        self.refused.iter().flatten().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gate() -> StampGate {
        StampGate::new(StampLimits::default())
    }

    #[test]
    fn steady_streams_pass() {
        let mut g = gate();
        for i in 0..100 {
            let t = 1000.0 + f64::from(i) * 0.01;
            assert_eq!(g.admit(Topic::Imu, t), Ok(()));
            if i % 10 == 0 {
                assert_eq!(g.admit(Topic::Lidar, t - 0.05), Ok(()));
                assert_eq!(g.admit(Topic::Gnss, t), Ok(()));
                assert_eq!(g.admit(Topic::Gnss, t), Ok(()), "one epoch, two sentences");
            }
        }
        assert_eq!(g.refused_total(), 0);
    }

    #[test]
    fn repeats_backwards_jumps_and_other_clocks_are_refused_and_counted() {
        let mut g = gate();
        g.admit(Topic::Odom, 500.0).unwrap();
        g.admit(Topic::Lidar, 500.0).unwrap();
        assert_eq!(g.admit(Topic::Lidar, 500.0), Err(StampFault::Repeated));
        assert_eq!(g.admit(Topic::Lidar, 499.9), Err(StampFault::Backwards));
        assert_eq!(g.admit(Topic::Lidar, 600.0), Err(StampFault::Jumped));
        assert_eq!(g.admit(Topic::Imu, 12.0), Err(StampFault::OtherClock));
        assert_eq!(g.admit(Topic::Imu, f64::NAN), Err(StampFault::NotATime));
        assert_eq!(g.admit(Topic::Gnss, 9e9), Err(StampFault::OtherClock));
        // The refused jump did not move the clock: the stream goes on.
        assert_eq!(g.admit(Topic::Lidar, 500.1), Ok(()));
        assert_eq!(g.refused_total(), 6);
        let c = g.counts();
        assert!(c.refused.contains(&(Topic::Lidar, StampFault::Repeated, 1)));
        assert!(c.refused.contains(&(Topic::Imu, StampFault::OtherClock, 1)));
    }

    #[test]
    fn a_silent_sensor_may_come_back() {
        let mut g = gate();
        g.admit(Topic::Lidar, 10.0).unwrap();
        for i in 1..=300 {
            g.admit(Topic::Odom, 10.0 + f64::from(i) * 0.01).unwrap();
        }
        // Three seconds of silence, then the sweeps resume on the same clock.
        assert_eq!(g.admit(Topic::Lidar, 13.0), Ok(()));
    }
}
