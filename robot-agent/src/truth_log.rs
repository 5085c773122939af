//! The simulator's truth, written as the live robot runs (`robot-agent sim --truth-out FILE`):
//! one line `t_unix_ms x_m y_m yaw_rad` every 0.1 s of simulated time, flushed per line so a
//! test can judge where the robot really drove (not where it thinks it drove) while it runs.

use std::io::Write;

/// Truth pose period, seconds.
const PERIOD_S: f64 = 0.1;

/// See the module docs.
pub struct TruthLog {
    out: std::io::BufWriter<std::fs::File>,
    next_s: f64,
}

impl TruthLog {
    /// Creates (truncates) the file.
    pub fn create(path: &std::path::Path) -> anyhow::Result<Self> {
        let f = std::fs::File::create(path)
            .map_err(|e| anyhow::anyhow!("--truth-out {}: {e}", path.display()))?;
        Ok(Self {
            out: std::io::BufWriter::new(f),
            next_s: 0.0,
        })
    }

    /// Records the truth at session time `t_s` when one is due.
    pub fn record(&mut self, t_s: f64, t_unix_ms: u64, truth: &common::geom::Pose2) {
        if t_s < self.next_s {
            return;
        }
        self.next_s = (self.next_s + PERIOD_S).max(t_s);
        let line = format!(
            "{t_unix_ms} {:.4} {:.4} {:.4}\n",
            truth.x_m, truth.y_m, truth.yaw_rad
        );
        // A full disk must not stop the robot; the test reading the file will say so.
        if self
            .out
            .write_all(line.as_bytes())
            .and_then(|()| self.out.flush())
            .is_err()
        {
            tracing::warn!("truth log: write failed");
        }
    }
}
