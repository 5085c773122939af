//! The bench's drive, shared with `examples/park_digest.rs`: the simulated VLP-16 in the
//! built-in `park` world (grass, curbs, trees, benches, walkers), driving a 10 m loop at
//! 0.8 m/s, 250 sweeps in the map frame at the true poses.

use mapping::RobotPose;
use nalgebra::Point3;

/// A sweep in the map frame with what the mapper needs alongside.
pub struct Sweep {
    /// Returns, map frame.
    pub points: Vec<[f32; 3]>,
    /// The sensor's map-frame position.
    pub origin: [f64; 3],
    /// The robot under it.
    pub robot: RobotPose,
}

/// The 250 sweeps of the drive, in order (one every 0.1 s of simulated time).
pub fn sweeps() -> Vec<Sweep> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let scenario = sim::Scenario::load(root.join("config/scenarios/park.toml")).expect("park");
    let cfg = sim::SimConfig {
        start: Some(common::geom::Pose2::new(-30.0, 0.0, 0.0)),
        ..sim::SimConfig::default()
    };
    let mut s = sim::Simulation::new(&scenario, cfg);
    let ext = s.lidar_extrinsic();
    let mut out = Vec::new();
    // Out along the path and back (turning on the spot), 10 m each way.
    let mut t = 0.0;
    while out.len() < 250 {
        let phase = (t / 12.5) as usize % 3;
        let (v, w) = match phase {
            0 => (0.8, 0.0),
            1 => (0.0, std::f64::consts::PI / 12.5),
            _ => (0.8, 0.0),
        };
        let step = s.step(0.01, v, w);
        t += 0.01;
        if let Some(scan) = step.scan {
            let base = s
                .truth_pose_at(scan.stamp_s)
                .unwrap_or_else(|| s.truth_pose());
            let lidar = base * ext;
            let m = lidar.to_homogeneous().cast::<f32>();
            let points = scan
                .points
                .iter()
                .map(|p| {
                    let q = m.transform_point(&Point3::new(p.x, p.y, p.z));
                    [q.x, q.y, q.z]
                })
                .collect();
            let b = base.translation.vector;
            let fwd = base.rotation * nalgebra::Vector3::x();
            let o = lidar.translation.vector;
            out.push(Sweep {
                points,
                origin: [o.x, o.y, o.z],
                robot: RobotPose {
                    x_m: b.x,
                    y_m: b.y,
                    z_m: b.z,
                    yaw_rad: fwd.y.atan2(fwd.x),
                },
            });
        }
    }
    out
}
