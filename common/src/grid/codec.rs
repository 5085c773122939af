//! Tile codec v4: the wire cells ([`super::wire_cell`]) coded losslessly with an adaptive
//! binary range coder under per-field context models, as lossless image codecs do (JBIG-like
//! neighbour contexts for the classes, LOCO-I-like prediction and error contexts for heights).
//! v3 is v4 without the cells' revisions (decoded as revision 0).
//!
//! Layout: `'T', 4`, postcard header (index, lattice, version), range-coded cells, CRC-32 of
//! everything before it (little endian). One routine, [`code_cells`], describes the format for
//! both directions. Passes in raster order:
//! 1. known or unknown, for every cell;
//! 2. obstacle or not, for known cells (the whole known mask is context by now);
//! 3. inflated or traversable, for the other known cells, in the context of the distance to the
//!    nearest obstacle cell of the tile: inflation is a function of that distance, so the rings
//!    cost almost nothing except where the obstacle lies in the next tile;
//! 4. per known cell: the cost (predicted from the class and that distance: the codec learns
//!    the mapper's cost-of-distance function as it goes, so it needs no mapper parameters; else
//!    the west or south neighbour's), the height (residual of the west/south mean in contexts
//!    of local activity and of the neighbours' residuals), the evidence (3 bits in the context
//!    of two neighbours'), and the stamp ("same as a neighbour" flags in the context of the
//!    neighbours' agreement, else a residual) followed by its revision (v4 only: zero or not in
//!    the context of the west and south neighbours' revisions, else its magnitude).

use super::range_coder::{prob, BitCoder, Decoder, Encoder, Prob, ResidualModel, TreeModel};
use super::{
    wire_cell, Cell, CellState, Lattice, Tile, TileCodecError, TileIndex, MAX_TILE_CELLS,
    TILE_MAGIC, WIRE_HEIGHT_STEP_CM, WIRE_HITS_MAX, WIRE_STAMP_STEP_S,
};
use serde::{Deserialize, Serialize};

/// Codec version written by [`encode`].
pub const VERSION: u8 = 4;
/// The previous version: the same coding without the cells' revisions.
pub const VERSION_V3: u8 = 3;

/// Cells within this many cells of an obstacle cell get a distance key; farther ones share one.
const DIST_RADIUS: i64 = 8;
const FAR_KEY: usize = (DIST_RADIUS * DIST_RADIUS) as usize + 1;
const OBSTACLE_KEY: usize = FAR_KEY + 1;
const INFLATED_KEY: usize = FAR_KEY + 2;
const COST_KEYS: usize = FAR_KEY + 3;
const STAMP_CANDS: usize = 4;

#[derive(Serialize, Deserialize)]
struct Header {
    tx: i32,
    ty: i32,
    cell_size_m: f32,
    tile_cells: u16,
    version: u64,
}

/// Every adaptive probability of one tile's coding; encoder and decoder evolve identical copies.
struct Models {
    known: Vec<Prob>,
    obstacle: Vec<Prob>,
    inflated: Vec<Prob>,
    /// [class][candidate]: whether the cost equals the candidate.
    cost_hit: [[Prob; 3]; 4],
    cost_raw: Vec<TreeModel>,
    /// Last cost seen per distance key: the learnt cost-of-distance function.
    cost_of_key: [Option<u8>; COST_KEYS],
    heights: Vec<ResidualModel>,
    hits: Vec<TreeModel>,
    stamp_first: TreeModel,
    stamp_same: Vec<Prob>,
    stamps: Vec<ResidualModel>,
    /// [west's revision zero, non-zero or absent][same for the south]: the revision (v4).
    revs: Vec<ResidualModel>,
}

impl Models {
    fn new() -> Self {
        Self {
            known: vec![prob(); 64],
            obstacle: vec![prob(); 81 * 3],
            inflated: vec![prob(); (FAR_KEY + 1) * 9],
            cost_hit: [[prob(); 3]; 4],
            cost_raw: vec![TreeModel::new(8); 4],
            cost_of_key: [None; COST_KEYS],
            heights: vec![ResidualModel::default(); 216],
            hits: vec![TreeModel::new(3); 81],
            stamp_first: TreeModel::new(8),
            stamp_same: vec![prob(); 32 * STAMP_CANDS],
            stamps: vec![ResidualModel::default(); 2],
            revs: vec![ResidualModel::default(); 9],
        }
    }
}

/// The wire values of one known cell, in wire steps.
#[derive(Clone, Copy, Default)]
struct Wire {
    cost: u8,
    h: i64,
    /// The height residual coded for this cell (context for its neighbours).
    h_err: i64,
    hits: u8,
    q: i64,
    rev: u16,
}

fn to_wire(c: &Cell) -> Wire {
    let w = wire_cell(c);
    Wire {
        cost: w.cost,
        h: i64::from(w.height_cm / WIRE_HEIGHT_STEP_CM),
        h_err: 0,
        hits: w.hits,
        q: i64::from(w.stamp_s / WIRE_STAMP_STEP_S),
        rev: w.rev,
    }
}

/// The tile being coded or decoded, in raster order.
struct Raster {
    n: i64,
    states: Vec<CellState>,
    wire: Vec<Option<Wire>>,
}

impl Raster {
    fn idx(&self, col: i64, row: i64) -> Option<usize> {
        (col >= 0 && row >= 0 && col < self.n && row < self.n)
            .then(|| (row * self.n + col) as usize)
    }

    fn state(&self, col: i64, row: i64) -> CellState {
        self.idx(col, row)
            .map_or(CellState::Unknown, |i| self.states[i])
    }

    fn wire(&self, col: i64, row: i64) -> Option<Wire> {
        self.idx(col, row).and_then(|i| self.wire[i])
    }

    fn known(&self, col: i64, row: i64) -> bool {
        self.state(col, row) != CellState::Unknown
    }

    /// Squared distance (cells) from every cell to the nearest obstacle cell, capped.
    fn obstacle_distances(&self) -> Vec<usize> {
        let n = self.n;
        let mut dist2 = vec![FAR_KEY; self.states.len()];
        for (i, s) in self.states.iter().enumerate() {
            if *s != CellState::Obstacle {
                continue;
            }
            let (c, r) = (i as i64 % n, i as i64 / n);
            for dr in -DIST_RADIUS..=DIST_RADIUS {
                for dc in -DIST_RADIUS..=DIST_RADIUS {
                    let d2 = (dc * dc + dr * dr) as usize;
                    if let (true, Some(j)) = (d2 < FAR_KEY, self.idx(c + dc, r + dr)) {
                        dist2[j] = dist2[j].min(d2);
                    }
                }
            }
        }
        dist2
    }
}

/// Codes the cells of an `n` x `n` tile: from `input` when encoding (which must hold wire
/// values), into the returned cells when decoding (`input` None). `revs`: the cells' revisions
/// are coded (v4; without, they are left out and decode as 0). The error says what a decoded
/// stream got wrong.
fn code_cells<C: BitCoder>(
    c: &mut C,
    n: usize,
    input: Option<&[Cell]>,
    revs: bool,
) -> Result<Vec<Cell>, &'static str> {
    let mut m = Models::new();
    let mut ras = Raster {
        n: n as i64,
        states: vec![CellState::Unknown; n * n],
        wire: vec![None; n * n],
    };
    let given = |i: usize| input.map_or(Cell::UNKNOWN, |cells| cells[i]);
    let pos = |i: usize| ((i % n) as i64, (i / n) as i64);
    // 1. Known mask. Known cells are marked Traversable until pass 2 and 3 refine them.
    c.field(0);
    for i in 0..n * n {
        let (x, y) = pos(i);
        let ctx = [(-1, 0), (0, -1), (-1, -1), (1, -1), (-2, 0), (0, -2)]
            .iter()
            .enumerate()
            .fold(0, |a, (k, (dx, dy))| {
                a | usize::from(ras.known(x + dx, y + dy)) << k
            });
        if c.code_bit(&mut m.known[ctx], given(i).state != CellState::Unknown) {
            ras.states[i] = CellState::Traversable;
        }
    }
    // 2. Obstacles among the known cells.
    c.field(1);
    let mut obstacle = vec![false; n * n];
    for i in 0..n * n {
        if ras.states[i] == CellState::Unknown {
            continue;
        }
        let (x, y) = pos(i);
        let class = |dx: i64, dy: i64| -> usize {
            match ras.idx(x + dx, y + dy) {
                Some(j) if ras.states[j] != CellState::Unknown => 1 + usize::from(obstacle[j]),
                _ => 0,
            }
        };
        let unknown_around = [
            (-1, 0),
            (1, 0),
            (0, -1),
            (0, 1),
            (-1, -1),
            (1, -1),
            (-1, 1),
            (1, 1),
        ]
        .iter()
        .filter(|(dx, dy)| !ras.known(x + dx, y + dy))
        .count();
        let ctx = ((class(-1, 0) * 3 + class(0, -1)) * 3 + class(-1, -1)) * 3 + class(1, -1);
        let ctx = ctx * 3 + unknown_around.min(2);
        obstacle[i] = c.code_bit(&mut m.obstacle[ctx], given(i).state == CellState::Obstacle);
        if obstacle[i] {
            ras.states[i] = CellState::Obstacle;
        }
    }
    // 3. Inflated or traversable, by distance to the nearest obstacle.
    c.field(2);
    let dist2 = ras.obstacle_distances();
    for (i, d2) in dist2.iter().enumerate() {
        if ras.states[i] != CellState::Traversable {
            continue;
        }
        let (x, y) = pos(i);
        let near = |dx: i64, dy: i64| match ras.state(x + dx, y + dy) {
            CellState::Inflated => 1,
            CellState::Traversable => 0,
            _ => 2,
        };
        let ctx = d2 * 9 + near(-1, 0) * 3 + near(0, -1);
        if c.code_bit(&mut m.inflated[ctx], given(i).state == CellState::Inflated) {
            ras.states[i] = CellState::Inflated;
        }
    }
    // 4. Values of the known cells.
    let h_max = i64::from(i16::MAX / WIRE_HEIGHT_STEP_CM);
    let h_min = i64::from(i16::MIN / WIRE_HEIGHT_STEP_CM);
    let q_max = i64::from(u32::MAX / WIRE_STAMP_STEP_S);
    let (mut last_h, mut last_q) = (None, None);
    let mut out = vec![Cell::UNKNOWN; n * n];
    for i in 0..n * n {
        let state = ras.states[i];
        if state == CellState::Unknown {
            continue;
        }
        let v_in = input.map_or(Wire::default(), |cells| to_wire(&cells[i]));
        let (x, y) = pos(i);
        let (w, s, sw, se) = (
            ras.wire(x - 1, y),
            ras.wire(x, y - 1),
            ras.wire(x - 1, y - 1),
            ras.wire(x + 1, y - 1),
        );
        // Cost: the first candidate that matches, else the value.
        c.field(3);
        let key = match state {
            CellState::Obstacle => OBSTACLE_KEY,
            CellState::Inflated => INFLATED_KEY,
            _ => dist2[i],
        };
        let class = match key {
            OBSTACLE_KEY => 0,
            INFLATED_KEY => 1,
            FAR_KEY => 2,
            _ => 3,
        };
        let mut cands = [m.cost_of_key[key], w.map(|x| x.cost), s.map(|x| x.cost)];
        for k in 1..3 {
            if cands[..k].contains(&cands[k]) {
                cands[k] = None;
            }
        }
        let mut cost = None;
        for (k, cand) in cands.iter().enumerate() {
            let Some(cand) = cand else { continue };
            if c.code_bit(&mut m.cost_hit[class][k], *cand == v_in.cost) {
                cost = Some(*cand);
                break;
            }
        }
        let cost = cost.unwrap_or_else(|| m.cost_raw[class].code(c, u32::from(v_in.cost)) as u8);
        m.cost_of_key[key] = Some(cost);
        // Height: the mean of the west and south neighbours (on grass it beats the median
        // predictor: the noise is in the flooring, not in edges); contexts of local activity,
        // of the neighbours' residual sizes and of their sign (flooring jitter leans).
        c.field(4);
        let hv = |x: Option<Wire>| x.map(|x| x.h);
        let (hw, hs, hsw, hse) = (hv(w), hv(s), hv(sw), hv(se));
        let (pred, full) = match (hw, hs) {
            (Some(a), Some(b)) => ((a + b).div_euclid(2), hsw.is_some()),
            _ => (hw.or(hs).or(hse).or(hsw).or(last_h).unwrap_or(0), false),
        };
        let diff = |a: Option<i64>, b: Option<i64>| a.zip(b).map_or(0, |(a, b)| (a - b).abs());
        let act = match diff(hw, hsw) + diff(hs, hsw) + diff(hs, hse) {
            0 => 0,
            1 => 1,
            2 => 2,
            3..=5 => 3,
            6..=12 => 4,
            _ => 5,
        };
        let err = w.map_or(0, |x| x.h_err.abs()) + s.map_or(0, |x| x.h_err.abs());
        let lean = (w.map_or(0, |x| x.h_err) + s.map_or(0, |x| x.h_err)).signum() + 1;
        let ctx = (((act * 2 + usize::from(state == CellState::Obstacle)) * 2 + usize::from(full))
            * 3
            + (err as usize).min(2))
            * 3
            + lean as usize;
        let h_err = m.heights[ctx].code(c, v_in.h - pred);
        let h = pred + h_err;
        if !(h_min..=h_max).contains(&h) {
            return Err("height out of range");
        }
        // Evidence.
        c.field(5);
        let hb = |x: Option<Wire>| x.map_or(8, |x| usize::from(x.hits.min(7)));
        let hits = m.hits[hb(w) * 9 + hb(s)].code(c, u32::from(v_in.hits)) as u8;
        if hits > WIRE_HITS_MAX {
            return Err("evidence above the wire's saturation");
        }
        // Stamp: distinct neighbour values are the candidates.
        c.field(6);
        let q = code_stamp(c, &mut m, [w, s, se, sw], last_q, v_in.q);
        if !(0..=q_max).contains(&q) {
            return Err("stamp out of range");
        }
        let rev = if revs {
            let rb = |x: Option<Wire>| x.map_or(2, |x| usize::from(x.rev != 0));
            let r = m.revs[rb(w) * 3 + rb(s)].code(c, i64::from(v_in.rev));
            u16::try_from(r).map_err(|_| "revision out of range")?
        } else {
            0
        };
        last_h = Some(h);
        last_q = Some(q);
        ras.wire[i] = Some(Wire {
            cost,
            h,
            h_err,
            hits,
            q,
            rev,
        });
        out[i] = Cell {
            state,
            cost,
            height_cm: (h * i64::from(WIRE_HEIGHT_STEP_CM)) as i16,
            hits,
            stamp_s: (q * i64::from(WIRE_STAMP_STEP_S)) as u32,
            rev,
        };
    }
    Ok(out)
}

fn code_stamp<C: BitCoder>(
    c: &mut C,
    m: &mut Models,
    near: [Option<Wire>; 4],
    last: Option<i64>,
    q_in: i64,
) -> i64 {
    let q = near.map(|x| x.map(|x| x.q));
    let mut cands = [0i64; STAMP_CANDS];
    let mut len = 0;
    for v in q.iter().flatten().chain(last.iter()) {
        if len < STAMP_CANDS && !cands[..len].contains(v) {
            cands[len] = *v;
            len += 1;
        }
    }
    let cands = &cands[..len];
    let Some(&base) = cands.first() else {
        // The tile's first stamp: 32 bits, the top byte modelled (it rarely changes).
        let hi = m.stamp_first.code(c, (q_in >> 24) as u32 & 0xFF);
        let lo = c.code_direct(q_in as u32 & 0xFF_FFFF, 24);
        return (i64::from(hi) << 24) | i64::from(lo);
    };
    // Which neighbours agree: (W == S, S == SE, W == SW, W present, S present).
    let eq = |a: usize, b: usize| q[a].is_some() && q[a] == q[b];
    let pattern = usize::from(eq(0, 1))
        | usize::from(eq(1, 2)) << 1
        | usize::from(eq(0, 3)) << 2
        | usize::from(q[0].is_some()) << 3
        | usize::from(q[1].is_some()) << 4;
    for (k, cand) in cands.iter().enumerate() {
        if c.code_bit(&mut m.stamp_same[pattern * STAMP_CANDS + k], *cand == q_in) {
            return *cand;
        }
    }
    base + m.stamps[usize::from(eq(0, 1))].code(c, q_in - base)
}

/// The ideal cost of each field of a tile, bytes: known mask, obstacles, inflation, costs,
/// heights, evidence, stamps.
pub fn field_bytes(tile: &Tile) -> [f64; 7] {
    let mut meter = super::range_coder::Meter::default();
    let _ = code_cells(
        &mut meter,
        tile.lattice.tile_cells as usize,
        Some(&tile.cells),
        true,
    );
    std::array::from_fn(|k| meter.bits[k] / 8.0)
}

/// Encodes a tile (its wire cells, see [`super::wire_tile`]).
pub fn encode(tile: &Tile) -> Vec<u8> {
    encode_version(tile, VERSION)
}

/// Encodes a tile as codec `version` ([`VERSION`] or [`VERSION_V3`]).
pub fn encode_version(tile: &Tile, version: u8) -> Vec<u8> {
    let n = tile.lattice.tile_cells as usize;
    let mut out = vec![TILE_MAGIC, version];
    let header = Header {
        tx: tile.index.tx,
        ty: tile.index.ty,
        cell_size_m: tile.lattice.cell_size_m,
        tile_cells: tile.lattice.tile_cells,
        version: tile.version,
    };
    out.extend(postcard::to_allocvec(&header).expect("tile header always encodes"));
    let mut e = Encoder::new();
    code_cells(&mut e, n, Some(&tile.cells), version != VERSION_V3)
        .expect("wire values always encode");
    out.extend(e.finish());
    let crc = crc32fast::hash(&out);
    out.extend(crc.to_le_bytes());
    out
}

/// Decodes a v4 or v3 tile (`bytes` starts with the magic and version).
pub fn decode(bytes: &[u8]) -> Result<Tile, TileCodecError> {
    let bad = |m: &str| Err(TileCodecError::Malformed(m.to_string()));
    if bytes.len() < 2 + 4 {
        return bad("too short");
    }
    let (body, crc) = bytes.split_at(bytes.len() - 4);
    if crc32fast::hash(body).to_le_bytes() != crc {
        return Err(TileCodecError::Checksum);
    }
    let (h, coded): (Header, &[u8]) = postcard::take_from_bytes(&body[2..])
        .map_err(|e| TileCodecError::Malformed(e.to_string()))?;
    if h.tile_cells == 0 || h.tile_cells > MAX_TILE_CELLS {
        return bad("tile size out of range");
    }
    if !(h.cell_size_m.is_finite() && h.cell_size_m > 0.0) {
        return bad("cell size not positive");
    }
    let mut d = Decoder::new(coded);
    let cells = code_cells(&mut d, h.tile_cells as usize, None, bytes[1] != VERSION_V3)
        .map_err(|e| TileCodecError::Malformed(e.to_string()))?;
    Ok(Tile {
        index: TileIndex { tx: h.tx, ty: h.ty },
        lattice: Lattice {
            cell_size_m: h.cell_size_m,
            tile_cells: h.tile_cells,
        },
        version: h.version,
        cells,
    })
}
