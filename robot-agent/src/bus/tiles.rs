//! When a tile goes on the wire, with which version and which clock: the publication policy.
//!
//! The mapper only says which tiles' cells changed; this decides what a consumer receives:
//!
//! - **Hysteresis.** A tile counts as changed when a cell's state or cost differs from what was
//!   last published, or its height moved `height_hysteresis_cm` or more: sensor noise on a cell
//!   mean must not republish a tile every sweep.
//! - **Rate.** A changed tile is republished at most every `min_interval_s` (architecture.md: at
//!   most 2 Hz per tile; 1 Hz halves the bandwidth while driving, and the planner reads the live
//!   grid, not tiles); its first publication goes out at once.
//! - **Versions.** +1 per publication, per tile.
//! - **Revisions.** Each published cell is [`common::grid::revise_cell`] of the one published
//!   before: a change inside one wire stamp step gets the next revision, and a cell the mapper
//!   stops knowing keeps its last published content. So every version of a cell the robot
//!   publishes is greater in the merge's order than the ones before it, and a station's merged
//!   map does not depend on which versions it received (docs/algorithms.md 8.2, 8.3).
//! - **Time.** The mapper stamps cells in session seconds (it has no clock); the wire carries Unix
//!   seconds so stations merge robots whose sessions started at different times. Every observed
//!   cell is converted here, once, from the session's start.
//!
//! Pure: no Zenoh, no clock; the caller passes the session time.

use common::grid::{revise_cell, Cell, CellState, Lattice, Tile, TileIndex};
use std::collections::BTreeMap;

/// The policy's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TilePolicy {
    /// A changed tile is republished at most this often, seconds.
    pub min_interval_s: f64,
    /// A cell's height counts as changed when it moved this much, centimetres.
    pub height_hysteresis_cm: i16,
}

impl Default for TilePolicy {
    fn default() -> Self {
        Self {
            min_interval_s: 1.0,
            height_hysteresis_cm: 3,
        }
    }
}

struct Published {
    /// Last published cells, Unix stamps and revisions as published (what the hysteresis
    /// compares against, and what the next publication revises).
    cells: Vec<Cell>,
    version: u64,
    last_s: f64,
    /// Differs from what was published and waits for its turn.
    changed: bool,
}

/// See the module docs.
pub struct TilePublisher {
    policy: TilePolicy,
    lattice: Lattice,
    session_start_unix_ms: u64,
    tiles: BTreeMap<TileIndex, Published>,
}

impl TilePublisher {
    /// A publisher for tiles on `lattice` of a session that started at `session_start_unix_ms`.
    pub fn new(policy: TilePolicy, lattice: Lattice, session_start_unix_ms: u64) -> Self {
        Self {
            policy,
            lattice,
            session_start_unix_ms,
            tiles: BTreeMap::new(),
        }
    }

    /// Notes the tiles whose cells changed (`cells_of` gives a tile's current cells) and
    /// returns, sorted, the tiles due for publication at session time `t_s`, versioned and in
    /// Unix time. `force`: every changed tile now, whatever the rate (a final flush).
    pub fn publish<'a>(
        &mut self,
        t_s: f64,
        changed: &[TileIndex],
        cells_of: impl Fn(TileIndex) -> Option<&'a [Cell]>,
        force: bool,
    ) -> Vec<Tile> {
        let n = usize::from(self.lattice.tile_cells).pow(2);
        for &index in changed {
            let Some(live) = cells_of(index) else {
                continue;
            };
            let p = self.tiles.entry(index).or_insert_with(|| Published {
                cells: vec![Cell::UNKNOWN; n],
                version: 0,
                last_s: f64::NEG_INFINITY,
                changed: false,
            });
            if !p.changed {
                let h = self.policy.height_hysteresis_cm;
                // A cell the mapper stopped knowing is not news: it stays as published.
                p.changed = p.cells.iter().zip(live).any(|(a, b)| {
                    b.state != CellState::Unknown
                        && (a.state != b.state
                            || a.cost != b.cost
                            || a.height_cm.wrapping_sub(b.height_cm).abs() >= h)
                });
            }
        }
        let mut out = Vec::new();
        for (&index, p) in &mut self.tiles {
            let due = force || p.version == 0 || t_s - p.last_s >= self.policy.min_interval_s;
            if !(p.changed && due) {
                continue;
            }
            let Some(live) = cells_of(index) else {
                continue;
            };
            p.changed = false;
            p.last_s = t_s;
            p.version += 1;
            // Cells whose change was below the hysteresis are published as they are now, so the
            // next comparison is against what consumers hold.
            let mut now = Tile {
                index,
                lattice: self.lattice,
                version: p.version,
                cells: live.to_vec(),
            };
            stamps_to_unix(&mut now, self.session_start_unix_ms);
            for (held, new) in p.cells.iter_mut().zip(&now.cells) {
                *held = revise_cell(held, new);
            }
            now.cells.clone_from(&p.cells);
            out.push(now);
        }
        out
    }
}

/// Turns a tile's cell stamps from session seconds into the wire's Unix seconds (unobserved
/// cells keep 0, "never").
pub fn stamps_to_unix(tile: &mut Tile, session_start_unix_ms: u64) {
    for c in &mut tile.cells {
        if c.state != CellState::Unknown {
            let ms = session_start_unix_ms + u64::from(c.stamp_s) * 1000;
            c.stamp_s = u32::try_from(ms / 1000).unwrap_or(u32::MAX);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice() -> Lattice {
        Lattice {
            cell_size_m: 0.2,
            tile_cells: 4,
        }
    }

    fn cell(h: i16) -> Cell {
        Cell {
            state: CellState::Traversable,
            height_cm: h,
            stamp_s: 10,
            ..Cell::UNKNOWN
        }
    }

    const T: TileIndex = TileIndex { tx: 0, ty: 0 };

    #[test]
    fn versions_rate_and_hysteresis() {
        let mut p = TilePublisher::new(TilePolicy::default(), lattice(), 1_780_000_000_500);
        let mut cells = vec![Cell::UNKNOWN; 16];
        cells[0] = cell(100);
        let out = p.publish(0.0, &[T], |_| Some(&cells), false);
        assert_eq!(out.len(), 1, "the first publication goes out at once");
        assert_eq!(out[0].version, 1);
        assert_eq!(out[0].cells[0].stamp_s, 1_780_000_010, "Unix seconds");
        assert_eq!(out[0].cells[1].stamp_s, 0, "unknown stays never-seen");
        // 2 cm of noise: not a change.
        cells[0] = cell(102);
        assert!(p.publish(0.5, &[T], |_| Some(&cells), false).is_empty());
        // A real change within the rate limit: held, then published when due, unasked.
        cells[1] = cell(50);
        assert!(p.publish(0.6, &[T], |_| Some(&cells), false).is_empty());
        let due = p.publish(1.0, &[], |_| Some(&cells), false);
        assert_eq!(due.len(), 1);
        assert_eq!(due[0].version, 2);
        assert_eq!(due[0].cells[0].height_cm, 102, "published as it is now");
        // Forced: out now, whatever the rate.
        cells[2] = cell(60);
        let forced = p.publish(1.1, &[T], |_| Some(&cells), true);
        assert_eq!(forced.len(), 1);
        assert_eq!(forced[0].version, 3);
    }

    #[test]
    fn changes_at_one_stamp_get_revisions_and_known_cells_stay_known() {
        let mut p = TilePublisher::new(TilePolicy::default(), lattice(), 0);
        let mut cells = vec![Cell::UNKNOWN; 16];
        cells[0] = cell(100);
        cells[1] = cell(100);
        let first = p.publish(0.0, &[T], |_| Some(&cells), false);
        assert_eq!((first[0].cells[0].rev, first[0].cells[1].rev), (0, 0));
        // Inflated within the same stamp step (no new observation): the next revision.
        cells[0].state = CellState::Inflated;
        cells[0].cost = 254;
        // The mapper stops knowing cell 1: it is published as it was.
        cells[1] = Cell::UNKNOWN;
        let second = p.publish(1.0, &[T], |_| Some(&cells), false);
        assert_eq!(second[0].cells[0].rev, 1);
        assert_eq!(second[0].cells[0].state, CellState::Inflated);
        assert_eq!(second[0].cells[1], first[0].cells[1]);
        // Observed again in a later stamp step: revision 0 again.
        cells[0].stamp_s = 20;
        cells[0].height_cm = 150;
        let third = p.publish(2.0, &[T], |_| Some(&cells), false);
        assert_eq!((third[0].cells[0].rev, third[0].cells[0].stamp_s), (0, 20));
        // Only the unknown cell differs from what was published: nothing is due.
        cells[2] = cell(100);
        cells[2] = Cell::UNKNOWN;
        assert!(p.publish(3.0, &[T], |_| Some(&cells), false).is_empty());
    }

    #[test]
    fn a_change_inside_the_rate_limit_waits_for_its_turn() {
        let mut p = TilePublisher::new(TilePolicy::default(), lattice(), 0);
        let mut cells = vec![Cell::UNKNOWN; 16];
        cells[0] = cell(100);
        assert_eq!(p.publish(10.0, &[T], |_| Some(&cells), false).len(), 1);
        cells[1] = cell(40);
        assert!(
            p.publish(10.5, &[T], |_| Some(&cells), false).is_empty(),
            "too soon"
        );
        let out = p.publish(11.0, &[], |_| Some(&cells), false);
        assert_eq!(out.len(), 1, "due one second after the last");
        assert_eq!(out[0].cells[1].height_cm, 40);
    }
}
