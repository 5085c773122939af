//! A set of lattice cells over their bounding box, grown by a square neighbourhood: which cells
//! of a rebuilt map a correction touched ([`super::rebuild::SweepStore::stale_cells`]).

/// Cells of the lattice (global indices), dense over their bounding box.
#[derive(Clone, Debug, Default)]
pub struct CellMask {
    cx0: i64,
    cy0: i64,
    w: usize,
    h: usize,
    bits: Vec<bool>,
    len: usize,
}

impl CellMask {
    /// The cells within `grow` cells (Chebyshev distance) of some cell of `cells`; None when
    /// their bounding box would hold more than `max_cells` cells (the caller takes every cell
    /// then).
    pub fn grown(cells: &[(i64, i64)], grow: i64, max_cells: usize) -> Option<Self> {
        let Some(&(x, y)) = cells.first() else {
            return Some(Self::default());
        };
        let grow = grow.max(0);
        let (mut x0, mut y0, mut x1, mut y1) = (x, y, x, y);
        for &(cx, cy) in cells {
            x0 = x0.min(cx);
            y0 = y0.min(cy);
            x1 = x1.max(cx);
            y1 = y1.max(cy);
        }
        let (cx0, cy0) = (x0 - grow, y0 - grow);
        let w = usize::try_from(x1 + grow - cx0 + 1).ok()?;
        let h = usize::try_from(y1 + grow - cy0 + 1).ok()?;
        if w.checked_mul(h)? > max_cells {
            return None;
        }
        let mut seed = vec![false; w * h];
        for &(cx, cy) in cells {
            seed[(cy - cy0) as usize * w + (cx - cx0) as usize] = true;
        }
        // A square grows as a run along the rows, then along the columns.
        let g = grow as usize;
        let mut rows = vec![false; w * h];
        for r in 0..h {
            dilate_line(&seed[r * w..(r + 1) * w], &mut rows[r * w..(r + 1) * w], g);
        }
        let mut bits = vec![false; w * h];
        let mut column = vec![false; h];
        let mut out = vec![false; h];
        for c in 0..w {
            for r in 0..h {
                column[r] = rows[r * w + c];
            }
            dilate_line(&column, &mut out, g);
            for r in 0..h {
                bits[r * w + c] = out[r];
            }
        }
        let len = bits.iter().filter(|&&b| b).count();
        Some(Self {
            cx0,
            cy0,
            w,
            h,
            bits,
            len,
        })
    }

    /// The cell is in the set.
    pub fn contains(&self, cx: i64, cy: i64) -> bool {
        let (dx, dy) = (cx - self.cx0, cy - self.cy0);
        if dx < 0 || dy < 0 || dx as usize >= self.w || dy as usize >= self.h {
            return false;
        }
        self.bits[dy as usize * self.w + dx as usize]
    }

    /// Cells in the set.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No cell in the set.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// `out[i]`: some `line[j]` with |i - j| <= `g` is set (a running count over the window).
fn dilate_line(line: &[bool], out: &mut [bool], g: usize) {
    let n = line.len();
    let mut count = 0usize;
    // The window of i is [i - g, i + g]; start with [0, g).
    for &b in line.iter().take(g.min(n)) {
        count += usize::from(b);
    }
    for i in 0..n {
        if i + g < n {
            count += usize::from(line[i + g]);
        }
        if i > g {
            count -= usize::from(line[i - g - 1]);
        }
        out[i] = count > 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grown_mask_is_the_chebyshev_neighbourhood_of_its_cells() {
        let cells = [(-3, 5), (10, 5), (10, 6)];
        let m = CellMask::grown(&cells, 2, 1 << 20).unwrap();
        for cy in -10..20 {
            for cx in -10..20 {
                let want = cells
                    .iter()
                    .any(|&(x, y)| (cx - x).abs() <= 2 && (cy - y).abs() <= 2);
                assert_eq!(m.contains(cx, cy), want, "({cx}, {cy})");
            }
        }
        assert_eq!(m.len(), 25 + 30);
        assert!(CellMask::grown(&[], 3, 10).unwrap().is_empty());
        // Too large a box is refused, not allocated.
        assert!(CellMask::grown(&[(0, 0), (100_000, 100_000)], 0, 1 << 20).is_none());
    }
}
