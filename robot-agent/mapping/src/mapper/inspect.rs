//! Read-only looks into a cell's evidence and verdict: heights and statistics for the agent's
//! taught-corridor test and for evaluation, the rules' verdict and a one-line description for
//! diagnostics ("why is this cell an obstacle?").

use super::cell_data::Moments;
use super::Mapper;
use crate::classify::{CellStats, Verdict};

impl Mapper {
    /// The mean height of a cell's evidence (or the driven height), if any.
    pub fn height_m(&self, cx: i64, cy: i64) -> Option<f64> {
        let d = self.data(cx, cy)?;
        let e = d.evidence();
        if e.n > 0 {
            Some(e.stats().mean_m)
        } else if d.driven {
            Some(f64::from(d.driven_z))
        } else {
            None
        }
    }

    /// The rule that decides a cell now (diagnostics: why is this cell an obstacle?).
    pub fn explain(&self, cx: i64, cy: i64) -> Verdict {
        self.rules.classify(&self.neighbourhood(cx, cy))
    }

    /// Lowest and highest point of a cell's current evidence, metres (None: no returns).
    pub fn height_range(&self, cx: i64, cy: i64) -> Option<(f32, f32)> {
        let e = self.data(cx, cy)?.evidence();
        (e.n > 0).then_some((e.zmin, e.zmax))
    }

    /// One line on why a cell is what it is (logs and diagnostics): class, the rules' verdict
    /// now, both evidence epochs, proprioception, last change.
    pub fn describe(&self, cx: i64, cy: i64) -> String {
        let Some(d) = self.data(cx, cy) else {
            return format!("cell ({cx}, {cy}) never observed");
        };
        let ep = |m: &Moments| {
            let s = m.stats();
            if m.n == 0 {
                "-".to_string()
            } else {
                format!(
                    "n {} mean {:.3} sd {:.3} [{:.3}, {:.3}]",
                    m.n,
                    s.mean_m,
                    s.var_m2.sqrt(),
                    m.zmin,
                    m.zmax
                )
            }
        };
        format!(
            "cell ({cx}, {cy}) {:?} (rules now: {:?}); cur {} from {:.1} m | prev {} from {:.1} m; closest view {:.1} m, accepted {:.1} s; headroom {}; driven {} at {:.3}; changed {} s; judged from {:.1} m; far-wiped {}; far-raised {}; canopy-suspect {}",
            d.class,
            self.explain(cx, cy),
            ep(&d.cur),
            d.cur_range_m,
            ep(&d.prev),
            d.prev_range_m,
            d.seen_range_m,
            d.accepted_s,
            d.headroom,
            d.driven,
            d.driven_z,
            d.stamp_s,
            d.class_range_m,
            d.far_wiped,
            d.far_raised,
            d.canopy_suspect
        )
    }

    /// Height statistics of one cell's current evidence (n = 0: none).
    pub fn height_stats(&self, cx: i64, cy: i64) -> CellStats {
        self.data(cx, cy)
            .map(|d| d.evidence().stats())
            .unwrap_or_default()
    }

    /// Height statistics of a cell's newest evidence epoch alone (`evidence_epoch_s` long):
    /// what the sensor saw there most recently.
    pub fn newest_height_stats(&self, cx: i64, cy: i64) -> CellStats {
        self.data(cx, cy).map(|d| d.cur.stats()).unwrap_or_default()
    }
}
