//! Traversability cells, map tiles on the fixed map-frame lattice, and the tile codec.
//!
//! The map frame is cut into square cells of `cell_size_m`, grouped into tiles of
//! `tile_cells` x `tile_cells` cells. Cell (cx, cy) covers `[cx*s, (cx+1)*s) x [cy*s, (cy+1)*s)`;
//! tile (tx, ty) holds cells `tx*n .. tx*n+n`. Because the lattice is anchored at the map origin,
//! tiles from different times, sessions and robots on the same datum line up cell-exactly.

use serde::{Deserialize, Serialize};

mod codec;
mod range_coder;

pub use codec::field_bytes as tile_field_bytes;

/// What is known about one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[repr(u8)]
pub enum CellState {
    /// Never observed.
    #[default]
    Unknown = 0,
    /// Observed and drivable.
    Traversable = 1,
    /// Observed and not drivable (step, slope, rough, negative obstacle).
    Obstacle = 2,
    /// Drivable ground, but within the inflation distance of an obstacle.
    Inflated = 3,
}

impl CellState {
    fn from_bits(b: u8) -> Self {
        match b & 3 {
            1 => CellState::Traversable,
            2 => CellState::Obstacle,
            3 => CellState::Inflated,
            _ => CellState::Unknown,
        }
    }
}

/// One cell of a tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Cell {
    /// Classification.
    pub state: CellState,
    /// Planner penalty, 0 (free) to 255.
    pub cost: u8,
    /// Mean ground height, centimetres in the map frame.
    pub height_cm: i16,
    /// Evidence: number of scans (not points) that observed the cell, saturating at 255. Counting
    /// scans keeps neighbouring cells alike, which is what lets tiles compress to well under 1 KB.
    pub hits: u8,
    /// Time of the newest observation, Unix seconds (0 = never); the merge lets newer evidence win.
    pub stamp_s: u32,
    /// Revision of the cell at its stamp and evidence: the publishing robot counts up each time
    /// the cell's content changes on the wire while its (coarse) stamp and evidence do not move,
    /// and restarts at 0 when they do ([`revise_cell`]). With it every consumer orders a robot's
    /// versions of a cell the same way ([`cell_order`]); 0 in a robot's own map.
    pub rev: u16,
}

impl Cell {
    /// An unobserved cell.
    pub const UNKNOWN: Cell = Cell {
        state: CellState::Unknown,
        cost: 0,
        height_cm: 0,
        hits: 0,
        stamp_s: 0,
        rev: 0,
    };
}

/// Index of a tile on the lattice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TileIndex {
    /// Column (x / east).
    pub tx: i32,
    /// Row (y / north).
    pub ty: i32,
}

/// The fixed map-frame lattice of cells and tiles.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lattice {
    /// Cell edge, metres.
    pub cell_size_m: f32,
    /// Cells per tile side.
    pub tile_cells: u16,
}

impl Default for Lattice {
    fn default() -> Self {
        Self {
            cell_size_m: 0.2,
            tile_cells: 64,
        }
    }
}

impl Lattice {
    /// The global cell holding map point (x, y).
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> (i64, i64) {
        let s = self.cell_size_f64();
        ((x_m / s).floor() as i64, (y_m / s).floor() as i64)
    }

    /// Cell edge in f64, rounded to the micrometre so that the f32 on the wire (0.2 is not exact
    /// in binary) gives the decimal size every producer and consumer means.
    pub fn cell_size_f64(&self) -> f64 {
        (self.cell_size_m as f64 * 1e6).round() / 1e6
    }

    /// Centre of a global cell, map frame.
    pub fn cell_center_m(&self, cx: i64, cy: i64) -> (f64, f64) {
        let s = self.cell_size_f64();
        ((cx as f64 + 0.5) * s, (cy as f64 + 0.5) * s)
    }

    /// The tile holding a global cell, and the cell's (column, row) inside it.
    #[inline]
    pub fn tile_of_cell(&self, cx: i64, cy: i64) -> (TileIndex, (u16, u16)) {
        let n = self.tile_cells as i64;
        if self.tile_cells.is_power_of_two() {
            // Hot path of every mapper lookup: an arithmetic shift is the floor division.
            let k = self.tile_cells.trailing_zeros();
            let m = n - 1;
            return (
                TileIndex {
                    tx: (cx >> k) as i32,
                    ty: (cy >> k) as i32,
                },
                ((cx & m) as u16, (cy & m) as u16),
            );
        }
        (
            TileIndex {
                tx: cx.div_euclid(n) as i32,
                ty: cy.div_euclid(n) as i32,
            },
            (cx.rem_euclid(n) as u16, cy.rem_euclid(n) as u16),
        )
    }

    /// Global index of the lower-left cell of a tile.
    pub fn tile_first_cell(&self, t: TileIndex) -> (i64, i64) {
        let n = self.tile_cells as i64;
        (t.tx as i64 * n, t.ty as i64 * n)
    }

    /// Lower-left corner of a tile, map frame, metres.
    pub fn tile_origin_m(&self, t: TileIndex) -> (f64, f64) {
        let (cx, cy) = self.tile_first_cell(t);
        let s = self.cell_size_f64();
        (cx as f64 * s, cy as f64 * s)
    }
}

/// A square block of cells on the lattice.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Tile {
    /// Where the tile is.
    pub index: TileIndex,
    /// The lattice it lives on.
    pub lattice: Lattice,
    /// Monotonic version: +1 each time the producer changes the tile.
    pub version: u64,
    /// `tile_cells^2` cells, row-major, row 0 = southmost (lowest y), column 0 = westmost.
    pub cells: Vec<Cell>,
}

impl Tile {
    /// An all-unknown tile.
    pub fn new(index: TileIndex, lattice: Lattice) -> Self {
        let n = lattice.tile_cells as usize;
        Self {
            index,
            lattice,
            version: 0,
            cells: vec![Cell::UNKNOWN; n * n],
        }
    }

    /// Cell at (column, row).
    pub fn get(&self, col: u16, row: u16) -> &Cell {
        &self.cells[row as usize * self.lattice.tile_cells as usize + col as usize]
    }

    /// Mutable cell at (column, row).
    pub fn get_mut(&mut self, col: u16, row: u16) -> &mut Cell {
        let n = self.lattice.tile_cells as usize;
        &mut self.cells[row as usize * n + col as usize]
    }

    /// Number of cells that are not unknown.
    pub fn known_cells(&self) -> usize {
        self.cells
            .iter()
            .filter(|c| c.state != CellState::Unknown)
            .count()
    }
}

/// First byte of every encoded tile.
pub const TILE_MAGIC: u8 = b'T';
/// Version of the tile codec layout [`encode_tile`] writes (4: context-modelled range coding of
/// the wire cells with their revisions; 3, still decoded: the same without revisions, read as
/// revision 0; 2, still decoded: the cells as zstd-compressed columns).
pub const TILE_CODEC_VERSION: u8 = codec::VERSION;
/// Codec v3 (the cells without their revision), still decoded so stores and recordings written
/// by older builds stay readable.
pub const TILE_CODEC_VERSION_V3: u8 = codec::VERSION_V3;
/// The v2 layout, still decoded so stores written by older builds stay readable.
pub const TILE_CODEC_VERSION_V2: u8 = 2;
/// zstd level of the v2 layout: 19 costs ~3 ms per full tile (a robot publishes tens a second at most) and
/// entropy-codes the quantized columns ~20% smaller than level 3.
const ZSTD_LEVEL: i32 = 19;
/// Largest tile side the decoder accepts (bounds memory on hostile input).
pub const MAX_TILE_CELLS: u16 = 512;
/// Heights travel in steps of this many centimetres: below the mapper's own height hysteresis
/// (3 cm) and far below any step that matters (`max_step_m` 10 cm), and it halves the entropy
/// that grass noise puts into a tile.
pub const WIRE_HEIGHT_STEP_CM: i16 = 2;
/// Evidence travels saturated at this many scans: merges only compare evidence to break ties,
/// and past a few scans "seen often" is all a consumer needs to know.
pub const WIRE_HITS_MAX: u8 = 7;
/// Stamps travel floored to this many seconds: the same observation time always gives the same
/// wire value whatever else the tile holds (so robot and station tiles compare cell by cell),
/// a decoded stamp is never newer than the observation, and runs of equal values compress.
pub const WIRE_STAMP_STEP_S: u32 = 4;

/// A cell as it travels: see [`wire_tile`].
pub fn wire_cell(c: &Cell) -> Cell {
    if c.state == CellState::Unknown {
        return Cell::UNKNOWN;
    }
    Cell {
        state: c.state,
        cost: c.cost,
        height_cm: c.height_cm.div_euclid(WIRE_HEIGHT_STEP_CM) * WIRE_HEIGHT_STEP_CM,
        hits: c.hits.min(WIRE_HITS_MAX),
        stamp_s: c.stamp_s - c.stamp_s % WIRE_STAMP_STEP_S,
        rev: c.rev,
    }
}

/// The total order of cells that the merge keeps the greatest of (docs/algorithms.md 8.3):
/// unknown below everything; then newer stamp, more evidence, higher revision; then, so that
/// two different cells never tie, state, cost and height. Meant for wire cells ([`wire_cell`]),
/// which is all a station has.
pub fn cell_order(a: &Cell, b: &Cell) -> std::cmp::Ordering {
    let known = |c: &Cell| c.state != CellState::Unknown;
    let key = |c: &Cell| (c.stamp_s, c.hits, c.rev, c.state as u8, c.cost, c.height_cm);
    match (known(a), known(b)) {
        (false, false) => std::cmp::Ordering::Equal,
        (ka, kb) if ka != kb => ka.cmp(&kb),
        _ => key(a).cmp(&key(b)),
    }
}

/// The cell a robot publishes when it last published `prev` and its map now holds `now` (both
/// exact cells with Unix stamps; `prev` as published, revision included). Makes every change a
/// consumer can see go up in [`cell_order`], so a robot's newest version of a cell is the
/// greatest it ever published and a merge that keeps the greatest does not depend on which of
/// its versions arrived or in which order:
/// - a cell the robot stops knowing keeps its last published content (evidence is not
///   retracted; the station never lets unknown win either);
/// - the same on the wire: `now` with `prev`'s revision;
/// - newer wire stamp or more wire evidence: `now`, revision 0;
/// - otherwise (a change inside one 4 s stamp step with saturated evidence, such as an
///   inflation ring moving): `now` with `prev`'s stamp and evidence where larger and the
///   revision + 1 (saturating at `u16::MAX`, 18 hours of changes at one stamp at 1 Hz).
pub fn revise_cell(prev: &Cell, now: &Cell) -> Cell {
    if now.state == CellState::Unknown {
        return *prev;
    }
    if prev.state == CellState::Unknown {
        return Cell { rev: 0, ..*now };
    }
    let same_rev = Cell {
        rev: prev.rev,
        ..*now
    };
    let (wp, wn) = (wire_cell(prev), wire_cell(&same_rev));
    if wn == wp {
        return same_rev;
    }
    if (wn.stamp_s, wn.hits) > (wp.stamp_s, wp.hits) {
        return Cell { rev: 0, ..*now };
    }
    Cell {
        stamp_s: now.stamp_s.max(prev.stamp_s),
        hits: now.hits.max(prev.hits),
        rev: prev.rev.saturating_add(1),
        ..*now
    }
}

/// The tile as a consumer receives it: `decode_tile(&encode_tile(t))`. States, costs and the
/// tile header are exact; per cell, heights are floored to [`WIRE_HEIGHT_STEP_CM`], evidence
/// saturates at [`WIRE_HITS_MAX`] and stamps are floored to [`WIRE_STAMP_STEP_S`]. Every step
/// is per cell and monotonic, so newer-evidence-wins comparisons give the same answer on either
/// side of the wire, and applying it twice changes nothing.
pub fn wire_tile(tile: &Tile) -> Tile {
    Tile {
        cells: tile.cells.iter().map(wire_cell).collect(),
        ..tile.clone()
    }
}

/// Why a tile payload was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TileCodecError {
    /// Not a tile payload (wrong magic) or empty.
    #[error("not a tile payload")]
    BadMagic,
    /// A tile codec this build does not speak.
    #[error("tile codec version {0}, this build speaks {TILE_CODEC_VERSION}")]
    UnsupportedVersion(u8),
    /// The compressed stream is corrupt or too large.
    #[error("tile decompression failed: {0}")]
    Decompress(String),
    /// The decompressed bytes are not a valid tile.
    #[error("malformed tile: {0}")]
    Malformed(String),
    /// The payload's checksum does not match: corrupted in transit or in storage.
    #[error("tile checksum mismatch")]
    Checksum,
}

/// Column-wise wire layout: grouping like values makes them compress; unknown cells carry only
/// their state.
#[derive(Serialize, Deserialize)]
struct TileWire {
    tx: i32,
    ty: i32,
    cell_size_m: f32,
    tile_cells: u16,
    version: u64,
    /// 2-bit states, four cells per byte.
    states: Vec<u8>,
    /// For known cells in order: the planner cost (inflation rings repeat, so raw values
    /// compress better than differences).
    costs: Vec<u8>,
    /// For known cells in order: height in wire steps minus the previous known cell's.
    height_deltas: Vec<i16>,
    /// For known cells in order: evidence, saturated at [`WIRE_HITS_MAX`].
    hits: Vec<u8>,
    /// Stamp of the first known cell in [`WIRE_STAMP_STEP_S`] steps; the others as differences
    /// to the previous known cell.
    stamp_base: u32,
    stamp_deltas: Vec<i32>,
}

/// Encodes a tile with the current codec (see the `codec` module). Lossy in the documented
/// ways of [`wire_cell`] only; `decode_tile(encode_tile(t)) == wire_tile(t)`.
pub fn encode_tile(tile: &Tile) -> Vec<u8> {
    codec::encode(tile)
}

/// Encodes a tile in the v3 layout (revisions left out: they decode as 0): what the previous
/// builds wrote, kept to show that their stores and recordings stay readable.
pub fn encode_tile_v3(tile: &Tile) -> Vec<u8> {
    codec::encode_version(tile, codec::VERSION_V3)
}

/// Encodes a tile in the v2 layout (postcard columns, then zstd): what older builds wrote, kept
/// as the baseline the codec benchmarks compare against.
pub fn encode_tile_v2(tile: &Tile) -> Vec<u8> {
    let n = tile.cells.len();
    let mut states = vec![0u8; n.div_ceil(4)];
    for (i, c) in tile.cells.iter().enumerate() {
        states[i / 4] |= (c.state as u8) << ((i % 4) * 2);
    }
    let k = tile.known_cells();
    let (mut costs, mut heights, mut hits, mut stamps) = (
        Vec::with_capacity(k),
        Vec::with_capacity(k),
        Vec::with_capacity(k),
        Vec::with_capacity(k),
    );
    let known = tile.cells.iter().filter(|c| c.state != CellState::Unknown);
    let stamp_base = tile
        .cells
        .iter()
        .find(|c| c.state != CellState::Unknown)
        .map_or(0, |c| c.stamp_s / WIRE_STAMP_STEP_S);
    let (mut prev_h, mut prev_s) = (0i16, stamp_base);
    for c in known {
        costs.push(c.cost);
        let h = c.height_cm.div_euclid(WIRE_HEIGHT_STEP_CM);
        heights.push(h.wrapping_sub(prev_h));
        prev_h = h;
        hits.push(c.hits.min(WIRE_HITS_MAX));
        let q = c.stamp_s / WIRE_STAMP_STEP_S;
        stamps.push(q.wrapping_sub(prev_s) as i32);
        prev_s = q;
    }
    let wire = TileWire {
        tx: tile.index.tx,
        ty: tile.index.ty,
        cell_size_m: tile.lattice.cell_size_m,
        tile_cells: tile.lattice.tile_cells,
        version: tile.version,
        states,
        costs,
        height_deltas: heights,
        hits,
        stamp_base,
        stamp_deltas: stamps,
    };
    let raw = postcard::to_allocvec(&wire).expect("tile wire layout always encodes");
    let mut out = vec![TILE_MAGIC, TILE_CODEC_VERSION_V2];
    out.extend(
        zstd::bulk::compress(&raw, ZSTD_LEVEL).expect("zstd compression into memory does not fail"),
    );
    out
}

/// Decodes a tile produced by [`encode_tile`] (or [`encode_tile_v2`]); any corruption is a
/// typed error, never a panic.
pub fn decode_tile(bytes: &[u8]) -> Result<Tile, TileCodecError> {
    match bytes {
        [TILE_MAGIC, TILE_CODEC_VERSION | TILE_CODEC_VERSION_V3, ..] => codec::decode(bytes),
        [TILE_MAGIC, TILE_CODEC_VERSION_V2, ..] => decode_tile_v2(bytes),
        [TILE_MAGIC, v, ..] => Err(TileCodecError::UnsupportedVersion(*v)),
        _ => Err(TileCodecError::BadMagic),
    }
}

fn decode_tile_v2(bytes: &[u8]) -> Result<Tile, TileCodecError> {
    let max = MAX_TILE_CELLS as usize;
    // Upper bound of a valid raw layout: generous per-cell budget plus header.
    let capacity = max * max * 12 + 64;
    let raw = zstd::bulk::decompress(&bytes[2..], capacity)
        .map_err(|e| TileCodecError::Decompress(e.to_string()))?;
    let (wire, rest): (TileWire, &[u8]) =
        postcard::take_from_bytes(&raw).map_err(|e| TileCodecError::Malformed(e.to_string()))?;
    let bad = |m: &str| Err(TileCodecError::Malformed(m.to_string()));
    if !rest.is_empty() {
        return bad("trailing bytes");
    }
    if wire.tile_cells == 0 || wire.tile_cells > MAX_TILE_CELLS {
        return bad("tile size out of range");
    }
    if !(wire.cell_size_m.is_finite() && wire.cell_size_m > 0.0) {
        return bad("cell size not positive");
    }
    let n = wire.tile_cells as usize * wire.tile_cells as usize;
    if wire.states.len() != n.div_ceil(4) {
        return bad("state array length");
    }
    let states: Vec<CellState> = (0..n)
        .map(|i| CellState::from_bits(wire.states[i / 4] >> ((i % 4) * 2)))
        .collect();
    let k = states.iter().filter(|s| **s != CellState::Unknown).count();
    if wire.costs.len() != k
        || wire.height_deltas.len() != k
        || wire.hits.len() != k
        || wire.stamp_deltas.len() != k
    {
        return bad("per-cell array lengths disagree with the states");
    }
    if wire.hits.iter().any(|h| *h > WIRE_HITS_MAX) {
        return bad("evidence above the wire's saturation");
    }
    let mut cells = vec![Cell::UNKNOWN; n];
    let (mut h, mut q) = (0i16, wire.stamp_base);
    let mut j = 0;
    for (cell, state) in cells.iter_mut().zip(&states) {
        if *state == CellState::Unknown {
            continue;
        }
        h = h.wrapping_add(wire.height_deltas[j]);
        q = q.wrapping_add(wire.stamp_deltas[j] as u32);
        if q > u32::MAX / WIRE_STAMP_STEP_S {
            return bad("stamp out of range");
        }
        *cell = Cell {
            state: *state,
            cost: wire.costs[j],
            height_cm: h.wrapping_mul(WIRE_HEIGHT_STEP_CM),
            hits: wire.hits[j],
            stamp_s: q * WIRE_STAMP_STEP_S,
            rev: 0,
        };
        j += 1;
    }
    Ok(Tile {
        index: TileIndex {
            tx: wire.tx,
            ty: wire.ty,
        },
        lattice: Lattice {
            cell_size_m: wire.cell_size_m,
            tile_cells: wire.tile_cells,
        },
        version: wire.version,
        cells,
    })
}

/// Realistic synthetic tiles for size reports and benchmarks: flat ground, a curb-rich street
/// corner, and noisy rough terrain with scattered obstacles.
pub mod samples {
    use super::*;

    /// Deterministic pseudo-random generator (SplitMix64) so samples are identical everywhere.
    fn next(state: &mut u64) -> u64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn tile_with(f: impl Fn(usize, usize, &mut u64) -> Cell) -> Tile {
        let lattice = Lattice::default();
        let mut t = Tile::new(TileIndex { tx: 3, ty: -2 }, lattice);
        let n = lattice.tile_cells as usize;
        let mut s = 42u64;
        for r in 0..n {
            for c in 0..n {
                t.cells[r * n + c] = f(c, r, &mut s);
            }
        }
        t.version = 17;
        t
    }

    /// Flat, fully observed, gently sloping ground (1 cm per 2 m), all traversable.
    pub fn flat() -> Tile {
        tile_with(|c, r, s| Cell {
            state: CellState::Traversable,
            cost: 0,
            height_cm: 1200 + (c / 10) as i16 + next(s).is_multiple_of(4) as i16,
            hits: 40 - (r / 4) as u8,
            stamp_s: 1_790_000_000 + (r as u32) / 8,
            rev: 0,
        })
    }

    /// A street corner: road, two 10-15 cm curbs with inflated bands, sidewalk; the far quarter unknown.
    pub fn curb_rich() -> Tile {
        tile_with(|c, r, s| {
            if c + r > 100 {
                return Cell::UNKNOWN;
            }
            let curb = c == 20 || r == 40;
            let near = (c as i32 - 20).abs() <= 2 || (r as i32 - 40).abs() <= 2;
            let sidewalk = c > 20 || r > 40;
            let (state, cost) = if curb {
                (CellState::Obstacle, 255)
            } else if near {
                (CellState::Inflated, 200)
            } else {
                (CellState::Traversable, 0)
            };
            Cell {
                state,
                cost,
                height_cm: 300 + if sidewalk { 12 } else { 0 } + next(s).is_multiple_of(3) as i16,
                hits: 30 - ((c + r) / 8) as u8,
                stamp_s: 1_790_000_000 + ((c + r) / 6) as u32,
                rev: 0,
            }
        })
    }

    /// Rough off-road terrain: heights varying by decimetres with ±2 cm grass noise, obstacle
    /// clusters (rocks, bushes) with inflated bands and decaying costs, 15% unknown (shadows).
    pub fn noisy() -> Tile {
        let rocks = [
            (10.0f32, 12.0f32, 3.0f32),
            (40.0, 20.0, 4.5),
            (25.0, 50.0, 2.5),
            (55.0, 55.0, 3.5),
        ];
        tile_with(move |c, r, s| {
            let (x, y) = (c as f32, r as f32);
            let d = rocks
                .iter()
                .map(|(rx, ry, rad)| ((x - rx).hypot(y - ry) - rad).max(0.0))
                .fold(f32::MAX, f32::min);
            // Shadows behind the rocks, as seen from a sensor at the tile's south-west corner.
            let shadow = rocks.iter().any(|(rx, ry, rad)| {
                let (dx, dy) = (x - rx, y - ry);
                dx > 0.0
                    && dy > 0.0
                    && (dx * ry - dy * rx).abs() / rx.hypot(*ry) < *rad
                    && dx.hypot(dy) < 12.0
            });
            if shadow {
                return Cell::UNKNOWN;
            }
            let (state, cost) = if d == 0.0 {
                (CellState::Obstacle, 255)
            } else if d <= 2.0 {
                (CellState::Inflated, 200)
            } else {
                (
                    CellState::Traversable,
                    (120.0 * (-(d - 2.0) / 3.0).exp()) as u8,
                )
            };
            Cell {
                state,
                cost,
                height_cm: 500
                    + ((x * 0.15).sin() * 25.0 + (y * 0.1).cos() * 15.0) as i16
                    + (next(s) % 5) as i16,
                hits: (60.0 - x.hypot(y) * 0.5) as u8,
                stamp_s: 1_790_000_000 + (x.hypot(y) / 4.0) as u32,
                rev: 0,
            }
        })
    }
}

/// A SHA-256 digest (hex) of a map's content: every tile's index and cells (state, cost, height,
/// evidence, stamp, revision), in tile order, whatever order `tiles` come in. Versions are left out: they
/// count publications, not content. Two runs that built the same map have the same digest,
/// which is how refactors and replays prove they changed nothing.
pub fn map_digest(tiles: &[Tile]) -> String {
    use sha2::{Digest, Sha256};
    let mut sorted: Vec<&Tile> = tiles.iter().collect();
    sorted.sort_by_key(|t| t.index);
    let mut h = Sha256::new();
    for t in sorted {
        h.update(t.index.tx.to_le_bytes());
        h.update(t.index.ty.to_le_bytes());
        h.update(t.lattice.cell_size_m.to_le_bytes());
        h.update(t.lattice.tile_cells.to_le_bytes());
        for c in &t.cells {
            h.update([c.state as u8, c.cost, c.hits]);
            h.update(c.height_cm.to_le_bytes());
            h.update(c.stamp_s.to_le_bytes());
            h.update(c.rev.to_le_bytes());
        }
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn map_digest_sees_content_not_order_or_version() {
        let l = Lattice::default();
        let mut a = Tile::new(TileIndex { tx: 0, ty: 0 }, l);
        let b = Tile::new(TileIndex { tx: 1, ty: -1 }, l);
        let d0 = map_digest(&[a.clone(), b.clone()]);
        assert_eq!(d0, map_digest(&[b.clone(), a.clone()]), "order");
        a.version = 9;
        assert_eq!(d0, map_digest(&[a.clone(), b.clone()]), "version");
        a.cells[5].height_cm = 1;
        assert_ne!(d0, map_digest(&[a, b]), "content");
    }

    #[test]
    fn lattice_is_anchored_at_the_origin() {
        let l = Lattice::default();
        assert_eq!(l.cell_of(0.0, 0.0), (0, 0));
        assert_eq!(l.cell_of(-0.01, 0.19), (-1, 0));
        assert_eq!(
            l.tile_of_cell(-1, 64),
            (TileIndex { tx: -1, ty: 1 }, (63, 0))
        );
        assert_eq!(l.tile_origin_m(TileIndex { tx: -1, ty: 1 }), (-12.8, 12.8));
        let (cx, cy) = l.cell_of(5.05, -3.3);
        let (t, (c, r)) = l.tile_of_cell(cx, cy);
        let (fx, fy) = l.tile_first_cell(t);
        assert_eq!((fx + c as i64, fy + r as i64), (cx, cy));
    }

    #[test]
    #[ignore = "report: prints the README's tile size table (cargo test --release -p common -- --ignored --nocapture)"]
    fn report_tile_sizes() {
        for (name, t) in [
            ("flat", samples::flat()),
            ("curb-rich", samples::curb_rich()),
            ("noisy", samples::noisy()),
        ] {
            let b = encode_tile(&t);
            let raw = postcard::to_allocvec(&t).unwrap().len();
            println!("| {name} | {} | {raw} | {} |", t.known_cells(), b.len());
        }
    }

    #[test]
    #[ignore = "report: codec v3 vs v2 on a folder of exact tiles (robot-agent map eval --tiles-out DIR; TERRANAV_TILE_CORPUS=DIR)"]
    fn corpus() {
        let Ok(dir) = std::env::var("TERRANAV_TILE_CORPUS") else {
            println!("TERRANAV_TILE_CORPUS not set: nothing to report");
            return;
        };
        let mut paths: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "tile"))
            .collect();
        paths.sort();
        let (mut v3, mut v2, mut known) = (0usize, 0usize, 0usize);
        let (mut t3, mut t2, mut d3, mut d2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let mut fields = [0.0f64; 7];
        for p in &paths {
            let t: Tile = postcard::from_bytes(&std::fs::read(p).unwrap()).unwrap();
            for (f, b) in fields.iter_mut().zip(tile_field_bytes(&t)) {
                *f += b;
            }
            let s = std::time::Instant::now();
            let b3 = encode_tile(&t);
            t3 += s.elapsed().as_secs_f64();
            let s = std::time::Instant::now();
            let b2 = encode_tile_v2(&t);
            t2 += s.elapsed().as_secs_f64();
            let s = std::time::Instant::now();
            assert_eq!(decode_tile(&b3).unwrap(), wire_tile(&t), "{}", p.display());
            d3 += s.elapsed().as_secs_f64();
            let s = std::time::Instant::now();
            assert_eq!(decode_tile(&b2).unwrap(), wire_tile(&t), "{}", p.display());
            d2 += s.elapsed().as_secs_f64();
            v3 += b3.len();
            v2 += b2.len();
            known += t.known_cells();
        }
        let n = paths.len().max(1) as f64;
        println!(
            "{} tiles, {:.0} known cells mean: v3 {:.0} B mean ({:.3} ms), v2 {:.0} B mean ({:.3} ms), v3/v2 size {:.3}, time {:.3}",
            paths.len(),
            known as f64 / n,
            v3 as f64 / n,
            t3 * 1e3 / n,
            v2 as f64 / n,
            t2 * 1e3 / n,
            v3 as f64 / v2.max(1) as f64,
            t3 / t2.max(1e-12)
        );
        println!(
            "decode (with the comparison): v3 {:.3} ms, v2 {:.3} ms",
            d3 * 1e3 / n,
            d2 * 1e3 / n
        );
        let names = [
            "known", "obstacle", "inflated", "cost", "height", "evidence", "stamp",
        ];
        let per: Vec<String> = names
            .iter()
            .zip(fields)
            .map(|(k, b)| format!("{k} {:.0}", b / n))
            .collect();
        println!("v3 bytes per field (ideal): {}", per.join(", "));
    }

    #[test]
    fn samples_round_trip_and_are_small() {
        // 4096 cells at 9 bytes raw = 36 KiB; see the README's table for the measured sizes.
        for (name, t, max) in [
            ("flat", samples::flat(), 1500),
            ("curb", samples::curb_rich(), 2000),
            ("noisy", samples::noisy(), 6000),
        ] {
            let b = encode_tile(&t);
            let back = decode_tile(&b).unwrap();
            assert_eq!(back, wire_tile(&t), "{name}");
            // What the codec changes it changes once: a relayed tile is the same tile.
            assert_eq!(encode_tile(&back), b, "{name}");
            assert!(b.len() < max, "{name}: {} bytes", b.len());
            // The wire's promises: heights within one step below, evidence saturated, stamps
            // never newer than observed.
            for (a, w) in t.cells.iter().zip(&back.cells) {
                assert_eq!((a.state, a.cost), (w.state, w.cost));
                if a.state != CellState::Unknown {
                    assert!((0..WIRE_HEIGHT_STEP_CM).contains(&(a.height_cm - w.height_cm)));
                    assert_eq!(w.hits, a.hits.min(WIRE_HITS_MAX));
                    assert!(w.stamp_s <= a.stamp_s, "{name}: stamp {w:?} vs {a:?}");
                }
            }
        }
        let empty = Tile::new(TileIndex { tx: 0, ty: 0 }, Lattice::default());
        assert_eq!(decode_tile(&encode_tile(&empty)).unwrap(), empty);
    }

    #[test]
    fn corrupt_tiles_are_typed_errors() {
        let b = encode_tile(&samples::curb_rich());
        assert_eq!(decode_tile(&[]), Err(TileCodecError::BadMagic));
        assert_eq!(decode_tile(b"X1abc"), Err(TileCodecError::BadMagic));
        assert_eq!(
            decode_tile(&[TILE_MAGIC, 99, 0]),
            Err(TileCodecError::UnsupportedVersion(99))
        );
        assert!(decode_tile(&b[..b.len() / 2]).is_err());
        // Every single corrupted byte is caught by the checksum: a damaged tile is refused,
        // never merged as garbage.
        for i in 2..b.len() {
            let mut flipped = b.clone();
            flipped[i] ^= 0x5a;
            assert!(decode_tile(&flipped).is_err(), "byte {i}");
        }
        let mut flipped = b.clone();
        flipped[5] ^= 1;
        assert_eq!(decode_tile(&flipped), Err(TileCodecError::Checksum));
        // Stores written by older builds stay readable.
        let t = samples::curb_rich();
        assert_eq!(decode_tile(&encode_tile_v2(&t)).unwrap(), wire_tile(&t));
    }

    fn arb_cell() -> impl Strategy<Value = Cell> {
        (
            0u8..4,
            any::<u8>(),
            any::<i16>(),
            any::<u8>(),
            any::<u32>(),
            prop_oneof![Just(0u16), 1u16..4, any::<u16>()],
        )
            .prop_map(|(s, cost, h, hits, stamp, rev)| {
                let state = CellState::from_bits(s);
                if state == CellState::Unknown {
                    Cell::UNKNOWN
                } else {
                    Cell {
                        state,
                        cost,
                        height_cm: h,
                        hits,
                        stamp_s: stamp,
                        rev,
                    }
                }
            })
    }

    proptest! {
        #[test]
        fn every_tile_round_trips(n in 1u16..24, tx in any::<i32>(), ty in any::<i32>(), version in any::<u64>(),
                                  cs in 0.01f32..2.0, cells in proptest::collection::vec(arb_cell(), 576)) {
            let lattice = Lattice { cell_size_m: cs, tile_cells: n };
            let nn = n as usize * n as usize;
            let t = Tile { index: TileIndex { tx, ty }, lattice, version, cells: cells[..nn].to_vec() };
            let back = decode_tile(&encode_tile(&t)).unwrap();
            prop_assert_eq!(&back, &wire_tile(&t));
            prop_assert_eq!(decode_tile(&encode_tile(&back)).unwrap(), back);
        }

        #[test]
        fn stamps_never_get_newer_and_keep_their_order(stamps in proptest::collection::vec(0u32..u32::MAX, 64)) {
            let lattice = Lattice { cell_size_m: 0.2, tile_cells: 8 };
            let mut t = Tile::new(TileIndex { tx: 0, ty: 0 }, lattice);
            for (c, s) in t.cells.iter_mut().zip(&stamps) {
                *c = Cell { state: CellState::Traversable, cost: 0, height_cm: 0, hits: 1, stamp_s: *s, rev: 0 };
            }
            let back = decode_tile(&encode_tile(&t)).unwrap();
            for (a, w) in t.cells.iter().zip(&back.cells) {
                prop_assert!(w.stamp_s <= a.stamp_s && a.stamp_s - w.stamp_s < WIRE_STAMP_STEP_S);
            }
            // Monotonic: an older observation never decodes newer than a newer one.
            for i in 0..64 {
                for j in 0..64 {
                    if t.cells[i].stamp_s <= t.cells[j].stamp_s {
                        prop_assert!(back.cells[i].stamp_s <= back.cells[j].stamp_s);
                    }
                }
            }
        }

        #[test]
        fn random_bytes_never_panic(mut bytes in proptest::collection::vec(any::<u8>(), 0..512), magic in any::<bool>()) {
            if magic && bytes.len() >= 2 { bytes[0] = TILE_MAGIC; bytes[1] = TILE_CODEC_VERSION; }
            let _ = decode_tile(&bytes);
            if magic && bytes.len() >= 2 { bytes[1] = TILE_CODEC_VERSION_V2; }
            let _ = decode_tile(&bytes);
        }

        #[test]
        fn corrupted_tiles_never_panic(flip in 0usize..4096, byte in any::<u8>()) {
            let mut b = encode_tile(&samples::curb_rich());
            let i = 2 + flip % (b.len() - 2);
            b[i] = byte;
            let _ = decode_tile(&b);
        }

        #[test]
        fn garbage_behind_a_valid_checksum_never_panics(body in proptest::collection::vec(any::<u8>(), 0..600), n in 1u16..80) {
            // What the checksum cannot catch (a producer's bug, a forged payload) reaches the
            // range decoder and the value checks, which must hold on their own.
            let mut b = vec![TILE_MAGIC, TILE_CODEC_VERSION];
            b.extend(postcard::to_allocvec(&(0i32, 0i32, 0.2f32, n, 1u64)).unwrap());
            b.extend(body);
            let crc = crc32fast::hash(&b);
            b.extend(crc.to_le_bytes());
            if let Ok(t) = decode_tile(&b) {
                prop_assert_eq!(t.cells.len(), n as usize * n as usize);
                prop_assert_eq!(wire_tile(&t), t);
            }
        }

        #[test]
        fn v2_tiles_still_decode(n in 1u16..24, cells in proptest::collection::vec(arb_cell(), 576)) {
            let lattice = Lattice { cell_size_m: 0.2, tile_cells: n };
            let nn = n as usize * n as usize;
            let t = Tile { index: TileIndex { tx: 3, ty: -4 }, lattice, version: 9, cells: cells[..nn].to_vec() };
            let mut want = wire_tile(&t);
            want.cells.iter_mut().for_each(|c| c.rev = 0);
            prop_assert_eq!(decode_tile(&encode_tile_v2(&t)).unwrap(), want.clone());
            // Codec v3 (the previous version) too: the same cells, revisions read as 0.
            prop_assert_eq!(decode_tile(&encode_tile_v3(&t)).unwrap(), want);
        }

        #[test]
        fn cell_order_is_total(a in arb_cell(), b in arb_cell(), c in arb_cell()) {
            use std::cmp::Ordering::*;
            let (a, b, c) = (wire_cell(&a), wire_cell(&b), wire_cell(&c));
            // Equal only when equal: the greatest of any set is one cell, whatever the order.
            prop_assert_eq!(cell_order(&a, &b) == Equal, a == b);
            prop_assert_eq!(cell_order(&a, &b), cell_order(&b, &a).reverse());
            if cell_order(&a, &b) != Greater && cell_order(&b, &c) != Greater {
                prop_assert!(cell_order(&a, &c) != Greater);
            }
        }

        #[test]
        fn a_revised_change_goes_up_in_the_order(prev in arb_cell(), now in arb_cell()) {
            use std::cmp::Ordering::*;
            // What a robot publishes after `prev`: never lower in the order, higher whenever the
            // wire shows a change, and unknown never replaces what it published.
            let next = revise_cell(&prev, &now);
            let (wp, wn) = (wire_cell(&prev), wire_cell(&next));
            prop_assert!(cell_order(&wn, &wp) != Less);
            if wn != wp && prev.rev < u16::MAX {
                prop_assert_eq!(cell_order(&wn, &wp), Greater);
            }
            if now.state != CellState::Unknown {
                prop_assert_eq!((next.state, next.cost, next.height_cm), (now.state, now.cost, now.height_cm));
            } else {
                prop_assert_eq!(next, prev);
            }
        }
    }
}
