//! Synthetic worlds and a VLP-16-like ray caster, for tests and benchmarks (not for the robot).

/// A LiDAR model: rings evenly spread between two elevations, a fixed azimuth step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LidarSpec {
    /// Number of rings.
    pub rings: u32,
    /// Lowest ring elevation, degrees.
    pub min_elev_deg: f64,
    /// Highest ring elevation, degrees.
    pub max_elev_deg: f64,
    /// Azimuth step, degrees.
    pub az_step_deg: f64,
    /// Maximum range, metres.
    pub max_range_m: f64,
    /// Gaussian range noise, metres (1 sigma).
    pub noise_m: f64,
}

impl LidarSpec {
    /// Velodyne VLP-16 at 10 Hz (0.2 deg azimuth steps, 28 800 beams).
    pub fn vlp16() -> Self {
        Self {
            rings: 16,
            min_elev_deg: -15.0,
            max_elev_deg: 15.0,
            az_step_deg: 0.2,
            max_range_m: 40.0,
            noise_m: 0.01,
        }
    }
}

/// Deterministic generator (SplitMix64) so synthetic scans are identical everywhere.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal.
    pub fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-12), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// Casts every beam of `spec` from `sensor` (map frame, sensor level) into the height field
/// `height(x, y)` (a 2.5D world: every obstacle is a column) and returns the map-frame hits.
pub fn cast_scan(
    height: &dyn Fn(f64, f64) -> f64,
    sensor: [f64; 3],
    spec: &LidarSpec,
    rng: &mut Rng,
) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    let n_az = (360.0 / spec.az_step_deg).round() as u32;
    for ring in 0..spec.rings {
        let e = spec.min_elev_deg
            + (spec.max_elev_deg - spec.min_elev_deg) * f64::from(ring)
                / f64::from(spec.rings.max(2) - 1);
        let (ce, se) = (e.to_radians().cos(), e.to_radians().sin());
        for a in 0..n_az {
            let az = (f64::from(a) * spec.az_step_deg).to_radians();
            let (dx, dy, dz) = (ce * az.cos(), ce * az.sin(), se);
            // March with a step that grows with range: fine near the robot, cheap far away.
            let mut r = 0.3;
            let mut prev_r = r;
            while r < spec.max_range_m {
                let (x, y, z) = (sensor[0] + dx * r, sensor[1] + dy * r, sensor[2] + dz * r);
                if z > sensor[2] + 4.0 {
                    break; // above every synthetic world: the beam goes to the sky
                }
                let h = height(x, y);
                if z <= h {
                    // Refine between the last free sample and this one.
                    let (mut lo, mut hi) = (prev_r, r);
                    for _ in 0..8 {
                        let m = 0.5 * (lo + hi);
                        if sensor[2] + dz * m <= height(sensor[0] + dx * m, sensor[1] + dy * m) {
                            hi = m;
                        } else {
                            lo = m;
                        }
                    }
                    let rr = hi + rng.normal() * spec.noise_m;
                    out.push([
                        (sensor[0] + dx * rr) as f32,
                        (sensor[1] + dy * rr) as f32,
                        (sensor[2] + dz * rr) as f32,
                    ]);
                    break;
                }
                prev_r = r;
                r += (0.01 + r * 0.004).min(0.05);
            }
        }
    }
    out
}

/// Points on a lattice `n[0]` wide (along x) and `n[1]` deep, `step_m` apart, the first at
/// `first`, each at the height `z(x, y)`; x outer, y inner. The flat patches, strips and
/// canopies the mapper's tests feed it without a ray caster.
pub fn lattice_points(
    first: [f64; 2],
    step_m: f64,
    n: [usize; 2],
    z: impl Fn(f64, f64) -> f64,
) -> Vec<[f32; 3]> {
    let mut pts = Vec::with_capacity(n[0] * n[1]);
    for i in 0..n[0] {
        for j in 0..n[1] {
            let (x, y) = (first[0] + i as f64 * step_m, first[1] + j as f64 * step_m);
            pts.push([x as f32, y as f32, z(x, y) as f32]);
        }
    }
    pts
}

/// A mapper after a short drive along y = 0 from x = 0 to 5 m (six sweeps 0.1 s apart from
/// 10 s, sensor 0.7 m up, VLP-16 rings every 0.4 deg out to 20 m) through the height field
/// `world`, its sweeps and poses placed `offset_m` (y, z) off: a drifted pose when not zero.
pub fn short_drive(
    world: &dyn Fn(f64, f64) -> f64,
    seed: u64,
    offset_m: [f64; 2],
) -> crate::Mapper {
    let spec = LidarSpec {
        az_step_deg: 0.4,
        max_range_m: 20.0,
        ..LidarSpec::vlp16()
    };
    let [dy, dz] = offset_m;
    let mut m = crate::Mapper::new(crate::Config::default()).expect("the default config");
    let mut rng = Rng::new(seed);
    for i in 0..6 {
        let x = f64::from(i);
        let mut pts = cast_scan(world, [x, 0.0, 0.7], &spec, &mut rng);
        for p in &mut pts {
            p[1] += dy as f32;
            p[2] += dz as f32;
        }
        let robot = crate::RobotPose {
            x_m: x,
            y_m: dy,
            z_m: dz,
            yaw_rad: 0.0,
        };
        m.update_sweep(pts, [x, dy, 0.7 + dz], &robot, 10.0 + f64::from(i) * 0.1)
            .expect("a synthetic sweep");
    }
    m
}
