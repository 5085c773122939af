//! The merged map as it was at a past moment, for scrubbing a past session in time.
//!
//! The merge hands every changed merged tile to the store twice: as the newest version (`tiles`,
//! what a restart restores) and into the tile history (`tile_history`), where it replaces the
//! version of the same tile in the same history period. The history therefore keeps at most one
//! version of each tile per period (the last one in it), so its size follows the tiles the robots
//! touch per period, not every publication: scrubbing shows the map at most one period late.
//!
//! The map at time `t` is, for every tile, its newest history version stamped at or before `t`
//! ([`crate::store::tiles_at`]). A [`Snapshot`] decodes those into a [`MergedMap`] and serves it
//! through a [`Pyramid`] of its own, so overview levels work as for the live map. Snapshots are
//! keyed by the newest history stamp at or before `t` (every `t` between two stored versions
//! shows the same map) and the last few are cached: a slider dragged back and forth decodes each
//! state once.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use common::grid::{decode_tile, TileIndex};

use crate::merge::MergedMap;
use crate::pyramid::{Pyramid, PyramidTile};
use crate::store::TileRow;

/// How many decoded past maps are kept.
const CACHED_SNAPSHOTS: usize = 4;

/// The history period a merge time falls in (`period_s` > 0): versions of one tile in one period
/// share a row, the last one kept.
pub fn bucket(t_unix_ms: u64, period_s: u32) -> u64 {
    t_unix_ms / (u64::from(period_s.max(1)) * 1000)
}

/// The merged map of one datum at one past moment.
pub struct Snapshot {
    /// The datum.
    pub datum_id: String,
    /// The newest history stamp the map holds (Unix ms): the snapshot's identity.
    pub t_key_ms: u64,
    map: MergedMap,
    pyramid: Mutex<Pyramid>,
    /// History rows that could not be decoded (skipped).
    pub unreadable: usize,
}

impl Snapshot {
    /// The map made of history `rows` (datum, tx, ty, t_unix_ms, encoded tile) of `datum_id`.
    pub fn from_rows(datum_id: &str, t_key_ms: u64, rows: Vec<TileRow>) -> Self {
        let mut map = MergedMap::default();
        let mut unreadable = 0;
        for (_, _, _, t_ms, data) in rows {
            match decode_tile(&data) {
                Ok(mut t) => {
                    // The pyramid's tags use the version: the stamp identifies a history row.
                    t.version = t_ms;
                    map.restore(datum_id, t);
                }
                Err(e) => {
                    unreadable += 1;
                    tracing::warn!("history tile of {datum_id} unreadable: {e}");
                }
            }
        }
        Self {
            datum_id: datum_id.to_string(),
            t_key_ms,
            map,
            pyramid: Mutex::new(Pyramid::new()),
            unreadable,
        }
    }

    /// Tiles in the snapshot.
    pub fn tile_count(&self) -> usize {
        self.map
            .datums
            .get(&self.datum_id)
            .map_or(0, |d| d.tiles.len())
    }

    /// Pyramid tile `index` of `level`, or None where the map then had nothing.
    pub fn tile(&self, level: u8, index: TileIndex) -> Option<Arc<PyramidTile>> {
        self.pyramid.lock().unwrap_or_else(|p| p.into_inner()).tile(
            &self.map,
            &self.datum_id,
            level,
            index,
        )
    }
}

/// The last few snapshots asked for.
#[derive(Default)]
pub struct SnapshotCache {
    recent: Mutex<VecDeque<Arc<Snapshot>>>,
    /// Held while a snapshot is built: the browser asks for a view's tiles of a new state at
    /// once, and each request building the state itself would multiply the work by the view.
    building: Mutex<()>,
}

impl SnapshotCache {
    /// The cached snapshot of `datum_id` at `t_key_ms`, or the one `make` builds (then cached,
    /// the oldest dropped).
    pub fn get_or_make(
        &self,
        datum_id: &str,
        t_key_ms: u64,
        make: impl FnOnce() -> Snapshot,
    ) -> Arc<Snapshot> {
        let find = |q: &VecDeque<Arc<Snapshot>>| {
            q.iter()
                .find(|s| s.datum_id == datum_id && s.t_key_ms == t_key_ms)
                .cloned()
        };
        let lock = || self.recent.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = find(&lock()) {
            return s;
        }
        let _building = self.building.lock().unwrap_or_else(|p| p.into_inner());
        // Another request may have built it while this one waited.
        if let Some(s) = find(&lock()) {
            return s;
        }
        // Built outside `recent`'s lock: cached states are served meanwhile.
        let made = Arc::new(make());
        let mut q = lock();
        q.push_back(made.clone());
        while q.len() > CACHED_SNAPSHOTS {
            q.pop_front();
        }
        made
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::grid::{encode_tile, Cell, CellState, Lattice, Tile};

    fn tile(tx: i32, state: CellState) -> Vec<u8> {
        let mut t = Tile::new(
            TileIndex { tx, ty: 0 },
            Lattice {
                cell_size_m: 0.2,
                tile_cells: 8,
            },
        );
        t.cells[0] = Cell {
            state,
            cost: 1,
            height_cm: 0,
            hits: 3,
            stamp_s: 1,
            rev: 0,
        };
        encode_tile(&t)
    }

    #[test]
    fn buckets_split_time_into_periods() {
        assert_eq!(bucket(59_999, 60), 0);
        assert_eq!(bucket(60_000, 60), 1);
        assert_eq!(bucket(5_000, 0), 5, "a zero period is one second");
    }

    #[test]
    fn a_snapshot_serves_its_tiles_and_skips_unreadable_rows() {
        let rows = vec![
            ("d0".into(), 0, 0, 1_000, tile(0, CellState::Obstacle)),
            ("d0".into(), 1, 0, 2_000, vec![9, 9, 9]),
        ];
        let s = Snapshot::from_rows("d0", 2_000, rows);
        assert_eq!((s.tile_count(), s.unreadable), (1, 1));
        let t = s.tile(0, TileIndex { tx: 0, ty: 0 }).expect("tile 0,0");
        assert_eq!(t.version, 1_000);
        assert!(s.tile(0, TileIndex { tx: 5, ty: 5 }).is_none());
        assert!(
            s.tile(1, TileIndex { tx: 0, ty: 0 }).is_some(),
            "overviews too"
        );
    }

    #[test]
    fn the_cache_builds_each_state_once_and_keeps_the_last_few() {
        let cache = SnapshotCache::default();
        let mut built = 0;
        for t in [1, 2, 1, 2, 3, 4, 5, 1] {
            cache.get_or_make("d0", t, || {
                built += 1;
                Snapshot::from_rows("d0", t, Vec::new())
            });
        }
        // 1 and 2 once each, 3, 4, 5, then 1 again (pushed out by 5 with four kept).
        assert_eq!(built, 6);
    }
}
