//! What the mapper keeps about one lattice cell: its height evidence as running moments in two
//! time epochs, where it was seen and judged from, and what the robot's body and the beams
//! proved about it.

use crate::classify::{CellStats, Class};

/// Running height moments of a cell's points: enough for the mean, the variance, the highest
/// and the lowest point, and cheap to merge and to shift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Moments {
    pub(super) n: u32,
    pub(super) sz: f64,
    pub(super) szz: f64,
    /// Highest point; a riser's points pull a cell's mean halfway down the step, its top does not.
    pub(super) zmax: f32,
    /// Lowest point: the cell's ground when something stands on it.
    pub(super) zmin: f32,
}

impl Default for Moments {
    fn default() -> Self {
        Self {
            n: 0,
            sz: 0.0,
            szz: 0.0,
            zmax: f32::NEG_INFINITY,
            zmin: f32::INFINITY,
        }
    }
}

impl Moments {
    /// Adds one point at height `z`.
    #[inline]
    pub(super) fn add(&mut self, z: f64) {
        self.n += 1;
        self.sz += z;
        self.szz += z * z;
        self.zmax = self.zmax.max(z as f32);
        self.zmin = self.zmin.min(z as f32);
    }

    /// The moments of both point sets together.
    #[inline]
    pub(super) fn merged(&self, o: &Moments) -> Moments {
        Moments {
            n: self.n + o.n,
            sz: self.sz + o.sz,
            szz: self.szz + o.szz,
            zmax: self.zmax.max(o.zmax),
            zmin: self.zmin.min(o.zmin),
        }
    }

    /// The same points moved up by `dz`.
    #[inline]
    pub(super) fn shifted(&self, dz: f64) -> Moments {
        if self.n == 0 {
            return *self;
        }
        let n = f64::from(self.n);
        Moments {
            n: self.n,
            sz: self.sz + n * dz,
            szz: self.szz + 2.0 * dz * self.sz + n * dz * dz,
            zmax: self.zmax + dz as f32,
            zmin: self.zmin + dz as f32,
        }
    }

    /// Count, mean, variance and extremes as the rules read them.
    #[inline]
    pub(super) fn stats(&self) -> CellStats {
        if self.n == 0 {
            return CellStats::default();
        }
        let n = f64::from(self.n);
        let mean = self.sz / n;
        CellStats {
            n: self.n,
            mean_m: mean,
            var_m2: (self.szz / n - mean * mean).max(0.0),
            max_m: f64::from(self.zmax),
            min_m: f64::from(self.zmin),
        }
    }
}

/// Everything the mapper keeps about one lattice cell.
#[derive(Clone, Copy, Debug)]
pub(super) struct CellData {
    /// Evidence of the newest epoch with observations, and of the one before.
    pub(super) cur: Moments,
    pub(super) prev: Moments,
    /// Closest robot distance each epoch's evidence was seen from, metres.
    pub(super) cur_range_m: f32,
    pub(super) prev_range_m: f32,
    /// Closest robot distance any evidence the cell holds or held since it was last wiped was
    /// accepted from, metres: the far-view rule's yardstick. Not the epochs' own distances, which
    /// creep outwards with the robot as it drives away, one accepted epoch after the other.
    pub(super) seen_range_m: f32,
    /// Session time evidence was last accepted into the cell, seconds.
    pub(super) accepted_s: f32,
    /// Session time the cell's heights were last in the current view's frame: evidence
    /// accepted from within the processing distance, the robot drove over it, or a revisit's
    /// offset moved it there, seconds.
    pub(super) current_s: f32,
    /// Session time evidence from within the processing distance last made an earlier visit's
    /// cell current before a revisit's offset moved its old epochs, seconds (negative infinity:
    /// none waiting).
    pub(super) unaligned_s: f32,
    /// What a revisit's plane moved the earlier visit's epochs by when it made the cell current
    /// before any sweep within the processing distance sampled it, metres (NaN: nothing
    /// waiting): the cell is still sampled once, against its old epochs as they were.
    pub(super) plane_shift_m: f32,
    /// The newest evidence epoch a revisit's offset has moved, and the epoch the move was made
    /// in (both i64::MIN: never moved). The moved epochs stand in the frame of the move.
    pub(super) aligned: (i64, i64),
    /// Closest robot distance from which this cell was judged a drop-off, metres.
    pub(super) neg_range_m: f32,
    /// Closest robot distance from which the cell's current class was judged, metres.
    pub(super) class_range_m: f32,
    /// Closest robot distance the evidence behind the current class had been seen from when it
    /// was last judged from within the processing distance, metres: a verdict made from close
    /// by on evidence only ever seen from afar is no better than that evidence.
    pub(super) class_seen_m: f32,
    pub(super) epoch: i64,
    /// The `prev` epoch's index.
    pub(super) prev_epoch: i64,
    /// Points far above the cell's ground seen in one scan only, waiting for confirmation.
    pub(super) pending: Moments,
    pub(super) pending_scan: u32,
    /// MapCloud mode: the moments last received, to tell unchanged cells.
    pub(super) last_cloud: Moments,
    pub(super) hits: u8,
    pub(super) last_scan: u32,
    pub(super) stamp_s: u32,
    /// A beam crossed the band between `clear_low_m` and the robot's height above this cell's
    /// ground: the space the robot body needs was seen empty at least once.
    pub(super) headroom: bool,
    /// Free space wiped this cell from beyond the processing distance since it was last
    /// classified: it may be judged again from out there (towards traversable or unknown).
    pub(super) far_wiped: bool,
    /// A ceiling wipe dropped this cell's evidence, or a neighbour's within the rules' 5 x 5,
    /// since it was last classified: its verdict may rest on a canopy's returns, and far rule 3
    /// may judge it again from out there, to overhung too.
    pub(super) canopy_suspect: bool,
    /// The class is an obstacle the stair rule raised from beyond the processing distance (far
    /// rule 2): far evidence may take it back (far rule 5).
    pub(super) far_raised: bool,
    /// The robot's footprint covered this cell (proprioception), at this ground height.
    pub(super) driven: bool,
    pub(super) driven_z: f32,
    pub(super) class: Class,
}

impl Default for CellData {
    fn default() -> Self {
        Self {
            cur: Moments::default(),
            prev: Moments::default(),
            cur_range_m: f32::INFINITY,
            prev_range_m: f32::INFINITY,
            seen_range_m: f32::INFINITY,
            accepted_s: f32::NEG_INFINITY,
            current_s: f32::NEG_INFINITY,
            unaligned_s: f32::NEG_INFINITY,
            plane_shift_m: f32::NAN,
            aligned: (i64::MIN, i64::MIN),
            neg_range_m: f32::INFINITY,
            class_range_m: f32::INFINITY,
            class_seen_m: f32::INFINITY,
            epoch: 0,
            prev_epoch: 0,
            pending: Moments::default(),
            pending_scan: 0,
            last_cloud: Moments::default(),
            hits: 0,
            last_scan: 0,
            stamp_s: 0,
            headroom: false,
            far_wiped: false,
            far_raised: false,
            canopy_suspect: false,
            driven: false,
            driven_z: 0.0,
            class: Class::default(),
        }
    }
}

impl CellData {
    /// Every stored height moved by `dz` metres (a frame or pose correction).
    pub(super) fn shift_heights(&mut self, dz: f64) {
        self.cur = self.cur.shifted(dz);
        self.prev = self.prev.shifted(dz);
        self.pending = self.pending.shifted(dz);
        if self.driven {
            self.driven_z += dz as f32;
        }
    }

    /// Drops the cell's evidence (it held something that has gone, or returns it should never
    /// have taken), so later points rebuild it; its class may then be judged again from anywhere,
    /// from beyond the processing distance when `far`.
    pub(super) fn drop_evidence(&mut self, far: bool) {
        self.cur = Moments::default();
        self.prev = Moments::default();
        self.pending = Moments::default();
        self.cur_range_m = f32::INFINITY;
        self.prev_range_m = f32::INFINITY;
        self.seen_range_m = f32::INFINITY;
        self.class_range_m = f32::INFINITY;
        self.far_wiped = far;
        self.canopy_suspect = false;
    }

    /// The epochs with index `before` or earlier, and the driven height, moved up by `dz`
    /// metres: an earlier visit's evidence onto the current frame.
    pub(super) fn shift_epochs_before(&mut self, before: i64, dz: f64) {
        if self.cur.n > 0 && self.epoch <= before {
            self.cur = self.cur.shifted(dz);
        }
        if self.prev.n > 0 && self.prev_epoch <= before {
            self.prev = self.prev.shifted(dz);
        }
        if self.driven {
            self.driven_z += dz as f32;
        }
    }

    /// The cell belongs to an earlier visit (docs/algorithms.md §4.13): nothing from within the
    /// processing distance reached it for `gap_s` before `t_s`, and it holds evidence of epochs
    /// `before` or earlier, or was driven over.
    pub(super) fn is_earlier_visit(&self, t_s: f32, gap_s: f32, before: i64) -> bool {
        t_s - self.current_s > gap_s && (self.driven || self.newest_epoch_before(before).is_some())
    }

    /// An offset measured against epochs up to `until_epoch` applies to this cell's epochs up to
    /// `before`: it holds evidence there that no offset has moved yet, or the move that placed
    /// it was made in the earlier visit the offset measures (a third visit to ground the second
    /// one moved without seeing it). A cell a plane moved without sampling it is not moved
    /// again by the same visit's planes once `revisit_gap_s` has passed without a sight of it.
    pub(super) fn awaits_offset(&self, before: i64, until_epoch: i64) -> bool {
        let (moved, at) = self.aligned;
        at <= until_epoch || self.newest_epoch_before(before).is_some_and(|e| e > moved)
    }

    /// The index of the newest epoch holding evidence with index `before` or earlier.
    pub(super) fn newest_epoch_before(&self, before: i64) -> Option<i64> {
        if self.cur.n > 0 && self.epoch <= before {
            Some(self.epoch)
        } else {
            (self.prev.n > 0 && self.prev_epoch <= before).then_some(self.prev_epoch)
        }
    }

    /// The moments of the epochs with index `before` or earlier, and the closest distance they
    /// were seen from.
    pub(super) fn epochs_before(&self, before: i64) -> (Moments, f32) {
        let (mut m, mut r) = (Moments::default(), f32::INFINITY);
        if self.cur.n > 0 && self.epoch <= before {
            (m, r) = (self.cur, self.cur_range_m);
        }
        if self.prev.n > 0 && self.prev_epoch <= before {
            (m, r) = (m.merged(&self.prev), r.min(self.prev_range_m));
        }
        (m, r)
    }

    /// Closest robot distance the cell's evidence was taken from, metres (infinity: it holds
    /// none): the yardstick of the far-view rule (§4.3).
    #[inline]
    pub(super) fn closest_view_m(&self) -> f32 {
        self.seen_range_m
            .min(self.cur_range_m)
            .min(self.prev_range_m)
    }

    /// Both epochs' evidence together.
    #[inline]
    pub(super) fn evidence(&self) -> Moments {
        self.cur.merged(&self.prev)
    }

    /// The cell's ground: its lowest return when it has evidence enough, else where the robot
    /// drove over it, else infinity (unknown).
    #[inline]
    pub(super) fn ground(&self, min_n: u32) -> f32 {
        let e = self.evidence();
        if e.n >= min_n {
            e.zmin
        } else if self.driven {
            self.driven_z
        } else {
            f32::INFINITY
        }
    }

    /// Whether the robot's proof that it drove here still holds: it does unless the current
    /// evidence shows something standing on the driven ground (a car parked, a tree fallen on
    /// a taught route since), which only observation can judge.
    #[inline]
    pub(super) fn driven_free(&self, stand_m: f32) -> bool {
        self.driven && {
            let ev = self.evidence();
            ev.n == 0 || ev.zmax <= self.driven_z + stand_m
        }
    }
}
