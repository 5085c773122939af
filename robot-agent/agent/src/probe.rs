//! Stage marks for measuring the agent from outside. The agent has no clock (it is driven by a
//! loop that feeds it time); a caller that wants to know where a sweep's time goes passes a
//! [`Probe`], and the agent marks the end of each stage. `robot-agent bench pipeline` reads
//! its clock at each mark; everything else passes [`NoProbe`].

/// A stage of one sweep's processing, in the order they run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    /// SLAM registration, GNSS/IMU anchoring, the trust gates.
    Localise,
    /// The traversability map update.
    Map,
    /// The safety gate on the raw sweep, and the path check a map change asks for.
    Safety,
}

/// Told when each [`Stage`] of a sweep ends.
pub trait Probe {
    /// `stage` has just finished.
    fn mark(&mut self, stage: Stage);
}

/// A probe that does nothing.
pub struct NoProbe;

impl Probe for NoProbe {
    fn mark(&mut self, _stage: Stage) {}
}
