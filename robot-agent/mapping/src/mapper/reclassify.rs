//! Classification (docs/algorithms.md §4.6-4.7 and §4.11, the source's step 4): which cells to
//! judge after an update (the dirty ones dilated by the rule neighbourhood, and those that got
//! evidence while out of reach), the verdict of [`crate::classify::Rules`] for each within the
//! processing distance, what the robot's own footprint and the missing headroom change about it,
//! and the order of the remaining stages (far rules, negative obstacles, inflation).

use super::cell_data::CellData;
use super::fast_hash::FastSet;
use super::window::Window;
use super::{norm2, Mapper, RobotPose, UpdateReport};
use crate::classify::{CellStats, Class, Neighbourhood};

impl Mapper {
    /// Reclassifies every cell of the window from the stored evidence (the full baseline).
    pub fn reclassify_all(&mut self) -> UpdateReport {
        let mut rep = UpdateReport::default();
        let Some(robot) = self.robot else { return rep };
        self.reclassify(Vec::new(), &robot, &mut rep);
        rep
    }

    /// Steps 4-6: classify the cells around `dirty` (or the whole window in full mode), find
    /// negative obstacles, and refresh inflation and costs where classes changed.
    pub(super) fn reclassify(
        &mut self,
        dirty: Vec<(i64, i64)>,
        robot: &RobotPose,
        rep: &mut UpdateReport,
    ) {
        let (rcx, rcy) = self.lattice.cell_of(robot.x_m, robot.y_m);
        self.win.cx0 = rcx;
        self.win.cy0 = rcy;
        let pd_cells = self.cfg.processing_distance_m / self.cfg.grid_size_m;
        self.win.begin_stats();
        let within = |cx: i64, cy: i64| norm2((cx - rcx) as f64, (cy - rcy) as f64) <= pd_cells;
        let todo = self.cells_to_classify(&dirty, (rcx, rcy), within);

        // Classification (step 4). Collect the cells whose class changed, and the cells whose
        // output may have changed without their class (their height, hits or stamp).
        let mut changed: Vec<(i64, i64)> = Vec::new();
        let mut refreshed: Vec<(i64, i64)> = Vec::new();
        for &(cx, cy) in &todo {
            if !within(cx, cy) {
                if let Some(d) = self.data(cx, cy).copied() {
                    if !self.full {
                        self.pending.insert((cx, cy));
                    }
                    self.judge_from_afar(cx, cy, &d, robot, &mut changed);
                    // Not classified out here, but its height is news for the tile.
                    refreshed.push((cx, cy));
                }
                continue;
            }
            if self.classify_close(cx, cy, robot, &mut changed) {
                rep.classified_cells += 1;
                refreshed.push((cx, cy));
            }
        }

        // Negative obstacles (step 6b).
        changed.extend(self.negative_obstacles(robot));
        self.win.end_stats();
        rep.class_changes = changed.len();

        // Inflation and costs (step 5), around cells whose class changed.
        self.refresh_outputs(&changed, refreshed, (rcx, rcy));
    }

    /// The cells to classify: the dirty ones dilated by the 5x5 rule neighbourhood (outside the
    /// window they wait in `pending`), and the pending cells now `within` reach; in full mode,
    /// every held cell of the planning window.
    fn cells_to_classify(
        &mut self,
        dirty: &[(i64, i64)],
        (rcx, rcy): (i64, i64),
        within: impl Fn(i64, i64) -> bool,
    ) -> Vec<(i64, i64)> {
        let mut todo: Vec<(i64, i64)> = Vec::new();
        let g = self.win.next_generation();
        if self.full {
            let h = i64::from(self.cfg.num_of_grid_cells / 2);
            for cy in rcy - h..rcy + h {
                for cx in rcx - h..rcx + h {
                    if self.data(cx, cy).is_some() {
                        todo.push((cx, cy));
                    }
                }
            }
            return todo;
        }
        let add = |win: &mut Window,
                   cx: i64,
                   cy: i64,
                   todo: &mut Vec<(i64, i64)>,
                   pending: &mut FastSet<(i64, i64)>| {
            if let Some(i) = win.local(cx, cy) {
                if win.mark[i] != g {
                    win.mark[i] = g;
                    todo.push((cx, cy));
                }
            } else {
                pending.insert((cx, cy));
            }
        };
        for &(cx, cy) in dirty {
            for dy in -2..=2 {
                for dx in -2..=2 {
                    add(
                        &mut self.win,
                        cx + dx,
                        cy + dy,
                        &mut todo,
                        &mut self.pending,
                    );
                }
            }
        }
        // Cells that got evidence while far away and are now within reach.
        let mut now: Vec<(i64, i64)> = self
            .pending
            .iter()
            .copied()
            .filter(|&(cx, cy)| within(cx, cy))
            .collect();
        now.sort_unstable();
        for (cx, cy) in now {
            self.pending.remove(&(cx, cy));
            add(&mut self.win, cx, cy, &mut todo, &mut self.pending);
        }
        todo
    }

    /// Classifies a held cell within the processing distance and records a change of class in
    /// `changed`; false when the cell is not held.
    fn classify_close(
        &mut self,
        cx: i64,
        cy: i64,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) -> bool {
        let Some(d) = self.data(cx, cy) else {
            return false;
        };
        let old = d.class;
        let new = if d.driven_free(self.cfg.stray_height_m as f32) {
            Class::Traversable
        } else {
            let nb = self.neighbourhood(cx, cy);
            let mut v = self.rules.classify(&nb).class();
            if v == Class::Traversable && !d.headroom {
                v = Class::Overhung;
            }
            // A negative obstacle stays one until the cell is actually observed, and the lip
            // of a drop stays one while the unobserved drop beside it does.
            if old == Class::NegativeObstacle
                && (v == Class::Unknown || (v == Class::Traversable && self.beside_drop(cx, cy)))
            {
                old
            } else {
                v
            }
        };
        // An obstacle judged from close by is not cleared by a verdict from much farther
        // away, where a 10 cm face is a couple of sparse returns (free space still clears
        // it: a wiped cell forgets where it was judged from).
        let dist = self.distance_m(cx, cy, robot) as f32;
        let judged_at = d.class_range_m;
        let far = dist > self.cfg.far_evidence_factor as f32 * judged_at + 1.0;
        let new = if old.is_obstacle() && !new.is_obstacle() && far {
            old
        } else {
            new
        };
        let seen_m = d.closest_view_m();
        let dm = self.data_mut(cx, cy);
        dm.far_wiped = false;
        dm.far_raised = false;
        dm.canopy_suspect = false;
        dm.class_seen_m = seen_m;
        if new != old {
            dm.class = new;
            dm.class_range_m = dist;
            changed.push((cx, cy));
        } else {
            dm.class_range_m = dm.class_range_m.min(dist);
        }
        true
    }

    /// The 5x5 neighbourhood of a cell as the rules see it.
    pub(super) fn neighbourhood(&self, cx: i64, cy: i64) -> Neighbourhood {
        let mut nb = Neighbourhood::default();
        let on = self.win.stats_on;
        let g = self.win.stats_generation;
        for (y, row) in nb.iter_mut().enumerate() {
            for (x, s) in row.iter_mut().enumerate() {
                let (nx, ny) = (cx + x as i64 - 2, cy + y as i64 - 2);
                // Neighbourhoods overlap (a cell is in up to 25 of them per update): inside
                // `reclassify`, where evidence stands still, each cell's stats are computed once.
                match self.win.local(nx, ny).filter(|_| on) {
                    Some(i) => {
                        let (cg, st) = self.win.stats[i].get();
                        *s = if cg == g {
                            st
                        } else {
                            let st = self.rule_stats(nx, ny);
                            self.win.stats[i].set((g, st));
                            st
                        };
                    }
                    None => *s = self.rule_stats(nx, ny),
                }
            }
        }
        nb
    }

    /// A cell as the rules see it: its evidence's stats, the driven ground when the evidence is
    /// too thin, or only the point count.
    fn rule_stats(&self, cx: i64, cy: i64) -> CellStats {
        let min = self.rules.min_points();
        let Some(d): Option<&CellData> = self.data(cx, cy) else {
            return CellStats::default();
        };
        let st = d.evidence().stats();
        if st.n >= min {
            st
        } else if d.driven {
            CellStats {
                n: min,
                mean_m: f64::from(d.driven_z),
                var_m2: 0.0,
                max_m: f64::from(d.driven_z),
                min_m: f64::from(d.driven_z),
            }
        } else {
            CellStats {
                n: st.n,
                ..CellStats::default()
            }
        }
    }
}
