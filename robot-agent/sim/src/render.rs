//! Top-down PNG of a world: hill-shaded height field, truth labels and the scenario's routes.

use crate::labels::{LabelParams, TruthGrid};
use crate::scenario::Scenario;
use crate::world::World;
use common::grid::{CellState, Lattice};

/// What to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Metres per pixel.
    pub m_per_px: f64,
    /// Tint cells by their truth label (green traversable, red obstacle).
    pub labels: bool,
    /// Lattice cell size for the labels, metres.
    pub cell_size_m: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            m_per_px: 0.1,
            labels: true,
            cell_size_m: 0.2,
        }
    }
}

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The image would be empty or absurdly large.
    #[error("image size {0} x {1} px is out of range (1..=8000)")]
    Size(usize, usize),
    /// PNG encoding failed.
    #[error("png: {0}")]
    Png(#[from] png::EncodingError),
}

/// Renders the world of `scenario` as PNG bytes.
pub fn render_png(
    scenario: &Scenario,
    world: &World,
    labels: &LabelParams,
    opt: &RenderOptions,
) -> Result<Vec<u8>, RenderError> {
    let e = &scenario.extent;
    let s = opt.m_per_px;
    let w = ((e.x_max_m - e.x_min_m) / s).floor() as usize;
    let h = ((e.y_max_m - e.y_min_m) / s).floor() as usize;
    if w == 0 || h == 0 || w > 8000 || h > 8000 {
        return Err(RenderError::Size(w, h));
    }
    let lattice = Lattice {
        cell_size_m: opt.cell_size_m,
        tile_cells: 64,
    };
    let truth: Option<TruthGrid> = opt.labels.then(|| {
        let (cx0, cy0) = lattice.cell_of(e.x_min_m, e.y_min_m);
        let (cx1, cy1) = lattice.cell_of(e.x_max_m, e.y_max_m);
        world.truth_labels(
            &lattice,
            cx0,
            cy0,
            (cx1 - cx0 + 1) as usize,
            (cy1 - cy0 + 1) as usize,
            labels,
        )
    });
    let (mut hmin, mut hmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let (_, _, nx, ny) = world.ground.grid();
    for j in (0..ny).step_by(8) {
        for i in (0..nx).step_by(8) {
            let v = world.ground.vertex(i, j);
            hmin = hmin.min(v);
            hmax = hmax.max(v);
        }
    }
    let span = (hmax - hmin).max(0.1);
    let mut rgb = vec![0u8; w * h * 3];
    for py in 0..h {
        let y = e.y_max_m - (py as f64 + 0.5) * s;
        for px in 0..w {
            let x = e.x_min_m + (px as f64 + 0.5) * s;
            let z = world.ground_height(x, y).unwrap_or(hmin);
            let zx = world.ground_height(x + s, y).unwrap_or(z)
                - world.ground_height(x - s, y).unwrap_or(z);
            let zy = world.ground_height(x, y + s).unwrap_or(z)
                - world.ground_height(x, y - s).unwrap_or(z);
            // Light from the north-west, 45 deg up.
            let n = nalgebra::Vector3::new(-zx / (2.0 * s), -zy / (2.0 * s), 1.0).normalize();
            let shade = n
                .dot(&nalgebra::Vector3::new(-0.5, 0.5, 0.707).normalize())
                .clamp(0.0, 1.0);
            let base = 60.0 + 140.0 * (z - hmin) / span;
            let g = (base * (0.55 + 0.6 * shade)).clamp(0.0, 255.0);
            let mut c = [g, g, g];
            if let Some(t) = &truth {
                if let Some(cell) = t.at(x, y) {
                    let tint = match cell.state {
                        CellState::Traversable => Some(([70.0, 200.0, 90.0], 0.3)),
                        CellState::Obstacle => Some(([230.0, 40.0, 40.0], 0.7)),
                        _ => None,
                    };
                    if let Some((tc, a)) = tint {
                        for k in 0..3 {
                            c[k] = c[k] * (1.0 - a) + tc[k] * a;
                        }
                    }
                }
            }
            let o = (py * w + px) * 3;
            rgb[o] = c[0] as u8;
            rgb[o + 1] = c[1] as u8;
            rgb[o + 2] = c[2] as u8;
        }
    }
    let mut dot = |x: f64, y: f64, col: [u8; 3], r: i64| {
        let px = ((x - e.x_min_m) / s) as i64;
        let py = ((e.y_max_m - y) / s) as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                let (qx, qy) = (px + dx, py + dy);
                if qx >= 0 && qy >= 0 && (qx as usize) < w && (qy as usize) < h {
                    let o = (qy as usize * w + qx as usize) * 3;
                    rgb[o..o + 3].copy_from_slice(&col);
                }
            }
        }
    };
    let line = |pts: &[[f64; 2]], col: [u8; 3], dot: &mut dyn FnMut(f64, f64, [u8; 3], i64)| {
        for seg in pts.windows(2) {
            let l = (seg[1][0] - seg[0][0]).hypot(seg[1][1] - seg[0][1]);
            let n = (l / (0.5 * s)).ceil().max(1.0) as usize;
            for k in 0..=n {
                let f = k as f64 / n as f64;
                dot(
                    seg[0][0] + f * (seg[1][0] - seg[0][0]),
                    seg[0][1] + f * (seg[1][1] - seg[0][1]),
                    col,
                    0,
                );
            }
        }
    };
    for wk in &scenario.walker {
        line(&wk.points, [240, 200, 40], &mut dot);
    }
    for r in [&scenario.teach, &scenario.drive].into_iter().flatten() {
        line(&r.points, [40, 90, 240], &mut dot);
    }
    for st in &scenario.start {
        dot(st.x_m, st.y_m, [250, 250, 250], 4);
        dot(
            st.x_m + 0.8 * st.yaw_deg.to_radians().cos(),
            st.y_m + 0.8 * st.yaw_deg.to_radians().sin(),
            [250, 250, 250],
            2,
        );
    }
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header()?;
        wr.write_image_data(&rgb)?;
    }
    Ok(bytes)
}
