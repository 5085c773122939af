//! The ray-model dynamic-point update of the map (docs/algorithms.md §3.5): which map points
//! this scan's beams passed through, looked up in direction bins and a coarse range image of
//! the scan, and the Bayes update of their P(dynamic). Split from `map.rs`, which keeps the
//! point store and its index.

use crate::config::DynamicConfig;
use crate::filters::OrientedCloud;
use nalgebra::{Isometry3, Vector3};
use sensing::Point;

/// atan2 to ~1e-5 rad (a bin index only needs to be consistent; the beam angle itself is
/// computed exactly), several times cheaper than libm's on 100k points a scan. Branch-free, so
/// loops over whole scans vectorise.
pub(super) fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (mn, mx) = (ax.min(ay), ax.max(ay));
    let a = if mx > 0.0 { mn / mx } else { 0.0 };
    let s = a * a;
    // Minimax polynomial for atan on [0, 1].
    let r = a
        * (0.999_977_26
            + s * (-0.332_623_47
                + s * (0.193_543_46
                    + s * (-0.116_432_87 + s * (0.052_653_32 + s * -0.011_721_2)))));
    let r = if ay > ax { FRAC_PI_2 - r } else { r };
    let r = if x < 0.0 { PI - r } else { r };
    r.copysign(y)
}

/// Azimuth in `[0, 2 pi)` and elevation in `[0, pi]` (both shifted to be non-negative) of a
/// direction, with [`fast_atan2`].
pub(super) fn angles(p: &Vector3<f32>) -> (f32, f32) {
    let az = fast_atan2(p.y, p.x) + std::f32::consts::PI;
    let el = fast_atan2(p.z, (p.x * p.x + p.y * p.y).sqrt()) + std::f32::consts::FRAC_PI_2;
    (az, el)
}

/// Direction bins of a scan (a sparse range image) for beam look-ups, built by counting sort
/// over the elevation band the scan covers: O(points), no comparison sort. Kept in the map and
/// rebuilt for each scan: its bin table is a megabyte or two, which allocated afresh for every
/// scan cost page faults and a copy.
#[derive(Debug, Default)]
pub(super) struct BeamBins {
    /// Cell `c` holds `order[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    order: Vec<u32>,
    /// Each direction's (azimuth, elevation) bin, kept between the two passes.
    bins: Vec<(u32, u32)>,
    n_az: u32,
    row0: u32,
    n_rows: u32,
    inv_bin: f32,
}

impl BeamBins {
    fn cell(&self, az: f32, el: f32) -> (u32, u32) {
        (
            ((az * self.inv_bin) as u32).min(self.n_az - 1),
            (el * self.inv_bin) as u32,
        )
    }

    /// Bins the directions `dirs` (from [`angles`]), reusing the buffers.
    fn rebuild(&mut self, dirs: &[(f32, f32)], bin_rad: f32) {
        self.inv_bin = 1.0 / bin_rad;
        self.n_az = (std::f32::consts::TAU * self.inv_bin).ceil() as u32;
        let mut bins = std::mem::take(&mut self.bins);
        bins.clear();
        bins.extend(dirs.iter().map(|(a, e)| self.cell(*a, *e)));
        let n_az = self.n_az;
        let row0 = bins.iter().map(|b| b.1).min().unwrap_or(0);
        let row1 = bins.iter().map(|b| b.1).max().unwrap_or(0);
        let n_rows = row1 - row0 + 1;
        let cells = (n_rows * n_az) as usize;
        let start = &mut self.start;
        start.clear();
        start.resize(cells + 1, 0);
        for (a, e) in &bins {
            start[((e - row0) * n_az + a) as usize + 1] += 1;
        }
        for c in 0..cells {
            start[c + 1] += start[c];
        }
        // Each cell's entry serves as its fill cursor (ending at the next cell's start), then
        // the table moves up one place: no second table.
        self.order.clear();
        self.order.resize(dirs.len(), 0);
        for (i, (a, e)) in bins.iter().enumerate() {
            let c = ((e - row0) * n_az + a) as usize;
            self.order[start[c] as usize] = i as u32;
            start[c] += 1;
        }
        start.copy_within(0..cells, 1);
        start[0] = 0;
        self.bins = bins;
        self.row0 = row0;
        self.n_rows = n_rows;
    }

    /// Calls `f` with the indices of points in the 3x3 bins around the direction `(az, el)`.
    fn for_each_near(&self, az: f32, el: f32, mut f: impl FnMut(usize)) {
        let (a, e) = self.cell(az, el);
        for de in [-1i64, 0, 1] {
            let row = i64::from(e) + de - i64::from(self.row0);
            if row < 0 || row >= i64::from(self.n_rows) {
                continue;
            }
            for da in [self.n_az - 1, 0, 1] {
                let col = (a + da) % self.n_az;
                let c = row as usize * self.n_az as usize + col as usize;
                for &i in &self.order[self.start[c] as usize..self.start[c + 1] as usize] {
                    f(i as usize);
                }
            }
        }
    }
}

/// A coarse range image of a ring-structured scan (`Point::ring` set): per laser its elevation
/// and the nearest return per azimuth bin. Lasers that fired upward and got nothing back saw free
/// space to the sensor's range; downward ones with no return are unknown (absorbed, or blocked
/// by the robot itself within the minimum range).
pub(super) struct RangeImage {
    /// Lasers by ascending elevation (shifted as in [`angles`]).
    pub(super) els: Vec<f32>,
    /// Per laser (same order), range per azimuth bin; INFINITY = free, NAN = unknown.
    pub(super) rows: Vec<Vec<f32>>,
    n_az: u32,
    inv_bin: f32,
}

impl RangeImage {
    /// `None` when the scan carries no usable ring structure (a single ring, or rings whose
    /// points do not share an elevation, e.g. a merged or re-projected cloud).
    pub(super) fn new(
        rings_of: &[u16],
        dirs: &[(f32, f32)],
        ranges: &[f32],
        bin_rad: f32,
        free_min_el: f32,
        n_lasers: usize,
    ) -> Option<Self> {
        let n_rings = usize::from(*rings_of.iter().max()?) + 1;
        if !(2..=256).contains(&n_rings) {
            return None;
        }
        let inv_bin = 1.0 / bin_rad;
        let n_az = (std::f32::consts::TAU * inv_bin).ceil() as u32;
        let mut els: Vec<Vec<f32>> = vec![Vec::new(); n_rings];
        let mut img = vec![vec![f32::NAN; n_az as usize]; n_rings];
        for ((r, (az, el)), range) in rings_of.iter().zip(dirs).zip(ranges) {
            let a = ((az * inv_bin) as u32).min(n_az - 1);
            let cell = &mut img[usize::from(*r)][a as usize];
            // NAN (no return yet) or farther: this return is the nearest so far.
            if cell.is_nan() || *range < *cell {
                *cell = *range;
            }
            els[usize::from(*r)].push(*el);
        }
        let free_min = free_min_el + std::f32::consts::FRAC_PI_2;
        // Elevation per ring from its returns (median).
        let mut ring_el: Vec<Option<f32>> = Vec::with_capacity(n_rings.max(n_lasers));
        for mut e in els {
            if e.len() < 3 {
                ring_el.push(None);
                continue;
            }
            let mid = e.len() / 2;
            let (_, med, _) = e.select_nth_unstable_by(mid, f32::total_cmp);
            let med = *med;
            // A laser's returns share one elevation (up to de-skewing and range noise near the
            // sensor); if most do not, this is no ring.
            let off = e.iter().filter(|x| (**x - med).abs() > 0.02).count();
            if off * 4 > e.len() {
                return None;
            }
            ring_el.push(Some(med));
        }
        // A laser that got no return at all (pointing at the sky) still fired: when the known
        // rings lie on one line (evenly spaced lasers, as a VLP-16's), place the silent ones on
        // it, up to the sensor's `n_lasers`.
        ring_el.resize(n_lasers.max(ring_el.len()), None);
        let known: Vec<(f32, f32)> = ring_el
            .iter()
            .enumerate()
            .filter_map(|(i, e)| e.map(|e| (i as f32, e)))
            .collect();
        if known.len() >= 4 && known.len() < ring_el.len() {
            let n = known.len() as f32;
            let (sx, sy) = known
                .iter()
                .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
            let (mx, my) = (sx / n, sy / n);
            let sxx: f32 = known.iter().map(|(x, _)| (x - mx) * (x - mx)).sum();
            let sxy: f32 = known.iter().map(|(x, y)| (x - mx) * (y - my)).sum();
            let slope = sxy / sxx.max(1e-9);
            let line = |x: f32| my + slope * (x - mx);
            if known.iter().all(|(x, y)| (line(*x) - y).abs() < 0.005) {
                for (i, e) in ring_el.iter_mut().enumerate() {
                    e.get_or_insert(line(i as f32));
                }
            }
        }
        img.resize(ring_el.len(), vec![f32::NAN; n_az as usize]);
        let mut rings: Vec<(f32, Vec<f32>)> = Vec::with_capacity(ring_el.len());
        for (e, mut row) in ring_el.into_iter().zip(img) {
            let Some(med) = e else { continue };
            if med >= free_min {
                row.iter_mut()
                    .filter(|c| c.is_nan())
                    .for_each(|c| *c = f32::INFINITY);
            }
            rings.push((med, row));
        }
        if rings.len() < 2 {
            return None;
        }
        rings.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (els, rows) = rings.into_iter().unzip();
        Some(Self {
            els,
            rows,
            n_az,
            inv_bin,
        })
    }

    /// Angular distance in elevation from `el` to the nearest laser.
    fn ring_distance(&self, el: f32) -> f32 {
        let i = self.els.partition_point(|e| *e <= el);
        let below = i.checked_sub(1).map_or(f32::INFINITY, |j| el - self.els[j]);
        let above = self.els.get(i).map_or(f32::INFINITY, |e| e - el);
        below.min(above)
    }

    /// The lasers just below and above the direction `(az, el)`, if it lies between two of them
    /// no more than `max_gap_rad` apart: for each, its angular distance from `q` in elevation and
    /// its nearest return within one azimuth bin of `q` (NAN: none known).
    fn bracket(&self, az: f32, el: f32, max_gap_rad: f32) -> Option<[(f32, f32); 2]> {
        let i = self.els.partition_point(|e| *e <= el);
        if i == 0 || i == self.els.len() {
            return None;
        }
        let (lo, hi) = (self.els[i - 1], self.els[i]);
        if hi - lo > max_gap_rad {
            return None;
        }
        let a = ((az * self.inv_bin) as u32).min(self.n_az - 1);
        // Bins without a return of a downward laser say nothing (the laser may simply not have
        // fired into that bin); the nearest known return decides.
        let near = |row: &[f32]| {
            [self.n_az - 1, 0, 1]
                .iter()
                .map(|d| row[((a + d) % self.n_az) as usize])
                .filter(|r| !r.is_nan())
                .fold(f32::NAN, f32::min)
        };
        Some([
            (el - lo, near(&self.rows[i - 1])),
            (hi - el, near(&self.rows[i])),
        ])
    }
}

/// Bayes update of P(dynamic) for map points seen along a beam of the new scan. Returns how many
/// points were updated.
///
/// For each map point q the scan's beam closest in direction decides, if it passes within
/// `theta_max`: it ended near q (q is there: static evidence), in front of q (no evidence), or
/// beyond q (it went through where q was: dynamic evidence). How the source's formulas are read
/// (docs/algorithms.md §3.5):
///
/// - `P(U) = (1 - theta/theta_max)(1 - 2 phi/pi)` is the chance the observation is usable
///   (strongest on the beam axis, weakest at grazing incidence); an unusable observation teaches
///   nothing, so the belief is a `P(U)`-weighted blend of the Bayes posterior and the old value.
///   Applying the transition matrix on every unusable look would drift every point toward its
///   fixed point `(1 - alpha)/(2 - alpha - beta)` = 2/3, next to the 0.75 threshold.
/// - "Beyond q" needs the beam to end farther than the noise band `eps_d + |q| eps_a` plus the
///   spread a surface at incidence `phi` allows a beam `theta` off q, `|q| tan(theta) tan(phi)`:
///   ground seen at grazing angles is otherwise "passed through" by every beam just above it.
///   With that spread modelled, the incidence weight is floored (a person's trail of points, a
///   vertical sheet along their path, looks like a wall seen edge-on). The dynamic likelihood
///   ramps from 0.1 at the band to 0.9 one band farther. A return of a neighbouring beam right at
///   q is static evidence whatever the nearest beam did (the beam beside a pole's edge misses the
///   pole, the next one hits it).
///
/// A 16-laser sensor puts a beam within `theta_max` of few map points, and the parts of a person
/// at sensor height may never be looked at again that way. Ring-structured scans therefore add
/// coarser looks from a range image: a laser that fired toward q and got no return went through
/// it (within `theta_max`, or a few times that for points without a trusted surface, which
/// people's are); otherwise, when both lasers bracketing q's direction ended beyond q, the sensor
/// saw through q's place at its own resolution (weight `dynamic.range_image_weight`).
pub(super) fn update_dynamic(
    bins: &mut BeamBins,
    map: &OrientedCloud,
    p_dynamic: &mut [f32],
    raw_sensor: &[Point],
    map_from_sensor: &Isometry3<f64>,
    cfg: &DynamicConfig,
) -> usize {
    // Weight and tan(phi) of an unknown surface, the grazing limits, the reach of free lasers
    // for points without a trusted surface.
    const W_UNKNOWN: f32 = 0.8;
    const TAN_UNKNOWN: f32 = 1.0;
    const TAN_MAX: f32 = 20.0;
    const W_GRAZING_MIN: f32 = 0.25;
    const UNKNOWN_FREE_REACH: f32 = 3.0;
    let mut scan: Vec<Vector3<f32>> = Vec::with_capacity(raw_sensor.len());
    let mut rings_of: Vec<u16> = Vec::with_capacity(raw_sensor.len());
    for p in raw_sensor {
        if p.is_finite() && p.range_m() > 0.0 {
            scan.push(Vector3::new(p.x, p.y, p.z));
            rings_of.push(p.ring);
        }
    }
    if scan.is_empty() {
        return 0;
    }
    let ranges: Vec<f32> = scan.iter().map(|p| p.norm()).collect();
    let dirs: Vec<(f32, f32)> = scan.iter().map(angles).collect();
    let theta_max = cfg.beam_half_angle_rad as f32;
    bins.rebuild(&dirs, theta_max);
    let bins = &*bins;
    let image = if cfg.range_image_weight > 0.0 {
        RangeImage::new(
            &rings_of,
            &dirs,
            &ranges,
            cfg.range_image_bin_rad as f32,
            cfg.no_return_min_elevation_rad as f32,
            cfg.lasers,
        )
    } else {
        None
    };
    let image_w = cfg.range_image_weight as f32;
    let max_gap = cfg.range_image_max_gap_rad as f32;
    let sensor_from_map = map_from_sensor.inverse().cast::<f32>();
    let rot = sensor_from_map.rotation.to_rotation_matrix().into_inner();
    let tr = sensor_from_map.translation.vector;
    let max_r2 = (cfg.max_range_m * cfg.max_range_m) as f32;
    let (alpha, beta) = (cfg.alpha as f32, cfg.beta as f32);
    let (eps_d, eps_a) = (cfg.eps_d_m as f32, cfg.eps_a as f32);
    let mut updated = 0;
    for ((q_map, n_map), pd) in map
        .points
        .iter()
        .zip(&map.normals)
        .zip(p_dynamic.iter_mut())
    {
        let q = rot * Vector3::from(*q_map) + tr;
        let q_r2 = q.norm_squared();
        if q_r2 > max_r2 || q_r2 < 1e-6 {
            continue;
        }
        let q_r = q_r2.sqrt();
        let (az, el) = angles(&q);
        // With a ring structure, no beam can pass within theta_max of q unless a laser does.
        let near_ring = image
            .as_ref()
            .is_none_or(|im| im.ring_distance(el) < 2.0 * theta_max);
        let q_unit = q / q_r;
        let band = eps_d + q_r * eps_a;
        // The reading point whose beam passes closest to q (largest cosine; theta is small, so
        // theta = sin(theta) = |p x q| / (|p| |q|)), and the return nearest to q.
        let mut best: Option<(f32, usize)> = None;
        let mut d2_min = f32::INFINITY;
        if near_ring {
            bins.for_each_near(az, el, |i| {
                let cos = scan[i].dot(&q_unit) / ranges[i];
                if best.is_none_or(|(c, _)| cos > c) {
                    best = Some((cos, i));
                }
                d2_min = d2_min.min((scan[i] - q).norm_squared());
            });
        }
        let seen = d2_min <= band * band;
        let fine = best.and_then(|(_, i)| {
            let theta = (scan[i].cross(&q_unit).norm() / ranges[i]).min(1.0);
            (theta < theta_max).then_some((theta, ranges[i]))
        });
        let bracket = if seen || fine.is_some() {
            None
        } else {
            let Some(b) = image.as_ref().and_then(|im| im.bracket(az, el, max_gap)) else {
                continue;
            };
            // Cheap reject before any trigonometry: neither laser ended beyond q's noise band
            // and neither is a free one close enough to count.
            let free_near = b
                .iter()
                .any(|(de, r)| *r == f32::INFINITY && *de < UNKNOWN_FREE_REACH * theta_max);
            let nearer = b[0].1.min(b[1].1);
            if !free_near && (nearer.is_nan() || nearer <= q_r + band) {
                continue;
            }
            Some(b)
        };
        if !seen && fine.is_some_and(|(_, p_r)| p_r < q_r) {
            // Something in front of q: the beam never reached it, no evidence either way.
            continue;
        }
        let n = rot * Vector3::from(*n_map);
        let unknown = n == Vector3::zeros();
        let (incidence_w, tan_phi) = if unknown {
            // No trusted normal (edges, thin or scattered objects such as people).
            (W_UNKNOWN, TAN_UNKNOWN)
        } else {
            let cos_phi = n.dot(&q_unit).abs().min(1.0);
            let phi = cos_phi.acos();
            let tan_phi = (1.0 - cos_phi * cos_phi).sqrt() / cos_phi.max(1e-6);
            let w = (1.0 - 2.0 * phi / std::f32::consts::PI).max(W_GRAZING_MIN);
            (w, tan_phi.min(TAN_MAX))
        };
        // How far beyond q a beam `theta` off q may end on q's own surface (small angles).
        let allowed = |theta: f32| band + q_r * theta * tan_phi;
        // (usable, ramp): how much this look counts, and how strongly it says "dynamic".
        let look = if seen {
            Some((incidence_w, 0.0))
        } else if let Some((theta, p_r)) = fine {
            let ramp = ((p_r - q_r - allowed(theta)) / band).clamp(0.0, 1.0);
            Some(((1.0 - theta / theta_max) * incidence_w, ramp))
        } else if let Some([lo, hi]) = bracket {
            let reach = if unknown {
                UNKNOWN_FREE_REACH * theta_max
            } else {
                theta_max
            };
            let free = [lo, hi]
                .into_iter()
                .filter(|(de, r)| *de < reach && *r == f32::INFINITY)
                .map(|(de, _)| de)
                .reduce(f32::min);
            let beyond = |(de, r): (f32, f32)| r - q_r - allowed(de);
            let excess = beyond(lo).min(beyond(hi));
            match free {
                Some(de) => Some(((1.0 - de / reach) * incidence_w, 1.0)),
                None => {
                    (excess > 0.0).then(|| (image_w * incidence_w, (excess / band).clamp(0.0, 1.0)))
                }
            }
        } else {
            None
        };
        let Some((usable, ramp)) = look else { continue };
        if usable <= 0.0 {
            continue;
        }
        let l_dyn = 0.1 + 0.8 * ramp;
        let l_sta = 1.0 - l_dyn;
        let ps = 1.0 - *pd;
        let pd_pred = (1.0 - alpha) * ps + beta * *pd;
        let ps_pred = alpha * ps + (1.0 - beta) * *pd;
        let num = pd_pred * l_dyn;
        let den = num + ps_pred * l_sta;
        if den > 0.0 {
            *pd = usable * (num / den) + (1.0 - usable) * *pd;
            updated += 1;
        }
    }
    updated
}
