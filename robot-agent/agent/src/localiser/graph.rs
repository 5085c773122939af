//! The pose graph behind SLAM, as the localiser runs it (`[graph]` in `config/slam.toml`,
//! docs/algorithms.md §3.7).
//!
//! Keyframes are the SLAM poses carried into the map frame by the anchoring the graph started
//! with (`map<-slam` at its first keyframe), so the graph's world is the map frame and RTK fixes
//! enter it as they are (ENU at the datum). Each keyframe keeps its sweep (base frame, voxel
//! thinned, with normals) for loop verification. The graph is optimised when a loop closes or
//! when RTK comes back after an outage; the localiser then moves the frame to the graph's
//! correction at the newest keyframe, and the terrain map's recent heights follow that shift
//! like any other frame correction.

use nalgebra::{Isometry3, Point3, Vector3};
use sensing::Point;
use slam::graph::{GraphConfig, KeyframeSelector, LoopRejection, PoseGraph};
use std::sync::Arc;

/// What the graph did with one sweep.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GraphStep {
    /// A keyframe was made from the sweep.
    pub keyframe: bool,
    /// A loop closed at it.
    pub loop_closed: bool,
    /// The new `map<-slam` after an optimisation, when one ran.
    pub map_from_slam: Option<Isometry3<f64>>,
}

/// Counters for the status and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GraphStats {
    /// Keyframes made.
    pub keyframes: usize,
    /// GNSS factors added.
    pub gnss_factors: usize,
    /// Gravity factors added.
    pub gravity_factors: usize,
    /// Loops accepted.
    pub loops: usize,
    /// Optimisations run.
    pub optimisations: usize,
    /// Loop searches that found no usable descriptor on the keyframe (too few points, or a
    /// nearly empty descriptor: open field).
    pub loop_no_descriptor: usize,
    /// Loop searches with no stored place within `place_max_distance`.
    pub loop_no_candidate: usize,
    /// Candidates whose verification ICP failed.
    pub loop_icp_failed: usize,
    /// Candidates whose ICP converged with too few inliers or too loose a fit.
    pub loop_poor_fit: usize,
    /// Candidates that fit but would move the robot further than the graph can have drifted.
    pub loop_inconsistent: usize,
}

/// The graph and what feeds it.
pub struct GraphLocaliser {
    cfg: GraphConfig,
    graph: PoseGraph,
    selector: KeyframeSelector,
    /// `map<-slam` when the first keyframe was made: the graph's world is that map frame.
    map_from_slam0: Option<Isometry3<f64>>,
    /// The newest trusted fix not yet on a keyframe: (time, base_link position in the map).
    pending_fix: Option<(f64, Vector3<f64>)>,
    /// Time of the fix behind the newest GNSS factor.
    last_factor_fix_s: Option<f64>,
    /// The previous sweep: (stamp, SLAM position), for the velocity that carries a fix from
    /// its own time to the keyframe's.
    prev_scan: Option<(f64, Vector3<f64>)>,
    stats: GraphStats,
}

impl GraphLocaliser {
    /// A graph when `[graph] enabled`, else `None` (the localiser then runs as before).
    pub fn new(cfg: &GraphConfig) -> Option<Self> {
        cfg.enabled.then(|| Self {
            cfg: cfg.clone(),
            graph: PoseGraph::new(cfg.clone()),
            selector: KeyframeSelector::default(),
            map_from_slam0: None,
            pending_fix: None,
            last_factor_fix_s: None,
            prev_scan: None,
            stats: GraphStats::default(),
        })
    }

    /// Counters.
    pub fn stats(&self) -> GraphStats {
        self.stats
    }

    /// The graph (evaluation).
    pub fn graph(&self) -> &PoseGraph {
        &self.graph
    }

    /// The graph's best `map<-slam` for a SLAM pose made at `t_s` (its correction there,
    /// interpolated between keyframes, after the anchoring it started with): where a sweep
    /// mapped then belongs now. `None` before the first keyframe.
    pub fn map_from_slam_at(&self, t_s: f64) -> Option<Isometry3<f64>> {
        Some(self.graph.correction_at(t_s)? * self.map_from_slam0?)
    }

    /// A trusted (RTK fixed) fix: `base_m` is base_link's position in the map frame (the
    /// antenna's lever arm already removed). It goes on the next keyframe made within
    /// `gnss_max_age_s` of it.
    pub fn on_fix(&mut self, t_s: f64, base_m: Vector3<f64>) {
        if t_s.is_finite() && base_m.iter().all(|v| v.is_finite()) {
            self.pending_fix = Some((t_s, base_m));
        }
    }

    /// One localised sweep: `slam_pose` = `slam<-base_link`, `points` in the lidar frame,
    /// `map_from_slam` the anchoring now, `up_base` the world's up in base_link as a fresh
    /// gravity estimate has it (None: no fresh one).
    pub fn on_scan(
        &mut self,
        stamp_s: f64,
        slam_pose: &Isometry3<f64>,
        points: &[Point],
        base_from_lidar: &Isometry3<f64>,
        map_from_slam: &Isometry3<f64>,
        up_base: Option<Vector3<f64>>,
    ) -> GraphStep {
        let mut step = GraphStep::default();
        let p_slam = slam_pose.translation.vector;
        // SLAM's velocity over the last sweep interval (slam frame); none across a gap.
        let v_slam = self
            .prev_scan
            .filter(|(t, _)| stamp_s > *t && stamp_s - t <= 1.0)
            .map(|(t, p)| (p_slam - p) / (stamp_s - t));
        self.prev_scan = Some((stamp_s, p_slam));
        if !self.selector.accept(
            slam_pose,
            self.cfg.keyframe_min_travel_m,
            self.cfg.keyframe_min_rotation_rad,
        ) {
            return step;
        }
        step.keyframe = true;
        let map_from_slam0 = *self.map_from_slam0.get_or_insert(*map_from_slam);
        let cloud = keyframe_cloud(points, base_from_lidar, &self.cfg);
        let kf = self
            .graph
            .add_keyframe(stamp_s, map_from_slam0 * slam_pose, cloud);
        self.stats.keyframes += 1;
        if let Some(up) = up_base.filter(|_| self.cfg.gravity_sigma_rad > 0.0) {
            self.graph.add_gravity(kf, up, self.cfg.gravity_sigma_rad);
            self.stats.gravity_factors += 1;
        }
        let mut optimise = false;
        if let Some((t_fix, p)) = self.pending_fix {
            if (stamp_s - t_fix).abs() <= self.cfg.gnss_max_age_s {
                // The fix is where the robot was at its own time, not at the sweep's stamp
                // (a 10 Hz receiver's newest fix is up to a sweep period off it): carried to
                // the keyframe's time along SLAM's velocity. Left as it was, the offset is a
                // bias along the direction of travel (8 cm at 0.8 m/s and 0.1 s) that the
                // cm-tight factors would write into every keyframe and the rebuilt map.
                let v = v_slam.map_or_else(Vector3::zeros, |v| map_from_slam0.rotation * v);
                let p = p + v * (stamp_s - t_fix);
                // RTK back after an outage: the drifted stretch is pulled back by the graph.
                optimise |= self
                    .last_factor_fix_s
                    .is_some_and(|t| t_fix - t >= self.cfg.outage_min_s);
                self.graph.add_gnss(
                    kf,
                    p,
                    self.cfg.gnss_min_sigma_m,
                    2.0 * self.cfg.gnss_min_sigma_m,
                );
                self.last_factor_fix_s = Some(t_fix);
                self.stats.gnss_factors += 1;
                self.pending_fix = None;
            }
        }
        match self.graph.detect_loop(kf) {
            Ok(lc) => {
                tracing::info!(
                    "pose graph: loop {} -> {} (descriptor {:.3}, inliers {:.2}, rms {:.3} m)",
                    lc.from,
                    lc.to,
                    lc.descriptor_distance,
                    lc.inlier_ratio,
                    lc.rms_m
                );
                self.stats.loops += 1;
                step.loop_closed = true;
                optimise = true;
            }
            Err(LoopRejection::NoDescriptor) => self.stats.loop_no_descriptor += 1,
            Err(LoopRejection::NoCandidate) => self.stats.loop_no_candidate += 1,
            Err(LoopRejection::IcpFailed(st)) => {
                tracing::debug!("pose graph: loop candidate at keyframe {kf}: ICP {st:?}");
                self.stats.loop_icp_failed += 1;
            }
            Err(LoopRejection::PoorFit {
                inlier_ratio,
                rms_m,
            }) => {
                tracing::debug!(
                    "pose graph: loop candidate at keyframe {kf}: inliers {inlier_ratio:.2}, rms {rms_m:.3} m"
                );
                self.stats.loop_poor_fit += 1;
            }
            Err(LoopRejection::Inconsistent {
                correction_m,
                allowed_m,
            }) => {
                tracing::debug!(
                    "pose graph: loop candidate at keyframe {kf}: would move it {correction_m:.2} m, the graph can have drifted {allowed_m:.2} m"
                );
                self.stats.loop_inconsistent += 1;
            }
            Err(LoopRejection::Degenerate { constraint }) => {
                // Counted with the poor fits: it fits, but not firmly enough to be a loop.
                tracing::debug!(
                    "pose graph: loop candidate at keyframe {kf}: fit free along a direction (constraint {constraint:.4})"
                );
                self.stats.loop_poor_fit += 1;
            }
        }
        if optimise {
            self.graph.optimise();
            self.stats.optimisations += 1;
            step.map_from_slam = self.graph.correction(kf).map(|c| c * map_from_slam0);
        }
        step
    }
}

/// The sweep in base_link, within the descriptor's range, voxel-thinned, with normals.
fn keyframe_cloud(
    points: &[Point],
    base_from_lidar: &Isometry3<f64>,
    cfg: &GraphConfig,
) -> Option<Arc<slam::filters::OrientedCloud>> {
    let tf = base_from_lidar.cast::<f32>();
    let max_r = cfg.place_max_range_m as f32;
    let base: Vec<[f32; 3]> = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
        .map(|p| tf * Point3::new(p.x, p.y, p.z))
        .filter(|q| q.coords.xy().norm() < max_r)
        .map(|q| [q.x, q.y, q.z])
        .collect();
    let thinned = slam::filters::voxel_downsample(&base, cfg.keyframe_voxel_m as f32);
    if thinned.len() < 100 {
        return None;
    }
    let sensor = base_from_lidar.translation.vector.cast::<f32>();
    Some(Arc::new(slam::graph::keyframe_normals(
        thinned,
        [sensor.x, sensor.y, sensor.z],
        cfg.keyframe_voxel_m,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use slam::se3;

    /// A graph localiser with the default configuration, switched on.
    fn enabled_localiser() -> GraphLocaliser {
        GraphLocaliser::new(&GraphConfig {
            enabled: true,
            ..GraphConfig::default()
        })
        .expect("enabled")
    }

    #[test]
    fn rtk_returning_after_an_outage_moves_the_frame_back_smoothly() {
        // A straight 200 m drive east, a sweep every metre, SLAM drifting 0.05 deg of yaw per
        // metre; RTK fixed (the truth) except between 60 m and 140 m.
        let mut g = enabled_localiser();
        let anchor = Isometry3::identity();
        let mut slam_pose = Isometry3::identity();
        let step = se3::from_xyz_rpy([1.0, 0.0, 0.0], [0.0, 0.0, 0.05f64.to_radians()]);
        let mut corrected = None;
        for i in 0..=200 {
            let t = i as f64;
            let x = i as f64;
            if !(60..140).contains(&i) {
                g.on_fix(t, Vector3::new(x, 0.0, 0.0));
            }
            let s = g.on_scan(t, &slam_pose, &[], &Isometry3::identity(), &anchor, None);
            if let Some(m) = s.map_from_slam {
                assert!(corrected.is_none(), "one optimisation, at the return");
                assert!((140..=142).contains(&i), "optimised at {i}");
                corrected = Some((i, m));
            }
            slam_pose *= step;
        }
        let (i, m) = corrected.expect("optimised when RTK came back");
        // The drifted pose at the return, moved by the new anchoring, is back on the truth.
        let drifted = (0..i).fold(Isometry3::identity(), |p, _| p * step);
        let before = (drifted.translation.vector - Vector3::new(i as f64, 0.0, 0.0)).norm();
        let after = ((m * drifted).translation.vector - Vector3::new(i as f64, 0.0, 0.0)).norm();
        assert!(before > 3.0, "drift too small to test: {before}");
        assert!(after < 0.1, "{before} m -> {after} m");
        let st = g.stats();
        assert_eq!(st.optimisations, 1);
        assert_eq!(st.loops, 0);
        // A keyframe every 3 m (two 1 m steps fall a hair short of the 2 m), RTK on 120 m of 200.
        assert!(st.keyframes >= 60 && st.gnss_factors >= 30, "{st:?}");
    }

    #[test]
    fn fixes_newer_than_the_sweep_are_carried_back_to_its_stamp() {
        // 0.8 m/s east, a sweep every 0.1 s; the receiver's newest fix is always the one at the
        // sweep's end (0.1 s after its stamp, 8 cm further on). SLAM is exact; RTK is lost
        // between 40 s and 60 s, so the graph optimises when it returns. Taken at face value
        // the fixes would pull every keyframe 8 cm forward.
        let mut g = enabled_localiser();
        let anchor = Isometry3::identity();
        let v = 0.8;
        let mut optimised = false;
        for i in 0..=900 {
            let t = i as f64 * 0.1;
            if !(40.0..60.0).contains(&t) {
                g.on_fix(t + 0.1, Vector3::new(v * (t + 0.1), 0.0, 0.0));
            }
            let pose = se3::from_xyz_rpy([v * t, 0.0, 0.0], [0.0; 3]);
            optimised |= g
                .on_scan(t, &pose, &[], &Isometry3::identity(), &anchor, None)
                .map_from_slam
                .is_some();
        }
        assert!(optimised, "RTK came back: optimised");
        for k in g.graph().keyframes() {
            let along = k.pose.translation.x - v * k.stamp_s;
            assert!(along.abs() < 0.02, "keyframe at {} s: {along} m", k.stamp_s);
        }
    }
}
