//! Top-down PNG of the grid: states drawn over a shaded height field.

use crate::mapper::Mapper;
use common::grid::CellState;
use std::io::Write;

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// Nothing to draw.
    #[error("the map is empty")]
    Empty,
    /// PNG encoding or writing failed.
    #[error("png: {0}")]
    Png(#[from] png::EncodingError),
}

/// A window of the lattice to draw: global cell bounds, inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderWindow {
    /// Lowest column.
    pub min_cx: i64,
    /// Lowest row.
    pub min_cy: i64,
    /// Highest column.
    pub max_cx: i64,
    /// Highest row.
    pub max_cy: i64,
}

/// Colours: traversable green, inflated orange, obstacle red, unknown dark grey, each shaded by
/// the height (brighter = higher) and by a hillshade so curbs and slopes show.
pub fn render_png(
    mapper: &Mapper,
    window: Option<RenderWindow>,
    px_per_cell: u32,
    path_m: &[(f64, f64)],
    out: impl Write,
) -> Result<(u32, u32), RenderError> {
    let w = match window {
        Some(w) => w,
        None => {
            let ((x0, y0), (x1, y1)) = mapper.bounds().ok_or(RenderError::Empty)?;
            RenderWindow {
                min_cx: x0,
                min_cy: y0,
                max_cx: x1,
                max_cy: y1,
            }
        }
    };
    let (cw, ch) = (
        (w.max_cx - w.min_cx + 1).max(1) as u32,
        (w.max_cy - w.min_cy + 1).max(1) as u32,
    );
    let s = px_per_cell.clamp(1, 16);
    let (pw, ph) = (cw * s, ch * s);
    // Height range over known cells for the shading.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for cy in w.min_cy..=w.max_cy {
        for cx in w.min_cx..=w.max_cx {
            if let Some(h) = mapper.height_m(cx, cy) {
                lo = lo.min(h);
                hi = hi.max(h);
            }
        }
    }
    let span = if hi > lo { hi - lo } else { 1.0 };
    let l = f64::from(mapper.lattice().cell_size_m);
    let mut rgb = vec![0u8; (pw * ph * 3) as usize];
    for row in 0..ch {
        let cy = w.max_cy - i64::from(row); // north up
        for col in 0..cw {
            let cx = w.min_cx + i64::from(col);
            let cell = mapper.cell(cx, cy);
            let h = mapper.height_m(cx, cy);
            let shade = h.map(|h| 0.55 + 0.45 * (h - lo) / span).unwrap_or(0.5);
            // Hillshade from the north-west: light falls on faces rising towards it.
            let hill = match (h, mapper.height_m(cx - 1, cy), mapper.height_m(cx, cy + 1)) {
                (Some(h), Some(hw), Some(hn)) => {
                    (1.0 + ((h - hw) - (hn - h)) / l * 0.8).clamp(0.6, 1.4)
                }
                _ => 1.0,
            };
            let base: [f64; 3] = match cell.state {
                CellState::Traversable => [70.0, 200.0, 80.0],
                CellState::Inflated => [240.0, 160.0, 40.0],
                CellState::Obstacle => [220.0, 30.0, 30.0],
                CellState::Unknown if h.is_some() => [110.0, 110.0, 150.0],
                CellState::Unknown => [35.0, 35.0, 35.0],
            };
            let k = if cell.state == CellState::Unknown && h.is_none() {
                1.0
            } else {
                shade * hill
            };
            let c = base.map(|v| (v * k).clamp(0.0, 255.0) as u8);
            for yy in 0..s {
                for xx in 0..s {
                    let i = (((row * s + yy) * pw + col * s + xx) * 3) as usize;
                    rgb[i..i + 3].copy_from_slice(&c);
                }
            }
        }
    }
    for &(x, y) in path_m {
        let (cx, cy) = mapper.lattice().cell_of(x, y);
        if cx < w.min_cx || cx > w.max_cx || cy < w.min_cy || cy > w.max_cy {
            continue;
        }
        let (col, row) = ((cx - w.min_cx) as u32, (w.max_cy - cy) as u32);
        for yy in 0..s {
            for xx in 0..s {
                let i = (((row * s + yy) * pw + col * s + xx) * 3) as usize;
                rgb[i..i + 3].copy_from_slice(&[40, 90, 255]);
            }
        }
    }
    let mut enc = png::Encoder::new(out, pw, ph);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header()?;
    wr.write_image_data(&rgb)?;
    wr.finish()?;
    Ok((pw, ph))
}
