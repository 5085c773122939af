//! Parameters that adapt to the sensor and the motion as scans come in (docs/algorithms.md §3.6):
//! the ideas of KISS-ICP (Vizzo et al., RA-L 2023), written for this pipeline.
//!
//! - Scale from the data: the scan's extent is a high percentile of its point ranges. A scan
//!   whose sampled cloud exceeds the point budget is voxelised at a size proportional to that
//!   extent (a 124k-point HDL-64E scan out to 80 m ends near 2k points at ~1 m, a VLP-16 scan
//!   under the budget is left as the robot's tuned sampling makes it), and the map's insertion
//!   spacing follows the voxel.
//! - Correspondence threshold from the motion-prediction error: the deviation between the prior
//!   (constant velocity or odometry) and the registered pose, with its rotation part taken as arc
//!   length at the scan's extent, collected over recent scans that moved; the gate is a multiple
//!   (3 sigma) of its RMS, bounded.
//! - Recovery: a registration that fails is retried from the same prior with the gate widened
//!   (coarse) and then refined at the normal gate from the coarse result (fine).
//!
//! Every `"auto"` key of `config/slam.toml` is resolved here; [`AdaptiveConfig`] holds the knobs.

use crate::config::{Auto, FilterConfig, IcpConfig, MapConfig};
use crate::icp::IcpResult;
use crate::se3;
use nalgebra::Isometry3;
use serde::Deserialize;
use std::collections::VecDeque;

/// Knobs of the adaptive parameters (`[adaptive]` in config/slam.toml).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptiveConfig {
    /// Percentile (0..100) of a scan's point ranges taken as its extent (a robust maximum).
    pub range_percentile: f64,
    /// Share of the previous extent estimate kept per scan (exponential smoothing, 0..1).
    pub range_smoothing: f64,
    /// A scan whose sampled cloud is expected to have at most this many points is not voxelised
    /// (`filters.voxel_size_m = "auto"`).
    pub point_budget: usize,
    /// Voxel size per metre of extent for scans over the budget (0.02: one cube per 1/50 of it).
    pub voxel_per_range: f64,
    /// Bounds of the automatic voxel, metres.
    pub min_voxel_m: f64,
    /// Upper bound of the automatic voxel, metres.
    pub max_voxel_m: f64,
    /// `map.min_dist_new_point_m = "auto"`: this share of the voxel...
    pub new_point_per_voxel: f64,
    /// ...and at least this, metres.
    pub min_new_point_m: f64,
    /// `icp.max_match_dist_m = "auto"`: the gate before any prediction error was seen, metres.
    pub initial_match_dist_m: f64,
    /// The gate is this many RMS prediction errors (KISS-ICP's 3 sigma)...
    pub sigma_factor: f64,
    /// ...bounded below by this, metres...
    pub min_match_dist_m: f64,
    /// ...and above by this, metres.
    pub max_match_dist_m: f64,
    /// A scan's prediction error counts only when the sensor moved at least this far since the
    /// previous scan, metres (standing still says nothing about the prediction).
    pub min_motion_m: f64,
    /// Prediction errors of this many recent moving scans make the RMS.
    pub window_scans: usize,
    /// Failed registrations are retried this many times, each with the gate widened by
    /// `recovery_factor` again (0: the prior is used at once).
    pub recovery_attempts: usize,
    /// Gate multiplier per recovery attempt.
    pub recovery_factor: f64,
}

impl Default for AdaptiveConfig {
    fn default() -> Self {
        Self {
            range_percentile: 99.0,
            range_smoothing: 0.9,
            point_budget: 8000,
            voxel_per_range: 0.02,
            min_voxel_m: 0.05,
            max_voxel_m: 2.0,
            new_point_per_voxel: 0.35,
            min_new_point_m: 0.07,
            initial_match_dist_m: 2.0,
            sigma_factor: 3.0,
            min_match_dist_m: 1.1,
            max_match_dist_m: 8.0,
            min_motion_m: 0.02,
            window_scans: 100,
            recovery_attempts: 2,
            recovery_factor: 3.0,
        }
    }
}

/// The `percentile` (0..100) of the ranges of `points` (sensor frame), from at most ~4k of them
/// (evenly strided: a percentile needs no more); `None` without a finite non-zero range.
pub fn range_percentile_m(points: &[sensing::Point], percentile: f64) -> Option<f64> {
    let step = (points.len() / 4096).max(1);
    let mut r: Vec<f32> = points
        .iter()
        .step_by(step)
        .map(|p| p.range_m())
        .filter(|r| r.is_finite() && *r > 0.0)
        .collect();
    if r.is_empty() {
        return None;
    }
    let k = ((percentile.clamp(0.0, 100.0) / 100.0) * (r.len() - 1) as f64).round() as usize;
    let (_, v, _) = r.select_nth_unstable_by(k, f32::total_cmp);
    Some(f64::from(*v))
}

/// The voxel size for a scan of extent `range_m` whose sampled cloud is expected to hold
/// `expected_points`: 0 (none) within the budget, else proportional to the extent, bounded.
pub fn voxel_size_m(range_m: f64, expected_points: usize, cfg: &AdaptiveConfig) -> f64 {
    if expected_points <= cfg.point_budget {
        return 0.0;
    }
    (range_m * cfg.voxel_per_range).clamp(cfg.min_voxel_m, cfg.max_voxel_m)
}

/// The motion-prediction error of one scan, metres: the translation of `prior^-1 * pose` plus
/// its rotation as the chord it sweeps at `range_m` (a rotation error moves far points most).
pub fn prediction_error_m(prior: &Isometry3<f64>, pose: &Isometry3<f64>, range_m: f64) -> f64 {
    let d = prior.inverse() * pose;
    se3::translation_norm(&d) + 2.0 * range_m * (se3::rotation_angle(&d) / 2.0).sin()
}

/// Recent motion-prediction errors and the correspondence gate they imply.
#[derive(Clone, Debug, Default)]
pub struct MatchGate {
    /// Squared errors of recent moving scans, oldest first.
    squared: VecDeque<f64>,
}

impl MatchGate {
    /// Records the prediction error of a scan that moved `motion_m` since the previous one.
    pub fn observe(&mut self, error_m: f64, motion_m: f64, cfg: &AdaptiveConfig) {
        if !error_m.is_finite() || motion_m < cfg.min_motion_m {
            return;
        }
        self.squared.push_back(error_m * error_m);
        while self.squared.len() > cfg.window_scans.max(1) {
            self.squared.pop_front();
        }
    }

    /// The gate, metres: `sigma_factor` RMS errors, bounded; the initial gate before any error.
    pub fn threshold_m(&self, cfg: &AdaptiveConfig) -> f64 {
        if self.squared.is_empty() {
            return cfg.initial_match_dist_m;
        }
        let rms = (self.squared.iter().sum::<f64>() / self.squared.len() as f64).sqrt();
        (cfg.sigma_factor * rms).clamp(cfg.min_match_dist_m, cfg.max_match_dist_m)
    }
}

/// The adaptive state of one SLAM session: the scan extent and the match gate.
#[derive(Clone, Debug, Default)]
pub struct Adaptive {
    range_m: Option<f64>,
    gate: MatchGate,
}

/// The parameters resolved for one scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    /// Reading filters with the voxel size resolved.
    pub filters: FilterConfig,
    /// ICP with the gate resolved.
    pub icp: IcpConfig,
    /// Map maintenance with the insertion spacing resolved.
    pub map: MapConfig,
    /// The scan extent used, metres.
    pub range_m: f64,
}

impl Adaptive {
    /// Resolves the `"auto"` keys for the scan `raw` (sensor frame); fixed keys pass through.
    pub fn resolve(
        &mut self,
        raw: &[sensing::Point],
        filters: &FilterConfig,
        icp: &IcpConfig,
        map: &MapConfig,
        cfg: &AdaptiveConfig,
    ) -> Resolved {
        if let Some(r) = range_percentile_m(raw, cfg.range_percentile) {
            let a = cfg.range_smoothing.clamp(0.0, 1.0);
            self.range_m = Some(self.range_m.map_or(r, |old| a * old + (1.0 - a) * r));
        }
        let range_m = self.range_m.unwrap_or(0.0);
        let mut f = filters.clone();
        let voxel = match filters.voxel_size_m {
            Auto::Fixed(v) => v,
            Auto::Auto => {
                let expected = raw.len() as f64 / filters.keep_every_n.max(1) as f64
                    * filters.keep_probability.clamp(0.0, 1.0);
                voxel_size_m(range_m, expected as usize, cfg)
            }
        };
        // An automatic voxel grid already bounds the density, evenly; the random max-density
        // thinning on top would strip near-range surfaces (on the indoor registration pair it
        // biased roll by ~0.3 deg).
        if filters.voxel_size_m == Auto::Auto && voxel > 0.0 {
            f.max_density_per_m3 = 0.0;
        }
        f.voxel_size_m = Auto::Fixed(voxel);
        let mut i = icp.clone();
        if i.max_match_dist_m == Auto::Auto {
            i.max_match_dist_m = Auto::Fixed(self.gate.threshold_m(cfg));
        }
        let mut m = map.clone();
        if m.min_dist_new_point_m == Auto::Auto {
            m.min_dist_new_point_m =
                Auto::Fixed((cfg.new_point_per_voxel * voxel).max(cfg.min_new_point_m));
        }
        Resolved {
            filters: f,
            icp: i,
            map: m,
            range_m,
        }
    }

    /// Feeds back one registered scan: `prior` was the prediction, `pose` the result and
    /// `previous` the pose of the scan before (for the motion gate).
    pub fn observe(
        &mut self,
        prior: &Isometry3<f64>,
        pose: &Isometry3<f64>,
        previous: &Isometry3<f64>,
        cfg: &AdaptiveConfig,
    ) {
        let range_m = self.range_m.unwrap_or(0.0);
        let motion = se3::translation_norm(&(previous.inverse() * pose));
        self.gate
            .observe(prediction_error_m(prior, pose, range_m), motion, cfg);
    }
}

/// Registers with the gate widened to `wide_m` first and refines the result at the gate of `icp`
/// (used when the motion is unknown: the second scan, whose prior assumes standing still).
/// Returns the refined result when usable, else the coarse one.
pub fn coarse_to_fine(
    register: impl Fn(&Isometry3<f64>, &IcpConfig) -> IcpResult,
    init: &Isometry3<f64>,
    icp: &IcpConfig,
    wide_m: f64,
) -> IcpResult {
    let coarse_cfg = IcpConfig {
        max_match_dist_m: Auto::Fixed(wide_m.max(icp.match_dist_m())),
        ..icp.clone()
    };
    let coarse = register(init, &coarse_cfg);
    if !coarse.status.is_ok() {
        return coarse;
    }
    let fine = register(&coarse.pose, icp);
    if fine.status.is_ok() {
        fine
    } else {
        coarse
    }
}

/// Retries a failed registration (coarse to fine): from `prior` with the gate of `icp` widened
/// by `recovery_factor` per attempt (up to `max_match_dist_m` x the factor), then refined from
/// that result at the normal gate. Returns the first usable result, or `None`.
pub fn recover(
    register: impl Fn(&Isometry3<f64>, &IcpConfig) -> IcpResult,
    prior: &Isometry3<f64>,
    icp: &IcpConfig,
    cfg: &AdaptiveConfig,
) -> Option<IcpResult> {
    let gate = icp.match_dist_m();
    let mut wide = gate;
    for _ in 0..cfg.recovery_attempts {
        wide *= cfg.recovery_factor.max(1.0);
        let coarse_cfg = IcpConfig {
            max_match_dist_m: Auto::Fixed(wide),
            ..icp.clone()
        };
        let coarse = register(prior, &coarse_cfg);
        if !coarse.status.is_ok() {
            continue;
        }
        let fine = register(&coarse.pose, icp);
        return Some(if fine.status.is_ok() { fine } else { coarse });
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use sensing::Point;

    fn ring(n: usize, r: f32) -> Vec<Point> {
        (0..n)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / n as f32;
                Point::xyz(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect()
    }

    #[test]
    fn range_percentile_ignores_a_few_far_outliers() {
        let mut pts = ring(990, 10.0);
        pts.extend(ring(10, 500.0));
        pts.push(Point::xyz(0.0, 0.0, 0.0)); // no return
        let p = range_percentile_m(&pts, 95.0).unwrap();
        assert!((p - 10.0).abs() < 1e-4, "{p}");
        assert_eq!(range_percentile_m(&[], 95.0), None);
    }

    #[test]
    fn voxel_follows_extent_over_budget_and_is_off_within_it() {
        let c = AdaptiveConfig::default();
        // A 64-beam car scan (extent ~50 m, ~29k sampled points): ~1 m cubes.
        assert!((voxel_size_m(50.0, 29_000, &c) - 1.0).abs() < 1e-9);
        // Twice the extent, twice the cube; bounded above.
        assert!((voxel_size_m(100.0, 29_000, &c) - 2.0).abs() < 1e-9);
        assert_eq!(voxel_size_m(1000.0, 29_000, &c), c.max_voxel_m);
        // An indoor scan over budget still gets a cube, bounded below.
        assert_eq!(voxel_size_m(1.0, 29_000, &c), c.min_voxel_m);
        // Within the budget (a sampled VLP-16 scan): none.
        assert_eq!(voxel_size_m(50.0, 6_500, &c), 0.0);
    }

    #[test]
    fn resolve_keeps_fixed_keys_and_derives_auto_ones() {
        let c = AdaptiveConfig::default();
        let mut a = Adaptive::default();
        // 120k points out to 50 m, sampled 1/3 at 0.7: over budget.
        let scan = ring(120_000, 50.0);
        let f = FilterConfig::default();
        let r = a.resolve(&scan, &f, &IcpConfig::default(), &MapConfig::default(), &c);
        let v = r.filters.voxel_size_m.fixed().unwrap();
        assert!((v - 1.0).abs() < 1e-6, "{v}");
        assert_eq!(r.filters.max_density_per_m3, 0.0);
        assert!((r.map.min_dist_new_point_m.fixed().unwrap() - 0.35).abs() < 1e-6);
        assert_eq!(r.icp.max_match_dist_m, Auto::Fixed(c.initial_match_dist_m));
        let fixed = FilterConfig {
            voxel_size_m: Auto::Fixed(0.0),
            ..f
        };
        let r = a.resolve(
            &scan,
            &fixed,
            &IcpConfig::default(),
            &MapConfig::default(),
            &c,
        );
        assert_eq!(r.filters.voxel_size_m, Auto::Fixed(0.0));
        assert!((r.map.min_dist_new_point_m.fixed().unwrap() - c.min_new_point_m).abs() < 1e-9);
    }

    #[test]
    fn gate_is_three_sigma_of_recent_moving_errors() {
        let c = AdaptiveConfig::default();
        let mut g = MatchGate::default();
        assert_eq!(g.threshold_m(&c), c.initial_match_dist_m);
        // Standing still: not counted.
        g.observe(5.0, 0.0, &c);
        assert_eq!(g.threshold_m(&c), c.initial_match_dist_m);
        // Errors 0.6 and 0.8 m: RMS sqrt(0.5) -> gate 3 * 0.7071.
        g.observe(0.6, 1.0, &c);
        g.observe(0.8, 1.0, &c);
        let want = 3.0 * (0.5f64).sqrt();
        assert!(
            (g.threshold_m(&c) - want).abs() < 1e-9,
            "{}",
            g.threshold_m(&c)
        );
        // Tiny errors: bounded below; huge ones: bounded above.
        let mut small = MatchGate::default();
        small.observe(0.01, 1.0, &c);
        assert_eq!(small.threshold_m(&c), c.min_match_dist_m);
        let mut big = MatchGate::default();
        big.observe(100.0, 1.0, &c);
        assert_eq!(big.threshold_m(&c), c.max_match_dist_m);
        // Old errors leave the window.
        let w = AdaptiveConfig {
            window_scans: 2,
            ..c.clone()
        };
        let mut g = MatchGate::default();
        for e in [9.0, 0.5, 0.5] {
            g.observe(e, 1.0, &w);
        }
        assert!(
            (g.threshold_m(&w) - 1.5).abs() < 1e-9,
            "{}",
            g.threshold_m(&w)
        );
    }

    #[test]
    fn prediction_error_counts_rotation_as_arc_at_the_extent() {
        let prior = Isometry3::identity();
        let pose = se3::from_xyz_rpy([0.3, 0.4, 0.0], [0.0, 0.0, 0.0]);
        assert!((prediction_error_m(&prior, &pose, 50.0) - 0.5).abs() < 1e-12);
        let turned = se3::from_xyz_rpy([0.0; 3], [0.0, 0.0, 0.01]);
        let e = prediction_error_m(&prior, &turned, 50.0);
        assert!((e - 100.0 * (0.005f64).sin()).abs() < 1e-9, "{e}");
    }
}
