//! The far rules (beyond the source): what a view from beyond the processing distance may still
//! change about a cell. Out there a 10 cm face is a couple of sparse returns, so far evidence
//! never clears an obstacle judged on close evidence and raises one only in two narrow cases,
//! each a function here, tried in this order on the cell as it was before any of them:
//!
//! 1. [`Mapper::far_step`]: a cell judged traversable from close by whose lower neighbour,
//!    shadowed by a step when the robot passed, shows up in a later distant view;
//! 2. [`Mapper::stair_continues`]: a cell left unknown from close by that the rules now find a
//!    step, beside an obstacle judged from close by (a stair's upper treads);
//! 3. [`Mapper::rejudge_wiped`]: an obstacle whose evidence free space wiped out here is judged
//!    again, towards traversable or unknown only (a walker's trail behind the robot), and so is
//!    one whose verdict may rest on a canopy a ceiling wipe dropped, to overhung too;
//! 4. [`Mapper::rejudge_seen_nearer`]: an obstacle judged from close by on evidence seen only
//!    from afar is judged again when nearer evidence comes in, towards traversable, overhung or
//!    unknown only;
//! 5. [`Mapper::retract_stair`]: an obstacle rule 2 raised goes back to unknown once the rules
//!    find it traversable on level, fully observed ground.

use super::cell_data::CellData;
use super::{Mapper, RobotPose};
use crate::classify::{Class, Verdict};

impl Mapper {
    /// Applies the far rules to a held cell beyond the processing distance; `d` is the cell as
    /// it was before (every rule reads that, not what an earlier rule wrote).
    pub(super) fn judge_from_afar(
        &mut self,
        cx: i64,
        cy: i64,
        d: &CellData,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) {
        self.far_step(cx, cy, d, robot, changed);
        self.stair_continues(cx, cy, d, robot, changed);
        self.rejudge_wiped(cx, cy, d, robot, changed);
        self.rejudge_seen_nearer(cx, cy, d, robot, changed);
        self.retract_stair(cx, cy, d, changed);
    }

    /// A cell judged traversable from close by may still turn into an obstacle from out here:
    /// the lower side of a step that lay in the step's shadow when the robot passed shows up in
    /// a later, distant view. Only that way round (distant evidence never clears), and only for
    /// a step verdict against a lower neighbour seen from afar ([`Mapper::shadowed_step`]).
    fn far_step(
        &mut self,
        cx: i64,
        cy: i64,
        d: &CellData,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) {
        let pd = self.cfg.processing_distance_m as f32;
        if self.cfg.far_step_distance_m > 0.0
            && d.class == Class::Traversable
            && d.class_range_m <= pd
            && !d.driven_free(self.cfg.stray_height_m as f32)
            && self.distance_m(cx, cy, robot) <= self.cfg.far_step_distance_m
            && self.shadowed_step(cx, cy, d)
        {
            let dm = self.data_mut(cx, cy);
            dm.class = Class::Obstacle;
            dm.far_raised = false;
            changed.push((cx, cy));
        }
    }

    /// A cell left unknown from close by whose evidence came from out here, and whose rules now
    /// find a step, continues an obstacle judged from close by beside it: the upper treads of a
    /// stair whose lower ones were judged as the robot passed. Only beside such an obstacle, so
    /// sparse far views of open ground raise nothing.
    fn stair_continues(
        &mut self,
        cx: i64,
        cy: i64,
        d: &CellData,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) {
        let pd = self.cfg.processing_distance_m as f32;
        if self.cfg.far_step_distance_m > 0.0
            && d.class == Class::Unknown
            && d.class_range_m <= pd
            && !d.far_wiped
        {
            let beside_close_obstacle = (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    (dx != 0 || dy != 0)
                        && self
                            .data(cx + dx, cy + dy)
                            .is_some_and(|n| n.class == Class::Obstacle && n.class_range_m <= pd)
                })
            });
            if beside_close_obstacle
                && self.distance_m(cx, cy, robot) <= self.cfg.far_step_distance_m
                && matches!(
                    self.rules.classify(&self.neighbourhood(cx, cy)),
                    Verdict::Step | Verdict::NeighbourStep | Verdict::TopStep
                )
            {
                let dm = self.data_mut(cx, cy);
                dm.class = Class::Obstacle;
                dm.far_raised = true;
                changed.push((cx, cy));
            }
        }
    }

    /// A stair continuation (rule 2) is a verdict on far evidence, and far evidence takes it
    /// back: once the rules find the cell traversable on level, fully observed ground, it goes
    /// back to unknown (judged from close by as before, so the rule may raise it again). The
    /// step it was raised on may have been a neighbour's passing returns: on `loop` the rule had
    /// raised flat ground under a canopy 12-13 m from the path (most likely on the canopy's
    /// returns before the ground below was known), and no view from out there could clear it.
    fn retract_stair(&mut self, cx: i64, cy: i64, d: &CellData, changed: &mut Vec<(i64, i64)>) {
        if d.class != Class::Obstacle || !d.far_raised {
            return;
        }
        // Out here a stair's upper treads may be hidden behind their risers, and a cell on a
        // riser may hold returns of both treads: only a cell whose own returns lie within
        // `max_step_m` and whose neighbourhood as the rules read it (5 x 5) is all observed,
        // the means level with its own within half of it, goes back.
        let half_step = 0.5 * self.cfg.max_step_m;
        let min_n = self.rules.min_points();
        let own = d.evidence().stats();
        let level = own.n >= min_n
            && own.max_m - own.min_m < self.cfg.max_step_m
            && (-2..=2)
                .flat_map(|dy| (-2..=2).map(move |dx| (dx, dy)))
                .filter(|&o| o != (0, 0))
                .all(|(dx, dy)| {
                    self.data(cx + dx, cy + dy).is_some_and(|n| {
                        let n = n.evidence().stats();
                        n.n >= min_n && (n.mean_m - own.mean_m).abs() < half_step
                    })
                });
        if !level || self.rules.classify(&self.neighbourhood(cx, cy)).class() != Class::Traversable
        {
            return;
        }
        let dm = self.data_mut(cx, cy);
        dm.class = Class::Unknown;
        dm.far_raised = false;
        changed.push((cx, cy));
    }

    /// An obstacle that free space wiped out here (its evidence gone) is judged again from what
    /// is left, but only towards traversable or unknown: far evidence does not raise obstacles
    /// (the far-step rule aside). A trail a walker left behind the robot clears this way once
    /// the robot has turned and sees through it from afar. Only the wiped cell itself: the cells
    /// beside it that were steps against it keep their close verdicts, because a grazing beam
    /// can also slip past a ramp's side face inside its boundary cell, and clearing the foot of
    /// that face would be worse than a trail's fringe (measured on `slopes`: recall 0.988 ->
    /// 0.967). A ceiling wipe is another matter: what it dropped were returns above the
    /// ceiling, and the verdicts around that read them are judged again too (`canopy_suspect`).
    fn rejudge_wiped(
        &mut self,
        cx: i64,
        cy: i64,
        d: &CellData,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) {
        let again = d.class == Class::Obstacle && (d.far_wiped || d.canopy_suspect);
        if again {
            let dist = self.distance_m(cx, cy, robot);
            // A wiped cell without headroom keeps its verdict rather than turn overhung (a
            // grazing beam slips under a car's edge), unless what went was a canopy's returns:
            // overhung is what such a cell is.
            let new = self
                .cleared_class(cx, cy, d.headroom)
                .filter(|&c| c != Class::Overhung || d.canopy_suspect);
            if let Some(c) = new.filter(|&c| c != d.class) {
                let dm = self.data_mut(cx, cy);
                dm.class = c;
                if c == Class::Traversable {
                    dm.class_range_m = dist as f32;
                }
                changed.push((cx, cy));
            }
        }
    }

    /// An obstacle judged from close by on evidence seen only from beyond the processing
    /// distance (`CellData::class_seen_m`) is judged again from what the cell holds once
    /// evidence seen from nearer than that comes in, towards traversable, overhung (traversable,
    /// but no beam ever showed the space above it empty) or unknown only. Such a verdict is
    /// only as good as the far evidence it rested on: the robot passed within the processing
    /// distance but saw nothing new of the cell. On `loop` with the graph on, a rebuild's
    /// correction put a strip 23-29 m from the path 7 cm above its neighbours, the robot judged
    /// it a step from 11-12 m on those returns, and a view from 13 m that showed it flat could
    /// not clear it.
    fn rejudge_seen_nearer(
        &mut self,
        cx: i64,
        cy: i64,
        d: &CellData,
        robot: &RobotPose,
        changed: &mut Vec<(i64, i64)>,
    ) {
        let pd = self.cfg.processing_distance_m as f32;
        let nearer = d.class_seen_m > pd
            && d.class_seen_m.is_finite()
            && d.closest_view_m() < d.class_seen_m;
        if d.class != Class::Obstacle || d.far_wiped || !nearer {
            return;
        }
        let Some(new) = self.cleared_class(cx, cy, d.headroom) else {
            return;
        };
        let dist = self.distance_m(cx, cy, robot);
        let dm = self.data_mut(cx, cy);
        dm.class = new;
        dm.class_range_m = dist as f32;
        dm.class_seen_m = d.closest_view_m();
        changed.push((cx, cy));
    }

    /// What the rules make of a cell now, when that clears an obstacle: traversable (with
    /// `headroom`), overhung (traversable without it) or unknown; `None` when they still find
    /// an obstacle. The far rules clear towards these only.
    pub(super) fn cleared_class(&self, cx: i64, cy: i64, headroom: bool) -> Option<Class> {
        match self.rules.classify(&self.neighbourhood(cx, cy)).class() {
            Class::Traversable if headroom => Some(Class::Traversable),
            Class::Traversable => Some(Class::Overhung),
            Class::Unknown => Some(Class::Unknown),
            _ => None,
        }
    }

    /// Whether a step test (profile, neighbour or top) fires at a cell because of a neighbour
    /// seen only from beyond the processing distance that lies lower than the cell: the far
    /// side of a raised edge, in the edge's shadow while the robot passed on the near side. Far
    /// views that make a neighbour look higher (grass tops at grazing angles) do not count.
    ///
    /// Only a neighbour seen within `revisit_gap_s` of the cell's last close view: a later one
    /// is another visit's, in a frame the cell's heights were never moved onto when the cell
    /// lies beyond the revisit's reach (on `loop` a 6 cm offset between the first visit's and
    /// the last leg's far view raised 159 cells of open ground).
    fn shadowed_step(&self, cx: i64, cy: i64, d: &CellData) -> bool {
        let pd = self.cfg.processing_distance_m as f32;
        let gap_s = self.cfg.revisit_gap_s as f32;
        let epoch_s = self.cfg.evidence_epoch_s as f32;
        let same_visit =
            |n: &CellData| gap_s <= 0.0 || n.epoch as f32 * epoch_s - d.current_s <= gap_s;
        let own = d.evidence().stats();
        let lower_far = (-1..=1)
            .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
            .any(|(dx, dy)| {
                self.data(cx + dx, cy + dy).is_some_and(|n| {
                    let e = n.evidence();
                    e.n >= self.rules.min_points()
                        && n.cur_range_m.min(n.prev_range_m) > pd
                        && same_visit(n)
                        && e.stats().mean_m < own.mean_m - 0.5 * self.cfg.max_step_m
                })
            });
        lower_far
            && matches!(
                self.rules.classify(&self.neighbourhood(cx, cy)),
                Verdict::Step | Verdict::NeighbourStep | Verdict::TopStep
            )
    }
}

#[cfg(test)]
mod tests {
    use crate::synth::short_drive;
    use crate::{Class, Mapper, RobotPose};

    /// Flat ground with a 1 m box over x 6-7, y -0.5-0.5.
    fn world(x: f64, y: f64) -> f64 {
        if (6.0..7.0).contains(&x) && y.abs() < 0.5 {
            1.0
        } else {
            0.0
        }
    }

    /// The ground and the box seen from close by, driving along y = 0 from x = 0 to 5.
    fn mapped() -> Mapper {
        short_drive(&world, 5, [0.0, 0.0])
    }

    #[test]
    fn a_stair_continuation_goes_back_to_unknown_once_its_step_is_gone() {
        let mut m = mapped();
        let l = m.lattice();
        // Flat ground the stair rule had raised (its step was a neighbour's passing returns),
        // the foot of the box raised the same way, and flat ground judged an obstacle from
        // close by: seen now from 13-17 m, beyond the processing distance.
        let flat_raised = l.cell_of(3.0, 3.0);
        let foot_raised = l.cell_of(5.9, 0.1);
        let flat_close = l.cell_of(3.0, -3.0);
        // And flat ground raised two cells from one not seen from out here (a stair's upper
        // tread behind its riser).
        let beside_hidden = l.cell_of(2.0, 3.0);
        let hidden = (beside_hidden.0, beside_hidden.1 + 2);
        let h = m.data_mut(hidden.0, hidden.1);
        h.cur = Default::default();
        h.prev = Default::default();
        for (c, far_raised) in [
            (flat_raised, true),
            (foot_raised, true),
            (flat_close, false),
            (beside_hidden, true),
        ] {
            assert!(m.data(c.0, c.1).is_some(), "{c:?} observed");
            let d = m.data_mut(c.0, c.1);
            d.class = Class::Obstacle;
            d.far_raised = far_raised;
        }
        let robot = RobotPose {
            x_m: -10.0,
            y_m: 0.0,
            z_m: 0.0,
            yaw_rad: 0.0,
        };
        let mut changed = Vec::new();
        for c in [flat_raised, foot_raised, flat_close, beside_hidden] {
            let d = *m.data(c.0, c.1).unwrap();
            m.judge_from_afar(c.0, c.1, &d, &robot, &mut changed);
        }
        assert_eq!(m.class(flat_raised.0, flat_raised.1), Class::Unknown);
        assert!(!m.data(flat_raised.0, flat_raised.1).unwrap().far_raised);
        assert_eq!(
            m.class(foot_raised.0, foot_raised.1),
            Class::Obstacle,
            "the rules still find the box's step: {}",
            m.describe(foot_raised.0, foot_raised.1)
        );
        assert_eq!(
            m.class(flat_close.0, flat_close.1),
            Class::Obstacle,
            "far evidence does not clear a close verdict"
        );
        assert_eq!(
            m.class(beside_hidden.0, beside_hidden.1),
            Class::Obstacle,
            "a neighbour not seen may hide the step"
        );
        assert_eq!(changed, vec![flat_raised]);
    }
}
