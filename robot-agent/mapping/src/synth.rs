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
