//! The merged map: tiles of every robot merged per datum into one large map, newer evidence
//! winning per cell: each cell is the greatest ever received in [`common::grid::cell_order`]
//! (stamp, then evidence, then the robot's revision, then content). Robots publish every version
//! of a cell greater than the last ([`common::grid::revise_cell`]), so the merged map is a
//! function of each robot's newest tiles, whatever the station received before and in whatever
//! order (docs/algorithms.md 8.3).
//!
//! [`MergedMap`] is plain data (no threads, no clock); [`MergeWorker`] runs it on its own thread
//! fed by a channel so decoding and merging never block the network tasks. A tile is decoded
//! once, there, on as many threads as there are cores, and merged in the order it was queued,
//! so the merged map is the same for any number of threads.

use std::collections::BTreeMap;
use std::sync::{mpsc, Arc, RwLock};

use common::grid::{
    cell_order, decode_tile, encode_tile, Cell, CellState, Lattice, Tile, TileIndex,
};

pub mod restore;

/// Why a tile was not merged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MergeError {
    /// The payload is not a valid tile.
    #[error("undecodable tile: {0}")]
    Decode(String),
    /// The tile's lattice differs from the datum's.
    #[error("tile lattice {got:?} differs from the datum's {want:?}")]
    LatticeMismatch {
        /// Lattice of the tile.
        got: Lattice,
        /// Lattice of the datum.
        want: Lattice,
    },
}

/// One merged tile.
#[derive(Clone, Debug, PartialEq)]
pub struct MergedTile {
    /// `tile_cells^2` cells, row 0 = south.
    pub cells: Vec<Cell>,
    /// Station version: +1 whenever a cell changes.
    pub version: u64,
}

/// The merged tiles of one datum.
#[derive(Clone, Debug)]
pub struct DatumMap {
    /// The lattice every tile of this datum lives on.
    pub lattice: Lattice,
    /// Tiles by index.
    pub tiles: BTreeMap<TileIndex, MergedTile>,
}

impl DatumMap {
    /// Bounds of the known tiles, metres: `[xmin, ymin, xmax, ymax]`, or None when empty.
    pub fn bounds_m(&self) -> Option<[f64; 4]> {
        let first = self.tiles.keys().next()?;
        let (mut x0, mut y0, mut x1, mut y1) = (first.tx, first.ty, first.tx, first.ty);
        for t in self.tiles.keys() {
            x0 = x0.min(t.tx);
            y0 = y0.min(t.ty);
            x1 = x1.max(t.tx);
            y1 = y1.max(t.ty);
        }
        let side = self.lattice.cell_size_f64() * self.lattice.tile_cells as f64;
        Some([
            x0 as f64 * side,
            y0 as f64 * side,
            (x1 + 1) as f64 * side,
            (y1 + 1) as f64 * side,
        ])
    }

    /// The merged tile as a `common::grid::Tile` (its version is the station's).
    pub fn tile(&self, index: TileIndex) -> Option<Tile> {
        let m = self.tiles.get(&index)?;
        Some(Tile {
            index,
            lattice: self.lattice,
            version: m.version,
            cells: m.cells.clone(),
        })
    }
}

/// True when `new` replaces `cur`: it is greater in [`cell_order`] (newer stamp, else more
/// evidence, else a later revision of the same robot's cell, else the greater content, so two
/// different cells never tie). Unknown cells never win.
pub fn newer_wins(new: &Cell, cur: &Cell) -> bool {
    cell_order(new, cur) == std::cmp::Ordering::Greater
}

/// A merged tile that changed.
#[derive(Clone, Debug, PartialEq)]
pub struct TileChange {
    /// Datum of the tile.
    pub datum_id: String,
    /// Index.
    pub index: TileIndex,
    /// New station version.
    pub version: u64,
}

/// Every datum's merged tiles.
#[derive(Clone, Debug, Default)]
pub struct MergedMap {
    /// Datum maps by `datum_id`.
    pub datums: BTreeMap<String, DatumMap>,
}

impl MergedMap {
    /// Merges one tile into the datum's map. Returns the new version when any cell changed.
    pub fn merge(&mut self, datum_id: &str, tile: &Tile) -> Result<Option<u64>, MergeError> {
        let dm = self
            .datums
            .entry(datum_id.to_string())
            .or_insert_with(|| DatumMap {
                lattice: tile.lattice,
                tiles: BTreeMap::new(),
            });
        if dm.lattice.tile_cells != tile.lattice.tile_cells
            || dm.lattice.cell_size_f64() != tile.lattice.cell_size_f64()
        {
            return Err(MergeError::LatticeMismatch {
                got: tile.lattice,
                want: dm.lattice,
            });
        }
        let n = tile.lattice.tile_cells as usize;
        if tile.cells.len() != n * n {
            return Err(MergeError::Decode("cell count".into()));
        }
        let m = dm.tiles.entry(tile.index).or_insert_with(|| MergedTile {
            cells: vec![Cell::UNKNOWN; n * n],
            version: 0,
        });
        let mut changed = false;
        for (cur, new) in m.cells.iter_mut().zip(&tile.cells) {
            if newer_wins(new, cur) && cur != new {
                *cur = *new;
                changed = true;
            }
        }
        if changed {
            m.version += 1;
            Ok(Some(m.version))
        } else {
            Ok(None)
        }
    }

    /// Puts a tile back as stored (loading from the database): replaces cells and version.
    pub fn restore(&mut self, datum_id: &str, tile: Tile) {
        let dm = self
            .datums
            .entry(datum_id.to_string())
            .or_insert_with(|| DatumMap {
                lattice: tile.lattice,
                tiles: BTreeMap::new(),
            });
        dm.tiles.insert(
            tile.index,
            MergedTile {
                cells: tile.cells,
                version: tile.version,
            },
        );
    }
}

/// RGBA of a cell in the map images (API.md colours).
pub fn cell_rgba(c: &Cell) -> [u8; 4] {
    match c.state {
        CellState::Unknown => [0, 0, 0, 0],
        CellState::Traversable => [0x9c, 0xcc, 0x65, 140],
        CellState::Inflated => [0xff, 0xb7, 0x4d, 220],
        CellState::Obstacle => [0xe5, 0x39, 0x35, 255],
    }
}

/// Encodes RGBA pixels as PNG.
pub fn png_rgba(width: u32, height: u32, rgba: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        // Writing into a Vec cannot fail for a correctly sized image.
        if let Ok(mut w) = enc.write_header() {
            let _ = w.write_image_data(rgba);
        }
    }
    out
}

/// A merged tile as PNG, row 0 = north.
pub fn tile_png(tile: &MergedTile, tile_cells: u16) -> Vec<u8> {
    let n = tile_cells as usize;
    let mut rgba = vec![0u8; n * n * 4];
    for row in 0..n {
        let src = n - 1 - row;
        for col in 0..n {
            let px = cell_rgba(&tile.cells[src * n + col]);
            rgba[(row * n + col) * 4..][..4].copy_from_slice(&px);
        }
    }
    png_rgba(n as u32, n as u32, &rgba)
}

/// The whole map of a datum as one PNG (north up), one pixel per cell, for exports. None when
/// the datum is empty.
pub fn datum_png(dm: &DatumMap) -> Option<Vec<u8>> {
    datum_png_scaled(dm, 1)
}

/// [`datum_png`] with `px_per_cell` x `px_per_cell` pixels per cell (nearest neighbour, so cell
/// edges stay sharp when a person looks at the export).
pub fn datum_png_scaled(dm: &DatumMap, px_per_cell: u32) -> Option<Vec<u8>> {
    let first = dm.tiles.keys().next()?;
    let (mut x0, mut y0, mut x1, mut y1) = (first.tx, first.ty, first.tx, first.ty);
    for t in dm.tiles.keys() {
        x0 = x0.min(t.tx);
        y0 = y0.min(t.ty);
        x1 = x1.max(t.tx);
        y1 = y1.max(t.ty);
    }
    let n = dm.lattice.tile_cells as usize;
    let w = (x1 - x0 + 1) as usize * n;
    let h = (y1 - y0 + 1) as usize * n;
    // Dark background so unknown is visible in a viewer.
    let mut rgba: Vec<u8> = [40u8, 40, 40, 255].repeat(w * h);
    for (idx, t) in &dm.tiles {
        let ox = (idx.tx - x0) as usize * n;
        let oy = (idx.ty - y0) as usize * n; // from the south edge
        for r in 0..n {
            for c in 0..n {
                let cell = &t.cells[r * n + c];
                if cell.state == CellState::Unknown {
                    continue;
                }
                let [cr, cg, cb, a] = cell_rgba(cell);
                let y_img = h - 1 - (oy + r);
                let p = &mut rgba[(y_img * w + ox + c) * 4..][..4];
                let af = a as f32 / 255.0;
                for (d, s) in p.iter_mut().zip([cr, cg, cb]) {
                    *d = (s as f32 * af + *d as f32 * (1.0 - af)).round() as u8;
                }
            }
        }
    }
    let k = px_per_cell.max(1) as usize;
    if k == 1 {
        return Some(png_rgba(w as u32, h as u32, &rgba));
    }
    let mut big = Vec::with_capacity(w * h * k * k * 4);
    for row in rgba.chunks_exact(w * 4) {
        let line: Vec<u8> = row
            .chunks_exact(4)
            .flat_map(|px| std::iter::repeat_n(px, k).flatten().copied())
            .collect();
        for _ in 0..k {
            big.extend_from_slice(&line);
        }
    }
    Some(png_rgba((w * k) as u32, (h * k) as u32, &big))
}

/// One tile to merge: the robot's encoded payload and the datum it belongs to.
#[derive(Clone, Debug)]
pub struct MergeJob {
    /// Datum of the robot's session.
    pub datum_id: String,
    /// Robot (for logs).
    pub robot: String,
    /// The tile index its key names, checked against the decoded tile (None: not checked).
    pub key_index: Option<TileIndex>,
    /// Payload from `common::grid::encode_tile`.
    pub encoded: Vec<u8>,
}

/// Called by the worker for every merged tile that changed, with the tile re-encoded.
pub type ChangeSink = Box<dyn FnMut(TileChange, Vec<u8>) + Send>;

enum MergeMsg {
    Job(MergeJob),
    Stop,
}

/// Queue of the merge thread (cheap to clone).
#[derive(Clone)]
pub struct MergeQueue(mpsc::Sender<MergeMsg>);

impl MergeQueue {
    /// Queues a tile; false when the worker has stopped.
    pub fn send(&self, job: MergeJob) -> bool {
        self.0.send(MergeMsg::Job(job)).is_ok()
    }
}

/// Most tiles taken from the queue in one batch per decoding thread: enough to keep every core
/// busy under load, few enough that the first tile of a batch is not held back long (a batch of
/// 16 tiles per thread is about 6 ms of decoding at codec v3's 0.38 ms a tile).
const BATCH_PER_THREAD: usize = 16;

/// The number of decoding threads the station uses: one per core.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Runs `f` over `items` on up to `threads` threads (the calling one included), results in the
/// order of `items`. Each thread takes the next item as it finishes one, so a thread the OS
/// preempts (the station shares its cores) holds back one item, not a share of the batch. Scoped
/// threads per batch: a batch is milliseconds of work, a spawn tens of microseconds.
fn par_map<T: Sync, R: Send>(items: &[T], threads: usize, f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    if threads <= 1 || items.len() <= 1 {
        return items.iter().map(&f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let work = || {
        let mut done = Vec::new();
        loop {
            let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let Some(item) = items.get(i) else {
                return done;
            };
            done.push((i, f(item)));
        }
    };
    let mut all: Vec<(usize, R)> = std::thread::scope(|s| {
        let handles: Vec<_> = (1..threads.min(items.len()))
            .map(|_| s.spawn(work))
            .collect();
        let mut all = work();
        for h in handles {
            match h.join() {
                Ok(v) => all.extend(v),
                // A panic in a decoder is a bug; carry it to the merge thread as one.
                Err(p) => std::panic::resume_unwind(p),
            }
        }
        all
    });
    all.sort_unstable_by_key(|(i, _)| *i);
    all.into_iter().map(|(_, r)| r).collect()
}

/// Decodes a job's payload and checks it against its key.
fn decode_job(job: &MergeJob) -> Result<Tile, String> {
    let t = decode_tile(&job.encoded).map_err(|e| e.to_string())?;
    match job.key_index {
        Some(k) if k != t.index => Err("tile index differs from its key".into()),
        _ => Ok(t),
    }
}

/// Merges one batch: decodes on `threads` threads, merges in arrival order (so the map, every
/// version and the order of the changes are the same for any thread count), re-encodes the
/// changed merged tiles on `threads` threads, and hands them to `sink` in merge order.
fn merge_batch(
    map: &RwLock<MergedMap>,
    sink: &mut ChangeSink,
    errors: &std::sync::atomic::AtomicU64,
    batch: Vec<MergeJob>,
    threads: usize,
) {
    let decoded = par_map(&batch, threads, decode_job);
    let mut changed: Vec<(TileChange, Tile)> = Vec::new();
    {
        let mut m = map.write().unwrap_or_else(|p| p.into_inner());
        for (job, tile) in batch.into_iter().zip(decoded) {
            let tile = match tile {
                Ok(t) => t,
                Err(e) => {
                    errors.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    tracing::warn!(robot = job.robot, "tile refused: {e}");
                    continue;
                }
            };
            match m.merge(&job.datum_id, &tile) {
                Ok(Some(version)) => {
                    if let Some(t) = m.datums.get(&job.datum_id).and_then(|d| d.tile(tile.index)) {
                        changed.push((
                            TileChange {
                                datum_id: job.datum_id,
                                index: tile.index,
                                version,
                            },
                            t,
                        ));
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    errors.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    tracing::warn!(robot = job.robot, "tile not merged: {e}");
                }
            }
        }
    }
    // Encode outside the lock: readers (the PNG handler) never wait on the codec.
    let encoded = par_map(&changed, threads, |(_, t)| encode_tile(t));
    for ((change, _), enc) in changed.into_iter().zip(encoded) {
        sink(change, enc);
    }
}

/// Merging off the network tasks: a merge thread takes the queued tiles in batches, decodes
/// them on a pool of threads, and merges them in the order they were queued.
pub struct MergeWorker {
    tx: mpsc::Sender<MergeMsg>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl MergeWorker {
    /// Starts the merge thread with one decoding thread per core; `errors` counts undecodable
    /// or mismatching tiles.
    pub fn start(
        map: Arc<RwLock<MergedMap>>,
        sink: ChangeSink,
        errors: Arc<std::sync::atomic::AtomicU64>,
    ) -> Self {
        Self::spawn(map, sink, errors, default_threads(), None)
    }

    /// [`MergeWorker::start`] that runs `first` on the merge thread before any job: jobs queued
    /// meanwhile wait for it (the stored map is restored this way, see [`restore`]).
    pub fn start_after(
        map: Arc<RwLock<MergedMap>>,
        sink: ChangeSink,
        errors: Arc<std::sync::atomic::AtomicU64>,
        first: Box<dyn FnOnce() + Send>,
    ) -> Self {
        Self::spawn(map, sink, errors, default_threads(), Some(first))
    }

    /// [`MergeWorker::start`] with `threads` decoding threads (at least one: the merge thread).
    pub fn with_threads(
        map: Arc<RwLock<MergedMap>>,
        sink: ChangeSink,
        errors: Arc<std::sync::atomic::AtomicU64>,
        threads: usize,
    ) -> Self {
        Self::spawn(map, sink, errors, threads, None)
    }

    fn spawn(
        map: Arc<RwLock<MergedMap>>,
        mut sink: ChangeSink,
        errors: Arc<std::sync::atomic::AtomicU64>,
        threads: usize,
        first: Option<Box<dyn FnOnce() + Send>>,
    ) -> Self {
        let threads = threads.max(1);
        let (tx, rx) = mpsc::channel::<MergeMsg>();
        let thread = std::thread::Builder::new()
            .name("merge".into())
            .spawn(move || {
                if let Some(first) = first {
                    first();
                }
                let mut stopping = false;
                while !stopping {
                    let Ok(MergeMsg::Job(first)) = rx.recv() else {
                        break;
                    };
                    // Whatever else is queued, up to a batch: under load every core decodes,
                    // a lone tile is merged at once.
                    let mut batch = vec![first];
                    while batch.len() < BATCH_PER_THREAD * threads {
                        match rx.try_recv() {
                            Ok(MergeMsg::Job(j)) => batch.push(j),
                            Ok(MergeMsg::Stop) => {
                                stopping = true;
                                break;
                            }
                            Err(_) => break,
                        }
                    }
                    merge_batch(&map, &mut sink, &errors, batch, threads);
                }
            })
            .expect("spawn the merge thread");
        Self {
            tx,
            thread: Some(thread),
        }
    }

    /// A sender for jobs.
    pub fn sender(&self) -> MergeQueue {
        MergeQueue(self.tx.clone())
    }

    /// Stops after the queued jobs are merged.
    pub fn finish(mut self) {
        let _ = self.tx.send(MergeMsg::Stop);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(state: CellState, stamp_s: u32, hits: u8, h: i16) -> Cell {
        Cell {
            state,
            cost: 0,
            height_cm: h,
            hits,
            stamp_s,
            rev: 0,
        }
    }

    fn tile(tx: i32, ty: i32, f: impl Fn(usize, usize) -> Cell) -> Tile {
        let mut t = Tile::new(TileIndex { tx, ty }, Lattice::default());
        let n = 64;
        for r in 0..n {
            for c in 0..n {
                t.cells[r * n + c] = f(c, r);
            }
        }
        t
    }

    #[test]
    fn overlapping_tiles_of_two_robots_merge_cell_exactly() {
        // Robot A saw the west half at t=100, robot B the east half plus an overlap band at t=200.
        let a = tile(2, -1, |c, _| {
            if c < 40 {
                cell(CellState::Traversable, 100, 5, 10)
            } else {
                Cell::UNKNOWN
            }
        });
        let b = tile(2, -1, |c, r| {
            if c >= 32 {
                let s = if r == 7 {
                    CellState::Obstacle
                } else {
                    CellState::Traversable
                };
                cell(s, 200, 3, 20)
            } else {
                Cell::UNKNOWN
            }
        });
        let mut m = MergedMap::default();
        assert_eq!(m.merge("d0", &a).unwrap(), Some(1));
        assert_eq!(m.merge("d0", &b).unwrap(), Some(2));
        let t = m.datums["d0"].tile(TileIndex { tx: 2, ty: -1 }).unwrap();
        for r in 0..64 {
            for c in 0..64 {
                let got = t.get(c as u16, r as u16);
                let want = if c >= 32 {
                    *b.get(c as u16, r as u16)
                } else {
                    *a.get(c as u16, r as u16)
                };
                assert_eq!(*got, want, "cell ({c},{r})");
            }
        }
        // Same merge in the other order gives the same map.
        let mut m2 = MergedMap::default();
        m2.merge("d0", &b).unwrap();
        m2.merge("d0", &a).unwrap();
        assert_eq!(
            m2.datums["d0"].tiles[&TileIndex { tx: 2, ty: -1 }].cells,
            t.cells
        );
    }

    /// Runs `jobs` through a worker with `threads` decoding threads; the map and every change
    /// handed to the sink, in order.
    fn run_worker(jobs: &[MergeJob], threads: usize) -> (MergedMap, Vec<TileChange>, u64) {
        let map = Arc::new(RwLock::new(MergedMap::default()));
        let changes = Arc::new(std::sync::Mutex::new(Vec::new()));
        let errors = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let c2 = changes.clone();
        let w = MergeWorker::with_threads(
            map.clone(),
            Box::new(move |ch, enc: Vec<u8>| {
                // What the store gets decodes to the merged tile of that version.
                assert_eq!(decode_tile(&enc).unwrap().version, ch.version);
                c2.lock().unwrap().push(ch);
            }),
            errors.clone(),
            threads,
        );
        let q = w.sender();
        for j in jobs {
            assert!(q.send(j.clone()));
        }
        w.finish();
        let m = map.read().unwrap().clone();
        let ch = changes.lock().unwrap().clone();
        (m, ch, errors.load(std::sync::atomic::Ordering::Relaxed))
    }

    #[test]
    fn a_live_tile_queued_during_the_restore_merges_after_it_and_is_stored_whole() {
        let idx = TileIndex { tx: 4, ty: -2 };
        let stored = tile(idx.tx, idx.ty, |c, r| {
            if (c, r) == (3, 0) {
                cell(CellState::Obstacle, 100, 4, 40)
            } else {
                Cell::UNKNOWN
            }
        });
        // The live tile has an older view of the stored cell and news elsewhere.
        let live = tile(idx.tx, idx.ty, |c, r| match (c, r) {
            (3, 0) => cell(CellState::Traversable, 50, 4, 0),
            (9, 9) => cell(CellState::Traversable, 200, 2, 0),
            _ => Cell::UNKNOWN,
        });
        let map = Arc::new(RwLock::new(MergedMap::default()));
        let stores = Arc::new(std::sync::Mutex::new(Vec::new()));
        let (go, wait) = mpsc::channel::<()>();
        let first = {
            let map = map.clone();
            let mut stored = stored.clone();
            Box::new(move || {
                let _ = wait.recv();
                stored.version = 5;
                map.write().unwrap().restore("d0", stored);
            })
        };
        let s2 = stores.clone();
        let w = MergeWorker::start_after(
            map.clone(),
            Box::new(move |ch, enc: Vec<u8>| s2.lock().unwrap().push((ch, enc))),
            Arc::new(std::sync::atomic::AtomicU64::new(0)),
            first,
        );
        assert!(w.sender().send(MergeJob {
            datum_id: "d0".into(),
            robot: "r1".into(),
            key_index: Some(idx),
            encoded: encode_tile(&live),
        }));
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert!(
            map.read().unwrap().datums.is_empty(),
            "merged before the restore"
        );
        go.send(()).unwrap();
        w.finish();
        let stores = stores.lock().unwrap();
        assert_eq!(stores.len(), 1);
        assert_eq!(stores[0].0.version, 6);
        // What goes to the store holds the restored cell as well as the news.
        let written = decode_tile(&stores[0].1).unwrap();
        assert_eq!(written.cells[3], cell(CellState::Obstacle, 100, 4, 40));
        assert_eq!(
            written.cells[9 * 64 + 9],
            cell(CellState::Traversable, 200, 2, 0)
        );
    }

    #[test]
    fn the_merged_map_is_the_same_for_any_number_of_threads() {
        // Tiles that disagree at equal stamp and hits (the order decides those cells), on few
        // indices so many jobs touch the same tile, two datums, and two bad payloads.
        let mut jobs = Vec::new();
        for i in 0..300u32 {
            let (tx, ty) = ((i % 3) as i32, ((i / 3) % 2) as i32);
            let t = tile(tx, ty, |c, r| {
                let k = (c as u32 * 7 + r as u32 * 3 + i) % 11;
                if k < 3 {
                    Cell::UNKNOWN
                } else {
                    let state = if k == 4 {
                        CellState::Obstacle
                    } else {
                        CellState::Traversable
                    };
                    // Stamps in wire steps, a few values only: ties are frequent.
                    cell(
                        state,
                        400 + 4 * ((i / 50) + k % 2),
                        1 + (k % 3) as u8,
                        (i % 9) as i16 * 2,
                    )
                }
            });
            jobs.push(MergeJob {
                datum_id: format!("d{}", i % 2),
                robot: format!("r{}", i % 5),
                key_index: Some(TileIndex { tx, ty }),
                encoded: encode_tile(&t),
            });
        }
        jobs.insert(
            17,
            MergeJob {
                datum_id: "d0".into(),
                robot: "bad".into(),
                key_index: None,
                encoded: b"not a tile".to_vec(),
            },
        );
        // A real tile on another tile's key.
        let mut wrong_key = jobs[3].clone();
        wrong_key.key_index = Some(TileIndex { tx: 9, ty: 9 });
        jobs.insert(40, wrong_key);
        let (m1, c1, e1) = run_worker(&jobs, 1);
        assert_eq!(e1, 2, "the bad payload and the wrong key are counted");
        assert!(c1.len() > 12, "{} changes", c1.len());
        for threads in [2, 3, 8] {
            let (m, c, e) = run_worker(&jobs, threads);
            assert_eq!(e, e1, "{threads} threads");
            assert_eq!(c, c1, "changes and their order, {threads} threads");
            assert_eq!(m.datums.len(), m1.datums.len());
            for (d, dm) in &m1.datums {
                assert_eq!(m.datums[d].tiles, dm.tiles, "datum {d}, {threads} threads");
            }
        }
        // Merged backwards the cells are the same (the order per cell is total) but the changes
        // and versions differ, so the test above would have seen a thread count that reordered
        // merges.
        let mut rev = jobs.clone();
        rev.reverse();
        let (mr, cr, _) = run_worker(&rev, 2);
        assert_ne!(cr, c1);
        for (d, dm) in &m1.datums {
            for (i, t) in &dm.tiles {
                assert_eq!(
                    mr.datums[d].tiles[i].cells, t.cells,
                    "datum {d}, tile {i:?}"
                );
            }
        }
    }

    /// What `robots` robots publish of one small tile over `steps` publications, one second
    /// apart (so several fall in one 4 s wire stamp step): per robot and publication, each cell
    /// is observed again (stamp, evidence, height, class), changes class or cost without a new
    /// observation (an inflation ring moving), is dropped by the mapper (unknown again), or
    /// stays. Every version is revised as the robot's publisher does and goes through the codec.
    /// The robots see the same cells at the same seconds, so they tie across robots too.
    fn robot_versions(robots: u64, steps: u32) -> Vec<Vec<Tile>> {
        let lattice = Lattice {
            cell_size_m: 0.2,
            tile_cells: 8,
        };
        let mut rng = 0x5eed_u64;
        let mut next = move |k: u64| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng % k
        };
        let states = [
            CellState::Traversable,
            CellState::Obstacle,
            CellState::Inflated,
        ];
        (0..robots)
            .map(|_| {
                let mut live = Tile::new(TileIndex { tx: 1, ty: -1 }, lattice);
                let mut published = live.clone();
                (1..=steps)
                    .map(|k| {
                        let t_s = 1_790_000_000 + k;
                        for c in &mut live.cells {
                            match next(5) {
                                0 | 1 => {
                                    *c = Cell {
                                        state: states[next(3) as usize],
                                        cost: next(3) as u8 * 100,
                                        height_cm: next(4) as i16 * 2,
                                        hits: c.hits.saturating_add(1 + next(4) as u8),
                                        stamp_s: t_s,
                                        rev: 0,
                                    }
                                }
                                2 if c.state != CellState::Unknown => {
                                    c.state = states[next(3) as usize];
                                    c.cost = next(3) as u8 * 100;
                                }
                                3 if next(3) == 0 => *c = Cell::UNKNOWN,
                                _ => {}
                            }
                        }
                        for (p, now) in published.cells.iter_mut().zip(&live.cells) {
                            *p = common::grid::revise_cell(p, now);
                        }
                        published.version = u64::from(k);
                        decode_tile(&encode_tile(&published)).unwrap()
                    })
                    .collect()
            })
            .collect()
    }

    fn merged_cells(tiles: &[&Tile]) -> Vec<Cell> {
        let mut m = MergedMap::default();
        for t in tiles {
            m.merge("d0", t).unwrap();
        }
        m.datums["d0"].tiles[&TileIndex { tx: 1, ty: -1 }]
            .cells
            .clone()
    }

    /// Every permutation of `items` (Heap's algorithm).
    fn permutations<T: Clone>(items: &[T]) -> Vec<Vec<T>> {
        fn go<T: Clone>(k: usize, a: &mut Vec<T>, out: &mut Vec<Vec<T>>) {
            if k <= 1 {
                out.push(a.clone());
                return;
            }
            for i in 0..k {
                go(k - 1, a, out);
                let j = if k.is_multiple_of(2) { i } else { 0 };
                a.swap(j, k - 1);
            }
        }
        let mut out = Vec::new();
        go(items.len(), &mut items.to_vec(), &mut out);
        out
    }

    #[test]
    fn the_merged_map_depends_only_on_each_robots_newest_tile() {
        let robots = robot_versions(2, 4);
        let newest: Vec<&Tile> = robots.iter().map(|v| v.last().unwrap()).collect();
        let want = merged_cells(&newest);
        assert!(
            want.iter()
                .filter(|c| c.state != CellState::Unknown)
                .count()
                > 40
        );
        let revised = robots.iter().flatten().flat_map(|t| &t.cells);
        assert!(revised.filter(|c| c.rev > 0).count() > 10, "ties to break");
        // Every version of both robots, in every one of the 8! orders.
        let all: Vec<&Tile> = robots.iter().flatten().collect();
        for (k, order) in permutations(&all).iter().enumerate() {
            assert_eq!(merged_cells(order), want, "order {k}");
        }
        // A station that missed intermediate versions (joined late, a lossy link): every
        // subset of each robot's older versions, with its newest, forwards and backwards.
        for mask in 0u32..64 {
            let mut got: Vec<&Tile> = Vec::new();
            for (r, versions) in robots.iter().enumerate() {
                for (v, t) in versions.iter().enumerate() {
                    if v == versions.len() - 1 || mask >> (r * 3 + v) & 1 == 1 {
                        got.push(t);
                    }
                }
            }
            assert_eq!(merged_cells(&got), want, "subset {mask:06b}");
            got.reverse();
            assert_eq!(merged_cells(&got), want, "subset {mask:06b} reversed");
        }
    }

    #[test]
    fn stale_tile_never_overwrites_newer_cells() {
        let new = tile(0, 0, |_, _| cell(CellState::Obstacle, 500, 2, 1));
        let old = tile(0, 0, |_, _| cell(CellState::Traversable, 400, 200, 2));
        let mut m = MergedMap::default();
        m.merge("d0", &new).unwrap();
        assert_eq!(m.merge("d0", &old).unwrap(), None, "nothing changes");
        let t = &m.datums["d0"].tiles[&TileIndex { tx: 0, ty: 0 }];
        assert!(t.cells.iter().all(|c| c.state == CellState::Obstacle));
        assert_eq!(t.version, 1);
        // Same stamp: more hits wins.
        let tie = tile(0, 0, |_, _| cell(CellState::Traversable, 500, 9, 3));
        assert_eq!(m.merge("d0", &tie).unwrap(), Some(2));
        // Re-sending the same tile changes nothing (no version bump).
        assert_eq!(m.merge("d0", &tie).unwrap(), None);
    }

    #[test]
    fn lattice_mismatch_is_refused() {
        let mut m = MergedMap::default();
        m.merge("d0", &tile(0, 0, |_, _| Cell::UNKNOWN)).unwrap();
        let mut t = Tile::new(
            TileIndex { tx: 0, ty: 0 },
            Lattice {
                cell_size_m: 0.5,
                tile_cells: 32,
            },
        );
        t.cells[0] = cell(CellState::Obstacle, 1, 1, 0);
        assert!(matches!(
            m.merge("d0", &t),
            Err(MergeError::LatticeMismatch { .. })
        ));
    }

    #[test]
    fn png_has_north_on_top() {
        let t = tile(0, 0, |_, r| {
            if r == 63 {
                cell(CellState::Obstacle, 1, 1, 0)
            } else {
                Cell::UNKNOWN
            }
        });
        let mt = MergedTile {
            cells: t.cells,
            version: 1,
        };
        let png = tile_png(&mt, 64);
        let dec = png::Decoder::new(std::io::Cursor::new(png));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        r.next_frame(&mut buf).unwrap();
        assert_eq!(
            &buf[..4],
            &[0xe5, 0x39, 0x35, 255],
            "top row is the northmost"
        );
        assert_eq!(buf[64 * 4 * 63 + 3], 0, "bottom row unknown, transparent");
    }

    #[test]
    fn scaled_export_repeats_each_cell() {
        // One obstacle cell at the north-west corner of tile (0, 1), tile (0, 0) below unknown.
        let mut m = MergedMap::default();
        m.merge(
            "d0",
            &tile(0, 1, |c, r| {
                if c == 0 && r == 63 {
                    cell(CellState::Obstacle, 1, 1, 0)
                } else {
                    cell(CellState::Traversable, 1, 1, 0)
                }
            }),
        )
        .unwrap();
        m.merge("d0", &tile(0, 0, |_, _| Cell::UNKNOWN)).unwrap();
        let decode = |png: Vec<u8>| {
            let mut r = png::Decoder::new(std::io::Cursor::new(png))
                .read_info()
                .unwrap();
            let mut buf = vec![0; r.output_buffer_size().unwrap()];
            let info = r.next_frame(&mut buf).unwrap();
            (info.width, info.height, buf)
        };
        let (w1, h1, one) = decode(datum_png(&m.datums["d0"]).unwrap());
        let (w3, h3, three) = decode(datum_png_scaled(&m.datums["d0"], 3).unwrap());
        assert_eq!((w1, h1), (64, 128));
        assert_eq!((w3, h3), (192, 384));
        let px = |buf: &[u8], w: u32, x: u32, y: u32| {
            let i = ((y * w + x) * 4) as usize;
            buf[i..i + 4].to_vec()
        };
        for y in 0..h3 {
            for x in 0..w3 {
                assert_eq!(
                    px(&three, w3, x, y),
                    px(&one, w1, x / 3, y / 3),
                    "({x},{y})"
                );
            }
        }
        assert_eq!(px(&three, w3, 2, 2), vec![0xe5, 0x39, 0x35, 255]);
    }
}
