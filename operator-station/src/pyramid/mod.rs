//! The zoom pyramid of the merged map: overview tiles above the merged tiles, so a browser shows
//! a whole site with a few dozen images instead of one per merged tile.
//!
//! Level 0 is the merged tiles themselves (one class per cell). A tile of level `L` covers the
//! 2x2 tiles of level `L - 1` beneath it (`(2tx + dx, 2ty + dy)`), at the same `tile_cells`
//! resolution: each of its pixels is the *worst* class of the 2x2 pixels below it
//! (obstacle > inflated > traversable > unknown), so an obstacle of a single cell is still drawn
//! at the top level. Its version is the sum of its children's versions, which only grows when
//! any merged tile beneath it changes (merged versions only grow, tiles are never removed).
//!
//! Tiles are built on demand (and all of them once at station start, [`warm_in_background`]) and
//! cached in memory (classes and, once asked for, the PNG). When
//! the merge changes a tile, [`Pyramid::mark_changed`] drops that tile and its ancestors from the
//! cache (nothing else), and the next request rebuilds exactly those from the cached rest.
//! Plain data: no threads, no clock, no I/O; the station keeps it behind a mutex.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock, RwLock};

use common::grid::{Cell, CellState, TileIndex};

use crate::merge::{cell_rgba, png_rgba, DatumMap, MergedMap};

/// Highest level: a top tile covers 2^10 x 2^10 merged tiles (13 km square with 0.2 m cells
/// and 64-cell tiles), far beyond a site.
pub const MAX_LEVEL: u8 = 10;

/// The severity of a class (higher wins when tiles are downsampled).
pub fn rank(state: CellState) -> u8 {
    match state {
        CellState::Unknown => 0,
        CellState::Traversable => 1,
        CellState::Inflated => 2,
        CellState::Obstacle => 3,
    }
}

/// The class of a rank (inverse of [`rank`]).
fn class_of(rank: u8) -> CellState {
    match rank {
        0 => CellState::Unknown,
        1 => CellState::Traversable,
        2 => CellState::Inflated,
        _ => CellState::Obstacle,
    }
}

/// The merged tile above `index` at `level` (level 0: itself).
pub fn ancestor(index: TileIndex, level: u8) -> TileIndex {
    // Arithmetic shifts round towards minus infinity, as the tiling does for negative indices.
    TileIndex {
        tx: index.tx >> level,
        ty: index.ty >> level,
    }
}

/// One tile of the pyramid.
#[derive(Debug)]
pub struct PyramidTile {
    /// `tile_cells^2` class ranks ([`rank`]), row 0 = south.
    pub classes: Vec<u8>,
    /// Level 0: the merged tile's version; above: the sum of the children's.
    pub version: u64,
    png: OnceLock<Arc<Vec<u8>>>,
}

impl PyramidTile {
    fn new(classes: Vec<u8>, version: u64) -> Self {
        Self {
            classes,
            version,
            png: OnceLock::new(),
        }
    }

    /// The tile as a `tile_cells` square PNG, north on top, in the colours of
    /// `merge::cell_rgba` (encoded once, then cached with the tile).
    pub fn png(&self) -> Arc<Vec<u8>> {
        self.png
            .get_or_init(|| {
                let n = (self.classes.len() as f64).sqrt() as usize;
                let colours: Vec<[u8; 4]> = (0..4u8)
                    .map(|r| {
                        cell_rgba(&Cell {
                            state: class_of(r),
                            ..Cell::UNKNOWN
                        })
                    })
                    .collect();
                let mut rgba = vec![0u8; n * n * 4];
                for row in 0..n {
                    let src = n - 1 - row;
                    for col in 0..n {
                        let c = colours[usize::from(self.classes[src * n + col].min(3))];
                        rgba[(row * n + col) * 4..][..4].copy_from_slice(&c);
                    }
                }
                Arc::new(png_rgba(n as u32, n as u32, &rgba))
            })
            .clone()
    }
}

/// Cache of one level: `None` = known to have nothing beneath it.
type LevelCache = HashMap<TileIndex, Option<Arc<PyramidTile>>>;

/// The pyramids of every datum.
#[derive(Debug, Default)]
pub struct Pyramid {
    datums: HashMap<String, Vec<LevelCache>>,
    rebuilds: u64,
}

impl Pyramid {
    /// An empty pyramid (everything is built on demand).
    pub fn new() -> Self {
        Self::default()
    }

    /// How many tiles were built so far (level 0 conversions included).
    pub fn rebuilds(&self) -> u64 {
        self.rebuilds
    }

    /// The merge changed (or created) merged tile `index` of `datum_id`: it and its ancestors
    /// are rebuilt when next asked for.
    pub fn mark_changed(&mut self, datum_id: &str, index: TileIndex) {
        if let Some(levels) = self.datums.get_mut(datum_id) {
            for (level, cache) in levels.iter_mut().enumerate() {
                cache.remove(&ancestor(index, level as u8));
            }
        }
    }

    /// Tile `index` of `level` (0 ..= [`MAX_LEVEL`]) of `datum_id` in `map`, building what is
    /// missing. None when no merged tile lies beneath it (or the datum or level is unknown).
    pub fn tile(
        &mut self,
        map: &MergedMap,
        datum_id: &str,
        level: u8,
        index: TileIndex,
    ) -> Option<Arc<PyramidTile>> {
        if level > MAX_LEVEL {
            return None;
        }
        let dm = map.datums.get(datum_id)?;
        let extent = Extent::of(dm)?;
        if !extent.meets(level, index) {
            return None;
        }
        let levels = self
            .datums
            .entry(datum_id.to_string())
            .or_insert_with(|| vec![LevelCache::new(); usize::from(MAX_LEVEL) + 1]);
        let mut b = Builder {
            levels,
            dm,
            extent,
            n: usize::from(dm.lattice.tile_cells),
            rebuilds: 0,
        };
        let t = b.build(level, index);
        self.rebuilds += b.rebuilds;
        t
    }
}

/// The merge's hook: merged tile `index` of `datum_id` changed (one call where the merge
/// reports a change, whichever thread that runs on).
pub fn mark_changed(pyramid: &Mutex<Pyramid>, datum_id: &str, index: TileIndex) {
    pyramid
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .mark_changed(datum_id, index);
}

/// Builds every datum's whole pyramid on a thread of its own (at station start: the first
/// browser view of a restored site then only encodes PNGs; ~0.2 s of one core for a 1 km² site).
pub fn warm_in_background(map: Arc<RwLock<MergedMap>>, pyramid: Arc<Mutex<Pyramid>>) {
    let spawned = std::thread::Builder::new()
        .name("pyramid-warm".into())
        .spawn(move || {
            let map = map.read().unwrap_or_else(|p| p.into_inner());
            let mut p = pyramid.lock().unwrap_or_else(|p| p.into_inner());
            p.warm(&map);
        });
    if let Err(e) = spawned {
        tracing::warn!("pyramid not prebuilt (built on demand instead): {e}");
    }
}

impl Pyramid {
    /// Builds every tile of every level of every datum of `map` that is not cached.
    pub fn warm(&mut self, map: &MergedMap) {
        for (datum_id, dm) in &map.datums {
            let Some(e) = Extent::of(dm) else { continue };
            let (lo, hi) = (ancestor(e.min, MAX_LEVEL), ancestor(e.max, MAX_LEVEL));
            for tx in lo.tx..=hi.tx {
                for ty in lo.ty..=hi.ty {
                    self.tile(map, datum_id, MAX_LEVEL, TileIndex { tx, ty });
                }
            }
        }
    }
}

/// The merged tiles' index range, to skip empty space without walking it.
#[derive(Clone, Copy, Debug)]
struct Extent {
    min: TileIndex,
    max: TileIndex,
}

impl Extent {
    fn of(dm: &DatumMap) -> Option<Self> {
        let first = *dm.tiles.keys().next()?;
        let mut e = Extent {
            min: first,
            max: first,
        };
        for t in dm.tiles.keys() {
            e.min.tx = e.min.tx.min(t.tx);
            e.min.ty = e.min.ty.min(t.ty);
            e.max.tx = e.max.tx.max(t.tx);
            e.max.ty = e.max.ty.max(t.ty);
        }
        Some(e)
    }

    /// True when tile `index` of `level` overlaps the extent.
    fn meets(&self, level: u8, index: TileIndex) -> bool {
        let (lo, hi) = (ancestor(self.min, level), ancestor(self.max, level));
        (lo.tx..=hi.tx).contains(&index.tx) && (lo.ty..=hi.ty).contains(&index.ty)
    }
}

struct Builder<'a> {
    levels: &'a mut Vec<LevelCache>,
    dm: &'a DatumMap,
    extent: Extent,
    n: usize,
    rebuilds: u64,
}

impl Builder<'_> {
    fn build(&mut self, level: u8, index: TileIndex) -> Option<Arc<PyramidTile>> {
        if let Some(hit) = self.levels[usize::from(level)].get(&index) {
            return hit.clone();
        }
        if !self.extent.meets(level, index) {
            return None;
        }
        let built = if level == 0 {
            self.dm.tiles.get(&index).map(|m| {
                let classes = m.cells.iter().map(|c| rank(c.state)).collect();
                Arc::new(PyramidTile::new(classes, m.version))
            })
        } else {
            let kids: [Option<Arc<PyramidTile>>; 4] =
                [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| {
                    self.build(
                        level - 1,
                        TileIndex {
                            tx: 2 * index.tx + dx,
                            ty: 2 * index.ty + dy,
                        },
                    )
                });
            if kids.iter().all(Option::is_none) {
                None
            } else {
                let version = kids.iter().flatten().map(|k| k.version).sum();
                Some(Arc::new(PyramidTile::new(
                    downsample(&kids, self.n),
                    version,
                )))
            }
        };
        if built.is_some() {
            self.rebuilds += 1;
        }
        // Empty merged tiles are a cheap lookup: only the levels above remember emptiness.
        if level > 0 || built.is_some() {
            self.levels[usize::from(level)].insert(index, built.clone());
        }
        built
    }
}

/// The worst class of each 2x2 block of the four children (`[sw, se, nw, ne]`), row 0 = south.
fn downsample(kids: &[Option<Arc<PyramidTile>>; 4], n: usize) -> Vec<u8> {
    let mut out = vec![0u8; n * n];
    // The children side by side are 2n x 2n pixels; pixel (x, y) of them falls on parent pixel
    // (x / 2, y / 2) (works for odd n too).
    for (k, kid) in kids.iter().enumerate() {
        let Some(kid) = kid else { continue };
        let (ox, oy) = ((k % 2) * n, (k / 2) * n);
        for (r, row) in kid.classes.chunks_exact(n).enumerate() {
            let dst = &mut out[((oy + r) / 2) * n..][..n];
            for (c, &v) in row.iter().enumerate() {
                let d = &mut dst[(ox + c) / 2];
                *d = (*d).max(v);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::grid::{Lattice, Tile};

    /// A tile observed at `stamp_s` (newer stamps win the merge).
    fn tile_at(tx: i32, ty: i32, stamp_s: u32, f: impl Fn(u16, u16) -> CellState) -> Tile {
        let mut t = Tile::new(TileIndex { tx, ty }, Lattice::default());
        let n = t.lattice.tile_cells;
        for r in 0..n {
            for c in 0..n {
                *t.get_mut(c, r) = Cell {
                    state: f(c, r),
                    cost: 0,
                    height_cm: 0,
                    hits: 1,
                    stamp_s,
                    rev: 0,
                };
            }
        }
        t
    }

    fn tile(tx: i32, ty: i32, f: impl Fn(u16, u16) -> CellState) -> Tile {
        tile_at(tx, ty, 1, f)
    }

    /// A 12 x 9 tile map around the origin (negative indices included), all traversable.
    fn site() -> MergedMap {
        let mut m = MergedMap::default();
        for tx in -5..7 {
            for ty in -4..5 {
                m.merge("d0", &tile(tx, ty, |_, _| CellState::Traversable))
                    .unwrap();
            }
        }
        m
    }

    /// Every tile of every level that exists, with its classes and version.
    fn all(p: &mut Pyramid, m: &MergedMap) -> Vec<(u8, TileIndex, Vec<u8>, u64)> {
        let mut out = Vec::new();
        for level in 0..=MAX_LEVEL {
            for tx in (-16 >> level)..=(16 >> level) {
                for ty in (-16 >> level)..=(16 >> level) {
                    let i = TileIndex { tx, ty };
                    if let Some(t) = p.tile(m, "d0", level, i) {
                        out.push((level, i, t.classes.clone(), t.version));
                    }
                }
            }
        }
        out
    }

    #[test]
    fn a_single_obstacle_cell_survives_to_the_top_level() {
        let mut m = site();
        // One obstacle cell in a corner tile with a negative index.
        m.merge(
            "d0",
            &tile_at(-5, -4, 2, |c, r| {
                if (c, r) == (13, 50) {
                    CellState::Obstacle
                } else {
                    CellState::Unknown
                }
            }),
        )
        .unwrap();
        let mut p = Pyramid::new();
        let top = p
            .tile(&m, "d0", MAX_LEVEL, TileIndex { tx: -1, ty: -1 })
            .expect("the top tile above the corner");
        assert_eq!(top.classes.iter().filter(|&&c| c == 3).count(), 1);
        // And one level below the top: still there, still exactly one pixel.
        let below = p
            .tile(&m, "d0", 3, ancestor(TileIndex { tx: -5, ty: -4 }, 3))
            .unwrap();
        assert_eq!(below.classes.iter().filter(|&&c| c == 3).count(), 1);
        // Nothing beneath: no tile.
        assert!(p.tile(&m, "d0", 2, TileIndex { tx: 40, ty: 0 }).is_none());
        assert!(p.tile(&m, "d1", 0, TileIndex { tx: 0, ty: 0 }).is_none());
    }

    #[test]
    fn changing_one_merged_tile_rebuilds_exactly_its_ancestors() {
        let mut m = site();
        let mut p = Pyramid::new();
        let before = all(&mut p, &m);
        let kept: Vec<(u8, TileIndex, Arc<PyramidTile>)> = before
            .iter()
            .map(|(l, i, _, _)| (*l, *i, p.tile(&m, "d0", *l, *i).unwrap()))
            .collect();
        let built = p.rebuilds();
        let changed = TileIndex { tx: -3, ty: 2 };
        let v = m
            .merge(
                "d0",
                &tile_at(changed.tx, changed.ty, 2, |c, _| {
                    if c == 7 {
                        CellState::Obstacle
                    } else {
                        CellState::Traversable
                    }
                }),
            )
            .unwrap();
        assert!(v.is_some());
        p.mark_changed("d0", changed);
        let after = all(&mut p, &m);
        assert_eq!(after.len(), before.len());
        // One tile per level, level 0 included.
        assert_eq!(p.rebuilds() - built, u64::from(MAX_LEVEL) + 1);
        for (l, i, old) in kept {
            let now = p.tile(&m, "d0", l, i).unwrap();
            let is_ancestor = ancestor(changed, l) == i;
            assert_eq!(!Arc::ptr_eq(&old, &now), is_ancestor, "level {l} {i:?}");
            if is_ancestor {
                assert!(now.version > old.version, "level {l}");
                assert!(now.classes.contains(&3), "level {l}");
            }
        }
    }

    #[test]
    fn an_updated_pyramid_equals_one_built_from_scratch() {
        let mut m = site();
        let mut p = Pyramid::new();
        let _ = all(&mut p, &m);
        // A new tile beyond the old extent, and changes inside it, some at negative indices.
        let changes = [(9, 9), (-5, -4), (0, 0), (-1, 3), (9, 9), (6, -4)];
        for (k, (tx, ty)) in changes.into_iter().enumerate() {
            let t = tile_at(tx, ty, 10 + k as u32, |c, r| match (c + r + k as u16) % 5 {
                0 => CellState::Obstacle,
                1 => CellState::Inflated,
                2 => CellState::Unknown,
                _ => CellState::Traversable,
            });
            if m.merge("d0", &t).unwrap().is_some() {
                p.mark_changed("d0", t.index);
            }
            // Ask in between too, so that stale tiles would be cached if marking missed them.
            let _ = all(&mut p, &m);
        }
        let mut fresh = Pyramid::new();
        assert_eq!(all(&mut p, &m), all(&mut fresh, &m));
        // Prebuilt, everything is cached: asking for every tile builds nothing more.
        let mut warm = Pyramid::new();
        warm.warm(&m);
        let built = warm.rebuilds();
        assert_eq!(all(&mut warm, &m), all(&mut fresh, &m));
        assert_eq!(warm.rebuilds(), built);
    }

    /// `cargo test --release -p operator-station -- --ignored --nocapture pyramid_build_time`:
    /// the cold build of a 78 x 78 tile (1 km²) site's whole pyramid, and one PNG.
    #[test]
    #[ignore]
    fn pyramid_build_time() {
        let mut m = MergedMap::default();
        for tx in -39..39 {
            for ty in -39..39 {
                let t = tile(tx, ty, |c, r| {
                    if (c * 7 + r * 3 + tx.unsigned_abs() as u16).is_multiple_of(97) {
                        CellState::Obstacle
                    } else {
                        CellState::Traversable
                    }
                });
                m.merge("d0", &t).unwrap();
            }
        }
        let mut p = Pyramid::new();
        let t0 = std::time::Instant::now();
        for tx in -1..=0 {
            for ty in -1..=0 {
                p.tile(&m, "d0", 7, TileIndex { tx, ty }).unwrap();
            }
        }
        let built = t0.elapsed();
        let t1 = std::time::Instant::now();
        let png = p
            .tile(&m, "d0", 4, TileIndex { tx: 0, ty: 0 })
            .unwrap()
            .png();
        println!(
            "cold pyramid of 6084 tiles: {} tiles built in {:.1} ms; one PNG {} B in {:.2} ms",
            p.rebuilds(),
            built.as_secs_f64() * 1e3,
            png.len(),
            t1.elapsed().as_secs_f64() * 1e3
        );
    }

    #[test]
    fn level_zero_png_is_the_merged_tile_png() {
        let mut m = MergedMap::default();
        m.merge(
            "d0",
            &tile(0, 0, |c, r| match (c * 3 + r) % 4 {
                0 => CellState::Obstacle,
                1 => CellState::Inflated,
                2 => CellState::Unknown,
                _ => CellState::Traversable,
            }),
        )
        .unwrap();
        let mut p = Pyramid::new();
        let t = p.tile(&m, "d0", 0, TileIndex { tx: 0, ty: 0 }).unwrap();
        let merged = &m.datums["d0"].tiles[&TileIndex { tx: 0, ty: 0 }];
        assert_eq!(*t.png(), crate::merge::tile_png(merged, 64));
    }
}
