//! CPU time of the agent's stages, sweep by sweep (`robot-agent bench pipeline`). The agent
//! marks where its stages end ([`agent::Probe`]); this reads the clock at each mark, adds the
//! planning and control the loop runs between sweeps, and closes one sensor period's total at
//! each new sweep, so the total is what the robot's computer spends per LiDAR period.
//!
//! The clock is the thread's CPU time, not the wall: the agent's algorithms run on the calling
//! thread only, so this is what one core spends, and other programs on the machine (a build, a
//! browser) do not inflate it the way they inflate wall time.

use agent::{Probe, Stage};
use serde::Serialize;
use std::collections::BTreeMap;

/// Samples per stage, milliseconds.
#[derive(Debug)]
pub struct StageTimes {
    mark: f64,
    samples: BTreeMap<&'static str, Vec<f64>>,
    period_ms: f64,
    periods: usize,
}

impl Default for StageTimes {
    fn default() -> Self {
        Self {
            mark: thread_cpu_ms(),
            samples: BTreeMap::new(),
            period_ms: 0.0,
            periods: 0,
        }
    }
}

/// CPU time the calling thread has used, milliseconds (0 where the clock is missing).
pub fn thread_cpu_ms() -> f64 {
    use nix::time::{clock_gettime, ClockId};
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 * 1e3 + t.tv_nsec() as f64 * 1e-6)
        .unwrap_or(0.0)
}

fn stage_name(s: Stage) -> &'static str {
    match s {
        Stage::Localise => "localisation",
        Stage::Map => "map_update",
        Stage::Safety => "safety",
    }
}

impl Probe for StageTimes {
    fn mark(&mut self, stage: Stage) {
        let now = thread_cpu_ms();
        let ms = now - self.mark;
        self.mark = now;
        self.add(stage_name(stage), ms);
    }
}

impl StageTimes {
    /// A sweep starts: the previous sensor period's total is closed (none before the first).
    pub fn begin_sweep(&mut self) {
        if self.periods > 0 {
            let total = self.period_ms;
            self.samples.entry("total").or_default().push(total);
        }
        self.periods += 1;
        self.period_ms = 0.0;
        self.mark = thread_cpu_ms();
    }

    /// `stage` took `ms` (planning and control, timed by the loop).
    pub fn add(&mut self, stage: &'static str, ms: f64) {
        self.samples.entry(stage).or_default().push(ms);
        if self.periods > 0 {
            self.period_ms += ms;
        }
    }

    /// Median, p99 and max per stage.
    pub fn summary(&self) -> BTreeMap<&'static str, StageSummary> {
        self.samples
            .iter()
            .map(|(k, v)| (*k, StageSummary::of(v)))
            .collect()
    }
}

/// One stage's distribution, milliseconds.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct StageSummary {
    /// Samples.
    pub n: usize,
    /// Median.
    pub median_ms: f64,
    /// 99th percentile (nearest rank).
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl StageSummary {
    /// The distribution of `v` (empty: all zero).
    pub fn of(v: &[f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let rank = |q: f64| s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
        Self {
            n: s.len(),
            median_ms: rank(0.5),
            p99_ms: rank(0.99),
            max_ms: s[s.len() - 1],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = StageSummary::of(&v);
        assert_eq!(
            (s.n, s.median_ms, s.p99_ms, s.max_ms),
            (100, 50.0, 99.0, 100.0)
        );
        assert_eq!(StageSummary::of(&[]), StageSummary::default());
        assert_eq!(StageSummary::of(&[3.0]).p99_ms, 3.0);
    }

    #[test]
    fn a_period_sums_its_stages_and_closes_at_the_next_sweep() {
        let mut t = StageTimes::default();
        t.add("planning", 5.0); // before the first sweep: not in any period
        t.begin_sweep();
        t.add("planning", 2.0);
        t.add("control", 1.0);
        t.begin_sweep();
        let s = t.summary();
        assert_eq!(s["total"].n, 1);
        assert_eq!(s["total"].median_ms, 3.0);
        assert_eq!(s["planning"].n, 2);
    }
}
