//! Inflation and costs (docs/algorithms.md §4.10, the source's step 5): each output cell's state
//! and planner cost from its class and the nearest inflation source (an obstacle, and by default an
//! undecided cell). Within `obstacle_distance_m` a traversable cell is inflated (cost 254); beyond
//! it the cost decays from `cost_max` with `cost_decay_m` and ends at `cost_distance_m`.

use super::window::Window;
use super::Mapper;
use crate::classify::Class;
use crate::config::Config;
use common::grid::{Cell, CellState};

/// The (distance, dx, dy) offsets within `cost_distance_m`, nearest first: the first source met
/// along them is the nearest.
pub(super) fn inflation_offsets(cfg: &Config) -> Vec<(f64, i64, i64)> {
    let l = cfg.grid_size_m;
    let rc = (cfg.cost_distance_m / l).ceil() as i64;
    let mut offsets = Vec::new();
    for dy in -rc..=rc {
        for dx in -rc..=rc {
            let d = (dx as f64).hypot(dy as f64) * l;
            if d <= cfg.cost_distance_m + 1e-9 {
                offsets.push((d, dx, dy));
            }
        }
    }
    offsets.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
    offsets
}

impl Mapper {
    /// Step 5: rewrites the output cells around the cells whose class `changed` (or the whole
    /// planning window in full mode) and the `refreshed` cells, with the robot in cell
    /// `(rcx, rcy)`.
    pub(super) fn refresh_outputs(
        &mut self,
        changed: &[(i64, i64)],
        refreshed: Vec<(i64, i64)>,
        (rcx, rcy): (i64, i64),
    ) {
        let g = self.win.next_generation();
        let rc = (self.cfg.cost_distance_m / self.cfg.grid_size_m).ceil() as i64;
        let mut out_cells: Vec<(i64, i64)> = Vec::new();
        let mark = |win: &mut Window, cx: i64, cy: i64, out: &mut Vec<(i64, i64)>| {
            if let Some(i) = win.local(cx, cy) {
                if win.mark[i] != g {
                    win.mark[i] = g;
                    out.push((cx, cy));
                }
            }
        };
        if self.full {
            let h = i64::from(self.cfg.num_of_grid_cells / 2);
            for cy in rcy - h..rcy + h {
                for cx in rcx - h..rcx + h {
                    if self.data(cx, cy).is_some() {
                        mark(&mut self.win, cx, cy, &mut out_cells);
                    }
                }
            }
        } else {
            // Around each changed cell, which cells within twice the cost distance are sources,
            // looked up once: every output cell of the block finds its nearest source in that
            // map instead of looking up its own disc of neighbours.
            let w = 4 * rc + 1;
            let at = |x: i64, y: i64| ((y + 2 * rc) * w + x + 2 * rc) as usize;
            let mut src = vec![false; (w * w) as usize];
            for &(cx, cy) in changed {
                for dy in -2 * rc..=2 * rc {
                    for dx in -2 * rc..=2 * rc {
                        src[at(dx, dy)] = self
                            .data(cx + dx, cy + dy)
                            .is_some_and(|n| self.is_source(n.class));
                    }
                }
                for dy in -rc..=rc {
                    for dx in -rc..=rc {
                        let (ox, oy) = (cx + dx, cy + dy);
                        if self.data(ox, oy).is_none() {
                            continue;
                        }
                        let Some(i) = self.win.local(ox, oy) else {
                            continue;
                        };
                        if self.win.mark[i] == g {
                            continue;
                        }
                        self.win.mark[i] = g;
                        let near = self.inflation_from(|ex, ey| src[at(dx + ex, dy + ey)]);
                        let cell = self.output_cell(ox, oy, Some(near));
                        self.write_live(ox, oy, cell);
                    }
                }
            }
        }
        for (cx, cy) in out_cells {
            let cell = self.output_cell(cx, cy, None);
            self.write_live(cx, cy, cell);
        }
        // Cells whose class and nearby sources did not change keep their state and cost; only
        // their height, hits and stamp are news. (The nearest-source search is most of the
        // output's cost, and most refreshed cells are open ground with no source in reach.)
        if !self.full {
            for (cx, cy) in refreshed {
                let Some(i) = self.win.local(cx, cy) else {
                    continue;
                };
                if self.win.mark[i] == g {
                    continue;
                }
                self.win.mark[i] = g;
                let shown = self.cell(cx, cy);
                let cell = self.output_cell(cx, cy, Some((shown.state, shown.cost)));
                self.write_live(cx, cy, cell);
            }
        }
    }

    /// Whether a cell of this class is inflated around.
    fn is_source(&self, c: Class) -> bool {
        c.is_obstacle() || (self.cfg.inflate_undecided && c == Class::Undecided)
    }

    /// The final cell: state and cost from the class and the nearest inflation source. `kept`:
    /// the state and cost a traversable cell is to show, known already (no source near it
    /// changed since it was computed, or its nearest source was found another way).
    pub(super) fn output_cell(&self, cx: i64, cy: i64, kept: Option<(CellState, u8)>) -> Cell {
        let Some(d) = self.data(cx, cy) else {
            return Cell::UNKNOWN;
        };
        let height_cm = output_height_cm(d, self.rules.min_points());
        let (state, cost) = match d.class {
            Class::Unknown | Class::Undecided | Class::Overhung => return Cell::UNKNOWN,
            Class::Obstacle | Class::NegativeObstacle => (CellState::Obstacle, 255),
            Class::Traversable => match kept {
                Some(k @ (CellState::Traversable | CellState::Inflated, _)) => k,
                _ => self.inflation(cx, cy),
            },
        };
        Cell {
            state,
            cost,
            height_cm,
            hits: d.hits.max(1),
            stamp_s: d.stamp_s,
            rev: 0,
        }
    }

    /// State and cost of a traversable cell from the nearest inflation source around it.
    fn inflation(&self, cx: i64, cy: i64) -> (CellState, u8) {
        self.inflation_from(|dx, dy| {
            self.data(cx + dx, cy + dy)
                .is_some_and(|n| self.is_source(n.class))
        })
    }

    /// [`Self::inflation`] with `source(dx, dy)` telling whether the cell at that offset is an
    /// inflation source.
    fn inflation_from(&self, source: impl Fn(i64, i64) -> bool) -> (CellState, u8) {
        let near = self.offsets.iter().find(|(_, dx, dy)| source(*dx, *dy));
        match near {
            Some((dist, _, _)) if *dist <= self.cfg.obstacle_distance_m + 1e-9 => {
                (CellState::Inflated, 254)
            }
            Some((dist, _, _)) => {
                let c = f64::from(self.cfg.cost_max)
                    * (-(dist - self.cfg.obstacle_distance_m) / self.cfg.cost_decay_m).exp();
                (CellState::Traversable, c.round() as u8)
            }
            None => (CellState::Traversable, 0),
        }
    }
}

/// The height a cell's output shows, centimetres: its evidence's mean, or where the robot drove
/// over it when that is all there is; 0 for a drop-off seen only as missing ground.
pub(super) fn output_height_cm(d: &super::cell_data::CellData, min_points: u32) -> i16 {
    let ev = d.evidence().stats();
    if d.class == Class::NegativeObstacle && ev.n == 0 {
        return 0;
    }
    let height_m = if d.driven && ev.n < min_points {
        f64::from(d.driven_z)
    } else {
        ev.mean_m
    };
    (height_m * 100.0)
        .round()
        .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}
