//! The stored merged map put back at start. It runs on the merge thread before the first live
//! tile, so the station answers HTTP at once (a site of 6 000 tiles takes seconds to decode)
//! while no live tile can merge into a tile not yet restored and then be stored over it. How far
//! it has come is in [`RestoreProgress`] (`/api/health`'s `restore`).

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::RwLock;
use std::time::Instant;

use common::grid::{decode_tile, TileIndex};
use serde::Serialize;

use super::{default_threads, par_map, MergedMap};
use crate::store::{self, TileRow};

/// Stored tiles decoded per step; the map's write lock is taken once per step, so readers (the
/// HTTP API) wait at most one step's insertions, never the whole restore.
const TILES_PER_STEP: usize = 256;

/// How far the restore of the stored map has come; shared between the merge thread and the API.
#[derive(Debug, Default)]
pub struct RestoreProgress {
    total: AtomicUsize,
    done: AtomicUsize,
    unreadable: AtomicUsize,
    finished: AtomicBool,
}

/// A snapshot of [`RestoreProgress`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct RestoreState {
    /// Stored tiles to restore.
    pub tiles: usize,
    /// Tiles handled so far (restored or found unreadable).
    pub done: usize,
    /// Stored tiles that could not be decoded (logged and left out; the row stays stored).
    pub unreadable: usize,
    /// The whole stored map is back (or reading it failed: see the log).
    pub finished: bool,
}

impl RestoreProgress {
    /// The state now.
    pub fn state(&self) -> RestoreState {
        RestoreState {
            tiles: self.total.load(Ordering::Relaxed),
            done: self.done.load(Ordering::Relaxed),
            unreadable: self.unreadable.load(Ordering::Relaxed),
            finished: self.is_finished(),
        }
    }

    /// True once the whole stored map is back.
    pub fn is_finished(&self) -> bool {
        self.finished.load(Ordering::Acquire)
    }

    /// Marks the restore ended (also after a failure to read the rows).
    pub fn finish(&self) {
        self.finished.store(true, Ordering::Release);
    }
}

/// Reads the stored merged map from the database at `db` and puts it into `map` on one thread
/// per core, calling `restored` for each tile put back; logs what it did. A database that
/// cannot be read is logged and ends the restore with nothing restored.
pub fn restore_from_db(
    db: &Path,
    map: &RwLock<MergedMap>,
    progress: &RestoreProgress,
    restored: impl FnMut(&str, TileIndex),
) {
    let t = Instant::now();
    match store::open(db).and_then(|c| store::tiles(&c, None)) {
        Ok(rows) => restore_rows(rows, map, default_threads(), progress, restored),
        Err(e) => {
            tracing::error!("stored map not restored: {e}");
            progress.finish();
        }
    }
    let s = progress.state();
    tracing::info!(
        tiles = s.tiles,
        unreadable = s.unreadable,
        seconds = t.elapsed().as_secs_f64(),
        "stored map restored"
    );
}

/// Decodes `rows` on `threads` threads and puts them into `map` as stored (cells and version),
/// calling `restored` for each tile put back (the zoom pyramid drops what it built beneath it).
/// An undecodable row is logged, counted and skipped; the rest is restored. Finishes `progress`.
fn restore_rows(
    rows: Vec<TileRow>,
    map: &RwLock<MergedMap>,
    threads: usize,
    progress: &RestoreProgress,
    mut restored: impl FnMut(&str, TileIndex),
) {
    progress.total.store(rows.len(), Ordering::Relaxed);
    for step in rows.chunks(TILES_PER_STEP) {
        let decoded = par_map(step, threads, |(_, _, _, _, data)| decode_tile(data));
        let mut m = map.write().unwrap_or_else(|p| p.into_inner());
        for ((datum_id, tx, ty, version, _), tile) in step.iter().zip(decoded) {
            match tile {
                Ok(mut t) if t.index == (TileIndex { tx: *tx, ty: *ty }) => {
                    t.version = *version;
                    let index = t.index;
                    m.restore(datum_id, t);
                    restored(datum_id, index);
                }
                Ok(t) => {
                    progress.unreadable.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        "stored tile {tx},{ty} of {datum_id} holds tile {},{}: left out",
                        t.index.tx,
                        t.index.ty
                    );
                }
                Err(e) => {
                    progress.unreadable.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("stored tile {tx},{ty} of {datum_id} unreadable: {e}");
                }
            }
        }
        drop(m);
        progress.done.fetch_add(step.len(), Ordering::Relaxed);
    }
    progress.finish();
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::grid::{encode_tile, Cell, CellState, Lattice, Tile};

    fn stored(tx: i32, ty: i32, version: u64) -> TileRow {
        let mut t = Tile::new(TileIndex { tx, ty }, Lattice::default());
        t.cells[3] = Cell {
            state: CellState::Obstacle,
            cost: 0,
            height_cm: 40,
            hits: 4,
            stamp_s: 100,
            rev: 0,
        };
        ("d0".into(), tx, ty, version, encode_tile(&t))
    }

    #[test]
    fn restores_every_readable_tile_with_its_version_and_counts_the_rest() {
        let mut rows: Vec<TileRow> = (0..600).map(|i| stored(i % 30, i / 30, 7)).collect();
        rows[10].4 = vec![1, 2, 3];
        // A row whose payload is another tile (a corrupt or hand-edited database).
        rows[20].4 = stored(99, 99, 1).4;
        let map = RwLock::new(MergedMap::default());
        let progress = RestoreProgress::default();
        let mut seen = 0;
        restore_rows(rows, &map, 2, &progress, |_, _| seen += 1);
        assert_eq!(
            progress.state(),
            RestoreState {
                tiles: 600,
                done: 600,
                unreadable: 2,
                finished: true
            }
        );
        assert_eq!(seen, 598);
        let m = map.read().unwrap();
        let dm = &m.datums["d0"];
        assert_eq!(dm.tiles.len(), 598);
        assert!(!dm.tiles.contains_key(&TileIndex { tx: 99, ty: 99 }));
        let t = &dm.tiles[&TileIndex { tx: 1, ty: 0 }];
        assert_eq!(t.version, 7);
        assert_eq!(t.cells[3].state, CellState::Obstacle);
    }

    #[test]
    fn a_fresh_progress_is_under_way_until_finished() {
        let p = RestoreProgress::default();
        assert!(!p.is_finished());
        p.finish();
        assert!(p.is_finished());
        assert!(p.state().finished);
    }
}
