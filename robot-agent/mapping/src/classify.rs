//! Per-cell classification rules (docs/algorithms.md §4.6: the source's step 4, plus the plane-fit
//! slope and step tests that go beyond it). Pure functions over a 5x5 neighbourhood of cell
//! statistics, so every rule is unit-tested on its own.

use crate::config::Config;

/// Height statistics of one cell's evidence.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CellStats {
    /// Number of points.
    pub n: u32,
    /// Mean height, metres (map frame).
    pub mean_m: f64,
    /// Height variance, m^2.
    pub var_m2: f64,
    /// Highest point, metres.
    pub max_m: f64,
    /// Lowest point, metres.
    pub min_m: f64,
}

/// The mean of the side slopes within a limit (at most two, so no allocation per test).
struct Sides {
    limit: f64,
    sum: f64,
    n: u32,
}

impl Sides {
    fn new(limit: f64) -> Self {
        Self {
            limit,
            sum: 0.0,
            n: 0,
        }
    }
    /// Counts a side unless it jumps by more than the limit (then it is a step of its own).
    fn add(&mut self, d: f64) {
        if d.abs() <= self.limit {
            self.sum += d;
            self.n += 1;
        }
    }
    fn mean(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum / f64::from(self.n))
    }
}

/// The classification of a cell before inflation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Class {
    /// No (or too little) evidence.
    #[default]
    Unknown,
    /// Observed, but too few points around to decide (`points_around_threshold`).
    Undecided,
    /// Drivable.
    Traversable,
    /// Not drivable: roughness, step or slope.
    Obstacle,
    /// Not drivable: the observed surface ends at a drop-off or hole (no returns where the
    /// geometry says there should be some).
    NegativeObstacle,
    /// Ground was seen but no beam ever crossed the robot's body height above it: something
    /// may hang over it (a car body on its wheels, a table, a low branch), or it lies in the
    /// grazing shadow of an edge. Not known to be drivable; not an obstacle either.
    Overhung,
}

impl Class {
    /// Non-traversable (positive or negative obstacle).
    pub fn is_obstacle(self) -> bool {
        matches!(self, Class::Obstacle | Class::NegativeObstacle)
    }
}

/// Why a cell is an obstacle (first rule that fired), for tests and diagnostics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Too little evidence in the cell.
    Unobserved,
    /// Too few points around.
    Undecided,
    /// Drivable.
    Traversable,
    /// `s2 > max_variance`.
    Variance,
    /// `|h_c - h_n| > h_max` for an 8-neighbour (diagonals at their longer distance).
    NeighbourStep,
    /// The least-squares plane of the 3x3 neighbourhood is steeper than `alpha`.
    Slope,
    /// The cell's top is above a neighbour's top by more than `h_max`: a riser (curb face)
    /// inside the cell, whose points pull the mean halfway down the step.
    TopStep,
    /// A jump in a height profile through the cell, after removing the slopes on both sides.
    Step,
}

impl Verdict {
    /// The class this verdict gives.
    pub fn class(self) -> Class {
        match self {
            Verdict::Unobserved => Class::Unknown,
            Verdict::Undecided => Class::Undecided,
            Verdict::Traversable => Class::Traversable,
            _ => Class::Obstacle,
        }
    }
}

/// 5x5 neighbourhood, `nb[dy + 2][dx + 2]`; cells with fewer than `min_points_per_cell` points
/// must be passed as `n = 0`.
pub type Neighbourhood = [[CellStats; 5]; 5];

/// The thresholds the rules need, precomputed from the config.
#[derive(Clone, Copy, Debug)]
pub struct Rules {
    min_points: u32,
    points_around: u32,
    max_variance_m2: f64,
    h_max_m: f64,
    tan_alpha: f64,
    max_step_m: f64,
    cell_m: f64,
    grass_sd_m: (f64, f64),
}

impl Rules {
    /// Thresholds from a config.
    pub fn new(cfg: &Config) -> Self {
        Self {
            min_points: cfg.min_points_per_cell.max(1),
            points_around: cfg.points_around_threshold,
            max_variance_m2: cfg.max_variance_m2,
            h_max_m: cfg.h_max_m(),
            tan_alpha: cfg.alpha_deg.to_radians().tan(),
            max_step_m: cfg.max_step_m,
            cell_m: cfg.grid_size_m,
            grass_sd_m: (cfg.grass_sd_min_m, cfg.grass_sd_max_m),
        }
    }

    /// Minimum points for a cell to count as observed.
    pub fn min_points(&self) -> u32 {
        self.min_points
    }

    /// Classifies the centre cell of `nb`.
    pub fn classify(&self, nb: &Neighbourhood) -> Verdict {
        let c = nb[2][2];
        if c.n < self.min_points {
            return Verdict::Unobserved;
        }
        let around: u32 = (1..4)
            .flat_map(|y| (1..4).map(move |x| (y, x)))
            .map(|(y, x)| nb[y][x].n)
            .sum();
        if around < self.points_around {
            return Verdict::Undecided;
        }
        if c.var_m2 > self.max_variance_m2 {
            return Verdict::Variance;
        }
        let seen = |dx: i32, dy: i32| {
            let s = nb[(dy + 2) as usize][(dx + 2) as usize];
            (s.n >= self.min_points).then_some(s.mean_m)
        };
        // The source's rule; diagonal neighbours are sqrt(2) l away, so their limit scales with
        // the distance (otherwise a 20 deg slope facing a diagonal would read as a step).
        for dy in -1..=1 {
            for dx in -1..=1 {
                if dx == 0 && dy == 0 {
                    continue;
                }
                if let Some(h) = seen(dx, dy) {
                    let limit = if dx != 0 && dy != 0 {
                        self.h_max_m * std::f64::consts::SQRT_2
                    } else {
                        self.h_max_m
                    };
                    if (c.mean_m - h).abs() > limit {
                        return Verdict::NeighbourStep;
                    }
                }
            }
        }
        let top = |dx: i32, dy: i32| {
            let s = nb[(dy + 2) as usize][(dx + 2) as usize];
            (s.n >= self.min_points).then_some(s.max_m)
        };
        for dy in -1..=1 {
            for dx in -1..=1 {
                if dx == 0 && dy == 0 {
                    continue;
                }
                if let Some(t) = top(dx, dy) {
                    let limit = if dx != 0 && dy != 0 {
                        self.h_max_m * std::f64::consts::SQRT_2
                    } else {
                        self.h_max_m
                    };
                    if c.max_m - t > limit {
                        return Verdict::TopStep;
                    }
                }
            }
        }
        if let Some((gx, gy)) = self.plane_gradient(nb) {
            if gx.hypot(gy) > self.tan_alpha {
                return Verdict::Slope;
            }
        }
        // Step test: along x, y and both diagonals, the jump between the cell and its neighbour
        // minus the mean slope on either side. A kink (ramp toe) gives half its slope change, a
        // step its full height, so 5 cm and 10 cm separate even on sloped ground.
        let face_var = (0.25 * self.max_step_m).powi(2);
        // The profile compares grounds: a grass cell's returns stand U(0, a) above its ground,
        // lifting its mean by a/2, so a 10 cm strip in grass reads as 6.5 cm against the
        // grass's mean. Cells whose spread is grass-like (`grass_sd_min_m` to `grass_sd_max_m`:
        // above the sensor's noise, below a face's) are taken at their lowest return: n points
        // spread over [0, a] put it a/(n+1) above the ground, far steadier than the mean less
        // sqrt(3) sd, whose few-point spread estimate swung 5 cm curbs over the step limit.
        let (sd_lo, sd_hi) = self.grass_sd_m;
        let ground = |st: CellStats| {
            let sd = st.var_m2.sqrt();
            if sd > sd_lo && sd < sd_hi {
                st.min_m
            } else {
                st.mean_m
            }
        };
        let gseen = |dx: i32, dy: i32| {
            let st = nb[(dy + 2) as usize][(dx + 2) as usize];
            (st.n >= self.min_points).then(|| ground(st))
        };
        let gc = ground(c);
        for (ux, uy) in [(1, 0), (0, 1), (1, 1), (1, -1)] {
            for s in [-1, 1] {
                let (ax, ay) = (ux * s, uy * s);
                let Some(h1) = gseen(ax, ay) else { continue };
                let jump = h1 - gc;
                // A side that is itself a discontinuity (steeper than alpha) says nothing about
                // the slope here; it is that cell's own step.
                let side_limit = if ax != 0 && ay != 0 {
                    self.h_max_m * std::f64::consts::SQRT_2
                } else {
                    self.h_max_m
                };
                // The slopes beside come from the means, one estimator on both ends of each:
                // a grass cell's lowest return against a neighbour's mean (its spread just
                // outside the grass bounds) would read the grass's lift as a slope.
                let mut sides = Sides::new(side_limit);
                if let (Some(hb), Some(hc)) = (seen(-ax, -ay), seen(0, 0)) {
                    sides.add(hc - hb);
                }
                if let (Some(h2), Some(h1m)) = (seen(2 * ax, 2 * ay), seen(ax, ay)) {
                    sides.add(h2 - h1m);
                }
                let Some(slope) = sides.mean() else {
                    continue;
                };
                if (jump - slope).abs() > self.max_step_m {
                    return Verdict::Step;
                }
            }
            // A step whose face lies inside this cell splits its height between the two
            // neighbour jumps (this cell's mean sits halfway); across the cell it is whole:
            // compare the neighbours on either side, minus twice the slope outside them. Only
            // for a cell whose own heights spread like a face of that size (a face of height h
            // spreads its points with a standard deviation of at least ~h/4).
            if c.var_m2 < face_var {
                continue;
            }
            let (Some(lo), Some(hi)) = (seen(-ux, -uy), seen(ux, uy)) else {
                continue;
            };
            // Only smooth sides give the slope: one that jumps by a step is that step.
            let side_limit = self.max_step_m;
            let mut sides = Sides::new(side_limit);
            if let Some(h) = seen(-2 * ux, -2 * uy) {
                sides.add(lo - h);
            }
            if let Some(h) = seen(2 * ux, 2 * uy) {
                sides.add(h - hi);
            }
            let Some(slope) = sides.mean() else {
                continue;
            };
            if (hi - lo - 2.0 * slope).abs() > self.max_step_m {
                return Verdict::Step;
            }
            // And across the grounds, as the profile does (grass read at its lowest return; the
            // slopes beside stay on the means): against the grass's mean a 10 cm curb whose
            // face lies inside this cell read 7 cm and passed (`park`, own poses). In addition
            // to the means, not instead: a curb top holding a few face returns has a grass-like
            // spread too, and its lowest return would hide the step (`street`'s 10 cm band).
            let (Some(glo), Some(ghi)) = (gseen(-ux, -uy), gseen(ux, uy)) else {
                continue;
            };
            if (ghi - glo - 2.0 * slope).abs() > self.max_step_m {
                return Verdict::Step;
            }
        }
        Verdict::Traversable
    }

    /// Least-squares plane `h = a + gx x + gy y` through the observed cells of the 3x3 block,
    /// as a gradient (dimensionless rise per metre); None when too few cells span it.
    fn plane_gradient(&self, nb: &Neighbourhood) -> Option<(f64, f64)> {
        let (mut n, mut sx, mut sy, mut sxx, mut syy, mut sxy, mut sh, mut sxh, mut syh) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let c = nb[2][2].mean_m;
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let s = nb[(dy + 2) as usize][(dx + 2) as usize];
                if s.n < self.min_points {
                    continue;
                }
                let (x, y, h) = (
                    f64::from(dx) * self.cell_m,
                    f64::from(dy) * self.cell_m,
                    s.mean_m - c,
                );
                n += 1.0;
                sx += x;
                sy += y;
                sxx += x * x;
                syy += y * y;
                sxy += x * y;
                sh += h;
                sxh += x * h;
                syh += y * h;
            }
        }
        if n < 4.0 {
            return None;
        }
        // Centre the normal equations on the mean position, then solve the 2x2 system.
        let (mx, my, mh) = (sx / n, sy / n, sh / n);
        let (cxx, cyy, cxy) = (sxx - n * mx * mx, syy - n * my * my, sxy - n * mx * my);
        let (cxh, cyh) = (sxh - n * mx * mh, syh - n * my * mh);
        let det = cxx * cyy - cxy * cxy;
        let l2 = self.cell_m * self.cell_m;
        if det.abs() < 1e-6 * l2 * l2 {
            return None;
        }
        Some(((cyy * cxh - cxy * cyh) / det, (cxx * cyh - cxy * cxh) / det))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const L: f64 = 0.2;

    /// A neighbourhood sampled from a height function of the cell centre (x, y in metres), each
    /// cell with `n` points and variance `var`.
    fn field(f: impl Fn(f64, f64) -> f64, n: u32, var: f64) -> Neighbourhood {
        let mut nb = Neighbourhood::default();
        for (y, row) in nb.iter_mut().enumerate() {
            for (x, c) in row.iter_mut().enumerate() {
                let (px, py) = ((x as f64 - 2.0) * L, (y as f64 - 2.0) * L);
                *c = CellStats {
                    n,
                    mean_m: f(px, py),
                    var_m2: var,
                    max_m: f(px, py) + 2.0 * var.sqrt(),
                    min_m: f(px, py) - 2.0 * var.sqrt(),
                };
            }
        }
        nb
    }

    fn rules() -> Rules {
        Rules::new(&Config::default())
    }

    /// A step of `h` between x < edge and x >= edge, evaluated for cells on both sides.
    fn step_verdicts(h: f64) -> Vec<Verdict> {
        (0..3)
            .map(|shift| {
                let edge = -0.1 + shift as f64 * L; // cell borders at -0.1, 0.1, 0.3
                rules().classify(&field(|x, _| if x >= edge { h } else { 0.0 }, 20, 0.0002))
            })
            .collect()
    }

    #[test]
    fn flat_ground_is_traversable() {
        assert_eq!(
            rules().classify(&field(|_, _| 3.0, 20, 0.0003)),
            Verdict::Traversable
        );
    }

    #[test]
    fn ten_cm_step_is_an_obstacle_five_cm_is_not() {
        let v10 = step_verdicts(0.10);
        // The cells on both sides of the border are obstacles; the cell two away is not.
        assert_ne!(v10[0], Verdict::Traversable, "{v10:?}");
        assert_ne!(v10[1], Verdict::Traversable, "{v10:?}");
        assert_eq!(v10[2], Verdict::Traversable, "{v10:?}");
        assert!(
            step_verdicts(0.05)
                .iter()
                .all(|v| *v == Verdict::Traversable),
            "{:?}",
            step_verdicts(0.05)
        );
        // Downward steps too.
        assert!(step_verdicts(-0.10)
            .iter()
            .take(2)
            .all(|v| *v != Verdict::Traversable));
    }

    #[test]
    fn curb_detected_on_a_15_deg_slope_without_the_slope_tripping() {
        let g = 15f64.to_radians().tan();
        let on_slope = |step: f64| {
            rules().classify(&field(
                |x, y| g * y + if x >= 0.1 { step } else { 0.0 },
                20,
                0.0002,
            ))
        };
        assert_eq!(on_slope(0.0), Verdict::Traversable);
        assert_eq!(on_slope(0.05), Verdict::Traversable);
        assert_ne!(on_slope(0.10), Verdict::Traversable);
    }

    #[test]
    fn slopes_over_23_deg_are_obstacles_in_any_direction() {
        for deg in [10.0, 20.0, 22.0] {
            for dir in [0.0f64, 22.5, 45.0, 67.5] {
                let (c, s) = (dir.to_radians().cos(), dir.to_radians().sin());
                let g = f64::tan(f64::to_radians(deg));
                assert_eq!(
                    rules().classify(&field(|x, y| g * (c * x + s * y), 20, 0.0003)),
                    Verdict::Traversable,
                    "{deg} deg at {dir}"
                );
            }
        }
        for deg in [24.0, 30.0, 35.0] {
            for dir in [0.0f64, 22.5, 45.0] {
                let (c, s) = (dir.to_radians().cos(), dir.to_radians().sin());
                let g = f64::tan(f64::to_radians(deg));
                assert_ne!(
                    rules().classify(&field(|x, y| g * (c * x + s * y), 20, 0.0003)),
                    Verdict::Traversable,
                    "{deg} deg at {dir}"
                );
            }
        }
    }

    #[test]
    fn ramp_toe_of_20_deg_is_not_a_step() {
        let g = 20f64.to_radians().tan();
        for shift in 0..3 {
            let x0 = -0.2 + shift as f64 * L;
            let v = rules().classify(&field(|x, _| g * (x - x0).max(0.0), 20, 0.0003));
            assert_eq!(v, Verdict::Traversable, "toe at {x0}");
        }
    }

    #[test]
    fn rough_cells_fail_on_variance() {
        assert_eq!(
            rules().classify(&field(|_, _| 0.0, 20, 0.003)),
            Verdict::Variance
        );
    }

    #[test]
    fn sparse_cells_are_undecided_or_unknown() {
        let mut nb = field(|_, _| 0.0, 1, 0.0);
        assert_eq!(rules().classify(&nb), Verdict::Unobserved);
        nb[2][2].n = 3;
        assert_eq!(rules().classify(&nb), Verdict::Undecided);
    }
}

#[cfg(test)]
mod grass_tests {
    use super::*;

    /// Grass (returns U(0, 4 cm) above the ground, plus 5 mm noise) for x < 0, a hard top `h`
    /// above the ground for x >= 0, as cell statistics of a 5x5 block centred on the last grass
    /// cell.
    fn grass_then_top(h: f64) -> Neighbourhood {
        let (a, noise) = (0.04f64, 0.005f64);
        let grass = CellStats {
            n: 30,
            mean_m: a / 2.0,
            var_m2: a * a / 12.0 + noise * noise,
            max_m: a,
            // The expected lowest of 30 points spread evenly over [0, a].
            min_m: a / 31.0,
        };
        let top = CellStats {
            n: 30,
            mean_m: h,
            var_m2: noise * noise,
            max_m: h + 2.0 * noise,
            min_m: h - 2.0 * noise,
        };
        let mut nb = Neighbourhood::default();
        for row in nb.iter_mut() {
            for (x, c) in row.iter_mut().enumerate() {
                *c = if x <= 2 { grass } else { top };
            }
        }
        nb
    }

    /// A 9 cm strip made by `strip` is a step and a 5 cm one is not; without the grass reading
    /// the 9 cm strip hides in the grass.
    fn assert_9_cm_blocks_by_the_grass_reading(strip: impl Fn(f64) -> Neighbourhood) {
        let r = Rules::new(&Config::default());
        assert_eq!(r.classify(&strip(0.09)), Verdict::Step);
        assert_eq!(r.classify(&strip(0.05)), Verdict::Traversable);
        let off = Rules::new(&Config {
            grass_sd_max_m: 0.0,
            ..Config::default()
        });
        assert_eq!(off.classify(&strip(0.09)), Verdict::Traversable);
    }

    #[test]
    fn a_9_cm_strip_in_grass_blocks_a_5_cm_one_does_not() {
        // Against the grass's mean these read 7 and 3 cm (both under max_step_m, 7.5 cm);
        // against its ground, 9 and 5.
        assert_9_cm_blocks_by_the_grass_reading(grass_then_top);
    }

    /// Grass for x < 0, a hard top `h` for x > 0, and the curb's face inside the centre cell a
    /// quarter of the way in from the grass (three quarters of its points on the top): the
    /// park strip's near edge, whose cell's mean sits between the grass's mean and the top.
    fn face_in_cell(h: f64) -> Neighbourhood {
        let mut nb = grass_then_top(h);
        let (grass, top) = (nb[2][1], nb[2][3]);
        let (w, d) = (0.75, h - grass.mean_m);
        let face = CellStats {
            n: 40,
            mean_m: w * top.mean_m + (1.0 - w) * grass.mean_m,
            var_m2: w * top.var_m2 + (1.0 - w) * grass.var_m2 + w * (1.0 - w) * d * d,
            max_m: top.max_m,
            min_m: grass.min_m,
        };
        for row in nb.iter_mut() {
            row[2] = face;
        }
        nb
    }

    #[test]
    fn a_9_cm_strip_whose_face_lies_inside_the_cell_blocks_against_grass() {
        // Across the face cell: 9 cm against the grass's ground, 7 cm against its mean (under
        // max_step_m), and no neighbour jump reaches a step on its own.
        assert_9_cm_blocks_by_the_grass_reading(face_in_cell);
    }
}
