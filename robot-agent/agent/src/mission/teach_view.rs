//! The local traversability seen at teach time (docs/algorithms.md §7.1): for every cell within
//! reach of the driven line, whether it was an obstacle then and how high its ground and top stood.
//!
//! On the return the robot sees the same ground again from other places and at other times;
//! where the two views disagree by a few centimetres (grazing angles, grass, the height drift of
//! the pose between teach and repeat) the mapper may call a cell on the taught line an obstacle
//! that the robot demonstrably drove through. The repeat asks this view instead of trusting the
//! class alone: an obstacle cell on the corridor is new only if something now stands higher
//! than what stood there at teach time by more than `new_obstacle_rise_m` (a parked car, a
//! fallen trunk). Routes taught in another session carry no view and are checked on the class.

use common::grid::Lattice;
use std::collections::HashMap;

/// One cell as it was at teach time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TaughtCell {
    /// The mapper classified it as an obstacle.
    pub obstacle: bool,
    /// Ground (mean) height, metres, map frame.
    pub ground_m: f32,
    /// Highest return, metres, map frame.
    pub top_m: f32,
}

impl TaughtCell {
    /// What a new obstacle must stand above: the ground of a free cell, the top of one that was
    /// an obstacle already (it is not new).
    fn reference_m(&self) -> f32 {
        if self.obstacle {
            self.top_m.max(self.ground_m)
        } else {
            self.ground_m
        }
    }
}

/// The teach-time cells along one route.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TeachView {
    cells: HashMap<(i64, i64), TaughtCell>,
}

impl TeachView {
    /// Captures the cells within `radius_m` of the polyline `points` through `lookup` (None: the
    /// cell was never observed, and stays out of the view).
    pub fn capture(
        points: &[(f64, f64)],
        radius_m: f64,
        lattice: &Lattice,
        lookup: impl Fn(i64, i64) -> Option<TaughtCell>,
    ) -> Self {
        let s = lattice.cell_size_f64();
        let r = (radius_m / s).ceil() as i64 + 1;
        let mut cells = HashMap::new();
        let mut visit = |x: f64, y: f64| {
            let (cx, cy) = lattice.cell_of(x, y);
            for dy in -r..=r {
                for dx in -r..=r {
                    let key = (cx + dx, cy + dy);
                    if cells.contains_key(&key) {
                        continue;
                    }
                    let (px, py) = lattice.cell_center_m(key.0, key.1);
                    if (px - x).hypot(py - y) > radius_m + 0.5 * s * std::f64::consts::SQRT_2 {
                        continue;
                    }
                    if let Some(c) = lookup(key.0, key.1) {
                        cells.insert(key, c);
                    }
                }
            }
        };
        for w in points.windows(2) {
            let (a, b) = (w[0], w[1]);
            let n = ((b.0 - a.0).hypot(b.1 - a.1) / (0.5 * s)).ceil().max(1.0) as usize;
            for k in 0..=n {
                let t = k as f64 / n as f64;
                visit(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
            }
        }
        if let [p] = points {
            visit(p.0, p.1);
        }
        Self { cells }
    }

    /// Cells held.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// True when no cell was captured.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// The cell at teach time, if it was observed.
    pub fn get(&self, cx: i64, cy: i64) -> Option<&TaughtCell> {
        self.cells.get(&(cx, cy))
    }

    /// Whether an obstacle cell whose evidence now stands up to `top_now_m` is new since teach
    /// time: unseen then, or standing more than `rise_m` above what stood there.
    pub fn is_new_obstacle(&self, cx: i64, cy: i64, top_now_m: Option<f32>, rise_m: f32) -> bool {
        match (self.cells.get(&(cx, cy)), top_now_m) {
            (Some(c), Some(top)) => top > c.reference_m() + rise_m,
            // No returns now (a drop-off judged from the geometry): trust the class.
            _ => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice() -> Lattice {
        Lattice::default()
    }

    #[test]
    fn captures_the_corridor_and_tells_new_obstacles_from_old_ground() {
        let l = lattice();
        let route = [(0.0, 0.0), (10.0, 0.0)];
        // Flat free ground at 0.1 m; one cell that was a bush (top 0.6 m) beside the line.
        let bush = l.cell_of(5.0, 0.3);
        let v = TeachView::capture(&route, 0.4, &l, |cx, cy| {
            Some(if (cx, cy) == bush {
                TaughtCell {
                    obstacle: true,
                    ground_m: 0.1,
                    top_m: 0.6,
                }
            } else {
                TaughtCell {
                    obstacle: false,
                    ground_m: 0.1,
                    top_m: 0.13,
                }
            })
        });
        // 50 cells along, about 5 across.
        assert!((200..=400).contains(&v.len()), "{} cells", v.len());
        let (cx, cy) = l.cell_of(3.0, 0.1);
        // The same ground seen a few centimetres off is not an obstacle; a car is.
        assert!(!v.is_new_obstacle(cx, cy, Some(0.18), 0.15));
        assert!(v.is_new_obstacle(cx, cy, Some(1.4), 0.15));
        // The bush is not new; something taller where it stood is.
        assert!(!v.is_new_obstacle(bush.0, bush.1, Some(0.62), 0.15));
        assert!(v.is_new_obstacle(bush.0, bush.1, Some(0.9), 0.15));
        // Cells never seen at teach time, and cells without returns now, count as new.
        let (fx, fy) = l.cell_of(5.0, 3.0);
        assert!(v.get(fx, fy).is_none());
        assert!(v.is_new_obstacle(fx, fy, Some(0.12), 0.15));
        assert!(v.is_new_obstacle(cx, cy, None, 0.15));
    }

    #[test]
    fn unobserved_cells_stay_out() {
        let l = lattice();
        let v = TeachView::capture(&[(0.0, 0.0), (2.0, 0.0)], 0.4, &l, |cx, _| {
            (cx % 2 == 0).then_some(TaughtCell {
                obstacle: false,
                ground_m: 0.0,
                top_m: 0.0,
            })
        });
        assert!(!v.is_empty());
        assert!(v.cells.keys().all(|(cx, _)| cx % 2 == 0));
    }
}
