//! The pose graph's keyframes against the simulator's truth (`robot-agent map eval`,
//! `graph_keyframes`): where the live localisation had the robot when each keyframe was made,
//! and where the graph has it at the end (after its optimisations), both against the true
//! pose at the keyframe's stamp. What tells a correction that helped from one that did harm.

use nalgebra::Isometry3;
use serde::Serialize;

/// One keyframe's errors, metres and degrees.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct KeyframeError {
    /// Stamp, seconds.
    pub t_s: f64,
    /// True position, metres.
    pub x_m: f64,
    /// True position, metres.
    pub y_m: f64,
    /// Live localisation's horizontal error when the keyframe was made, metres.
    pub live_xy_m: f64,
    /// The graph's final pose: horizontal error, metres.
    pub graph_xy_m: f64,
    /// Live yaw error, degrees.
    pub live_yaw_deg: f64,
    /// The graph's final yaw error, degrees.
    pub graph_yaw_deg: f64,
    /// Live height error (estimate less truth), metres.
    pub live_z_m: f64,
    /// The graph's final height error, metres.
    pub graph_z_m: f64,
    /// Live tilt error (angle between the estimated and the true up axis), degrees.
    pub live_tilt_deg: f64,
    /// The graph's final tilt error, degrees.
    pub graph_tilt_deg: f64,
}

/// Keyframe errors over a run with the graph on.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct GraphKeyframes {
    /// Keyframes scored.
    pub keyframes: usize,
    /// Mean live horizontal error, metres.
    pub live_xy_mean_m: f64,
    /// Largest live horizontal error, metres.
    pub live_xy_max_m: f64,
    /// Mean horizontal error of the graph's final poses, metres.
    pub graph_xy_mean_m: f64,
    /// Largest horizontal error of the graph's final poses, metres.
    pub graph_xy_max_m: f64,
    /// Mean absolute live yaw error, degrees.
    pub live_yaw_mean_deg: f64,
    /// Mean absolute yaw error of the graph's final poses, degrees.
    pub graph_yaw_mean_deg: f64,
    /// Mean absolute live height error, metres.
    pub live_z_mean_m: f64,
    /// Mean absolute height error of the graph's final poses, metres.
    pub graph_z_mean_m: f64,
    /// Mean live tilt error, degrees.
    pub live_tilt_mean_deg: f64,
    /// Mean tilt error of the graph's final poses, degrees.
    pub graph_tilt_mean_deg: f64,
    /// Every keyframe.
    pub per_keyframe: Vec<KeyframeError>,
}

/// What a run records as keyframes are made: the truth and the live pose at each.
#[derive(Clone, Debug, Default)]
pub struct KeyframeLog {
    seen: Vec<(Isometry3<f64>, Isometry3<f64>)>,
}

impl KeyframeLog {
    /// After a sweep: when the graph has just made a keyframe, records the true pose at its
    /// stamp and the live estimate.
    pub fn record(&mut self, rig: &super::Rig) {
        let Some(g) = rig.agent.localiser().graph() else {
            return;
        };
        let kfs = g.graph().keyframes();
        let Some(k) = kfs.last().filter(|_| kfs.len() > self.seen.len()) else {
            return;
        };
        let (Some(truth), Some(live)) = (
            rig.sim.truth_pose_at(k.stamp_s),
            rig.agent.localiser().pose_at_scan(),
        ) else {
            return;
        };
        // A keyframe is made per sweep at most: the log stays in step with the graph.
        while self.seen.len() < kfs.len() {
            self.seen.push((truth, live.iso));
        }
    }

    /// Scores the graph's final keyframe poses (`(stamp, pose)`, oldest first, in the order
    /// they were recorded) and the live ones against the truth.
    pub fn score(&self, graph: &[(f64, Isometry3<f64>)]) -> GraphKeyframes {
        let mut out = GraphKeyframes::default();
        for (&(truth, live), &(t_s, pose)) in self.seen.iter().zip(graph) {
            let xy = |p: &Isometry3<f64>| (p.translation.vector - truth.translation.vector).xy();
            let yaw = |p: &Isometry3<f64>| {
                let (_, _, a) = p.rotation.euler_angles();
                let (_, _, b) = truth.rotation.euler_angles();
                common::geom::wrap_angle(a - b).to_degrees()
            };
            let z = |p: &Isometry3<f64>| p.translation.z - truth.translation.z;
            let up = |p: &Isometry3<f64>| p.rotation * nalgebra::Vector3::z();
            let tilt = |p: &Isometry3<f64>| up(p).angle(&up(&truth)).to_degrees();
            out.per_keyframe.push(KeyframeError {
                t_s,
                x_m: truth.translation.x,
                y_m: truth.translation.y,
                live_xy_m: xy(&live).norm(),
                graph_xy_m: xy(&pose).norm(),
                live_yaw_deg: yaw(&live),
                graph_yaw_deg: yaw(&pose),
                live_z_m: z(&live),
                graph_z_m: z(&pose),
                live_tilt_deg: tilt(&live),
                graph_tilt_deg: tilt(&pose),
            });
        }
        let k = &out.per_keyframe;
        out.keyframes = k.len();
        let n = k.len().max(1) as f64;
        out.live_xy_mean_m = k.iter().map(|e| e.live_xy_m).sum::<f64>() / n;
        out.graph_xy_mean_m = k.iter().map(|e| e.graph_xy_m).sum::<f64>() / n;
        out.live_xy_max_m = k.iter().map(|e| e.live_xy_m).fold(0.0, f64::max);
        out.graph_xy_max_m = k.iter().map(|e| e.graph_xy_m).fold(0.0, f64::max);
        out.live_yaw_mean_deg = k.iter().map(|e| e.live_yaw_deg.abs()).sum::<f64>() / n;
        out.graph_yaw_mean_deg = k.iter().map(|e| e.graph_yaw_deg.abs()).sum::<f64>() / n;
        out.live_z_mean_m = k.iter().map(|e| e.live_z_m.abs()).sum::<f64>() / n;
        out.graph_z_mean_m = k.iter().map(|e| e.graph_z_m.abs()).sum::<f64>() / n;
        out.live_tilt_mean_deg = k.iter().map(|e| e.live_tilt_deg).sum::<f64>() / n;
        out.graph_tilt_mean_deg = k.iter().map(|e| e.graph_tilt_deg).sum::<f64>() / n;
        out
    }
}
