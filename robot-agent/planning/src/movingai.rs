//! Moving AI grid benchmark files (Sturtevant): `.map` grids and `.scen` scenario lists.
//!
//! `.map`: `type octile`, `height H`, `width W`, `map`, then H rows of W characters; `.` and `G`
//! are free, everything else (`@ O T S W`) blocked. `.scen`: `version 1`, then tab- or
//! space-separated `bucket map width height start_x start_y goal_x goal_y optimal_length`.
//! x is the column, y the row counted from the top. CRLF line endings are accepted.
//!
//! The grid built from a map has cell size 1 and puts file row y in grid row y (the file's
//! top-down order is kept: only lengths matter for the benchmark).

use std::path::Path;

use crate::grid::{CellXY, PlanGrid};

/// What went wrong reading a Moving AI file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MovingAiError {
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The header is missing or malformed.
    #[error("bad header: {0}")]
    Header(String),
    /// The grid rows do not match the header's size.
    #[error("grid row {row}: {reason}")]
    Row {
        /// Row, 0 = top.
        row: usize,
        /// What is wrong.
        reason: String,
    },
    /// A scenario line cannot be parsed.
    #[error("scenario line {line}: {reason}")]
    Scenario {
        /// Line number, 1-based.
        line: usize,
        /// What is wrong.
        reason: String,
    },
}

/// A parsed `.map` file.
#[derive(Clone, Debug, PartialEq)]
pub struct MovingAiMap {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width * height` flags, row-major from the top row: true = free.
    pub free: Vec<bool>,
}

impl MovingAiMap {
    /// Whether column x, row y (from the top) is free; false outside.
    pub fn is_free(&self, x: i64, y: i64) -> bool {
        x >= 0
            && y >= 0
            && x < i64::from(self.width)
            && y < i64::from(self.height)
            && self.free[(y * i64::from(self.width) + x) as usize]
    }

    /// The planning grid: cell size 1, zero penalties, file row y = grid row y.
    pub fn to_grid(&self) -> PlanGrid {
        let mut g = PlanGrid::new(self.width, self.height, 1.0, (0.0, 0.0));
        for y in 0..i64::from(self.height) {
            for x in 0..i64::from(self.width) {
                if !self.is_free(x, y) {
                    g.set_blocked(x, y);
                }
            }
        }
        g
    }
}

/// One scenario of a `.scen` file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// Difficulty bucket.
    pub bucket: u32,
    /// Start cell (column, row from the top).
    pub start: CellXY,
    /// Goal cell.
    pub goal: CellXY,
    /// Optimal 8-connected length without corner cutting.
    pub optimal_length: f64,
}

/// Parses the text of a `.map` file.
pub fn parse_map(text: &str) -> Result<MovingAiMap, MovingAiError> {
    let mut lines = text.lines().map(|l| l.trim_end_matches('\r'));
    let mut width = None;
    let mut height = None;
    for line in lines.by_ref() {
        let mut parts = line.split_whitespace();
        match (parts.next(), parts.next()) {
            (Some("type"), _) => {}
            (Some("height"), Some(v)) => height = v.parse::<u32>().ok(),
            (Some("width"), Some(v)) => width = v.parse::<u32>().ok(),
            (Some("map"), None) => break,
            (None, _) => {}
            _ => return Err(MovingAiError::Header(format!("unexpected line {line:?}"))),
        }
    }
    let (Some(width), Some(height)) = (width, height) else {
        return Err(MovingAiError::Header(
            "missing width or height before `map`".into(),
        ));
    };
    let mut free = Vec::with_capacity(width as usize * height as usize);
    for row in 0..height as usize {
        let line = lines.next().ok_or_else(|| MovingAiError::Row {
            row,
            reason: "missing".into(),
        })?;
        let bytes = line.as_bytes();
        if bytes.len() < width as usize {
            return Err(MovingAiError::Row {
                row,
                reason: format!("{} characters, expected {width}", bytes.len()),
            });
        }
        free.extend(
            bytes[..width as usize]
                .iter()
                .map(|&b| b == b'.' || b == b'G'),
        );
    }
    Ok(MovingAiMap {
        width,
        height,
        free,
    })
}

/// Parses the text of a `.scen` file.
pub fn parse_scen(text: &str) -> Result<Vec<Scenario>, MovingAiError> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() || line.starts_with("version") {
            continue;
        }
        let bad = |reason: &str| MovingAiError::Scenario {
            line: n + 1,
            reason: reason.to_string(),
        };
        // The map name may in principle hold spaces; the numbers are the last 7 fields.
        let fields: Vec<&str> = line.split(['\t', ' ']).filter(|f| !f.is_empty()).collect();
        if fields.len() < 9 {
            return Err(bad("expected 9 fields"));
        }
        let k = fields.len();
        let int = |s: &str| {
            s.parse::<u32>()
                .map_err(|_| bad(&format!("not an integer: {s:?}")))
        };
        let optimal_length = fields[k - 1]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| bad("bad optimal length"))?;
        out.push(Scenario {
            bucket: int(fields[0])?,
            start: CellXY::new(int(fields[k - 5])?, int(fields[k - 4])?),
            goal: CellXY::new(int(fields[k - 3])?, int(fields[k - 2])?),
            optimal_length,
        });
    }
    Ok(out)
}

/// Reads and parses a `.map` file.
pub fn load_map(path: &Path) -> Result<MovingAiMap, MovingAiError> {
    parse_map(&read(path)?)
}

/// Reads and parses a `.scen` file.
pub fn load_scen(path: &Path) -> Result<Vec<Scenario>, MovingAiError> {
    parse_scen(&read(path)?)
}

fn read(path: &Path) -> Result<String, MovingAiError> {
    std::fs::read_to_string(path).map_err(|source| MovingAiError::Io {
        path: path.display().to_string(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::astar::Planner;

    #[test]
    fn parses_crlf_and_symbols() {
        let text = "type octile\r\nheight 2\r\nwidth 3\r\nmap\r\n.G@\r\nTS.\r\n";
        let m = parse_map(text).unwrap();
        assert_eq!((m.width, m.height), (3, 2));
        assert_eq!(m.free, vec![true, true, false, false, false, true]);
        assert!(parse_map("type octile\nheight 3\nwidth 3\nmap\n...\n...\n").is_err());
        assert!(parse_map("type octile\nmap\n...\n").is_err());
    }

    #[test]
    fn parses_scenarios() {
        let text = "version 1\r\n0\tx.map\t37\t37\t11\t23\t8\t23\t3.00000000\r\n1\tx.map\t37\t37\t1\t2\t3\t4\t2.5\n";
        let s = parse_scen(text).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].start, CellXY::new(11, 23));
        assert_eq!(s[1].goal, CellXY::new(3, 4));
        assert!((s[1].optimal_length - 2.5).abs() < 1e-12);
        assert!(parse_scen("version 1\n0\tx.map\t1\t2\n").is_err());
    }

    #[test]
    fn real_maps_first_scenarios_are_exact() {
        let Some(dir) = common::shared_data::locate(
            env!("CARGO_MANIFEST_DIR"),
            "movingai",
            "real_maps_first_scenarios_are_exact",
        ) else {
            return;
        };
        let mut maps: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "map"))
            .collect();
        maps.sort();
        assert!(!maps.is_empty());
        let mut planner = Planner::new();
        for map_path in maps {
            let map = load_map(&map_path).unwrap();
            let grid = map.to_grid();
            let scen_path = map_path.with_extension("map.scen");
            let scens = load_scen(&scen_path).unwrap();
            for s in scens.iter().take(200) {
                let path = planner.plan(&grid, s.start, s.goal).unwrap();
                assert!(
                    (path.length_m - s.optimal_length).abs() < 1e-5,
                    "{}: {:?} got {} want {}",
                    map_path.display(),
                    s,
                    path.length_m,
                    s.optimal_length
                );
            }
        }
    }
}
