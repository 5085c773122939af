//! PCD v0.7 point-cloud files: read ascii and binary (fields x y z and, when present, intensity,
//! ring/channel and a per-point time), write binary `x y z intensity ring t`.

use crate::cloud::Point;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// Why a PCD file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PcdError {
    /// The file could not be opened or read.
    #[error("reading {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The header is incomplete or inconsistent.
    #[error("bad PCD header: {0}")]
    Header(String),
    /// A data encoding this reader does not support (e.g. `binary_compressed`).
    #[error("unsupported PCD data encoding {0:?}")]
    Unsupported(String),
    /// The data section is shorter than the header promises or has unparsable values.
    #[error("bad PCD data: {0}")]
    Data(String),
}

#[derive(Debug, Clone)]
struct Field {
    name: String,
    size: usize,
    kind: u8,
    count: usize,
}

impl Field {
    fn bytes(&self) -> usize {
        self.size * self.count
    }
    /// First element of this field as f64 from little-endian bytes.
    fn read(&self, b: &[u8]) -> f64 {
        match (self.kind, self.size) {
            (b'F', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            (b'F', 8) => f64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])),
            (b'U', 1) => b[0] as f64,
            (b'U', 2) => u16::from_le_bytes([b[0], b[1]]) as f64,
            (b'U', 4) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            (b'U', 8) => u64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])) as f64,
            (b'I', 1) => b[0] as i8 as f64,
            (b'I', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
            (b'I', 4) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            (b'I', 8) => i64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])) as f64,
            _ => f64::NAN,
        }
    }
}

/// Which PCD field feeds which point attribute.
#[derive(Default)]
struct Mapping {
    x: Option<usize>,
    y: Option<usize>,
    z: Option<usize>,
    intensity: Option<usize>,
    ring: Option<usize>,
    time: Option<usize>,
}

/// A PCD file's points plus the raw values of every field (for fields the [`Point`] type lacks).
#[derive(Debug, Clone, Default)]
pub struct PcdCloud {
    /// The points.
    pub points: Vec<Point>,
    /// Field names in file order.
    pub field_names: Vec<String>,
    /// Per point, the first value of every field in file order.
    pub values: Vec<Vec<f64>>,
}

/// Reads a PCD file's points.
pub fn read_pcd(path: impl AsRef<Path>) -> Result<Vec<Point>, PcdError> {
    Ok(read_pcd_full(path)?.points)
}

/// Reads a PCD file with all field values.
pub fn read_pcd_full(path: impl AsRef<Path>) -> Result<PcdCloud, PcdError> {
    let path = path.as_ref();
    let io = |source| PcdError::Io {
        path: path.display().to_string(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    parse_pcd(BufReader::new(file)).map_err(|e| match e {
        PcdError::Io { source, .. } => io(source),
        other => other,
    })
}

/// Parses PCD from a reader.
pub fn parse_pcd(mut r: impl BufRead) -> Result<PcdCloud, PcdError> {
    let io = |source| PcdError::Io {
        path: "<stream>".into(),
        source,
    };
    let mut names = Vec::new();
    let mut sizes = Vec::new();
    let mut kinds = Vec::new();
    let mut counts = Vec::new();
    let mut points: Option<usize> = None;
    let mut width: Option<usize> = None;
    let mut height: Option<usize> = None;
    let data;
    loop {
        let mut line = String::new();
        if r.read_line(&mut line).map_err(io)? == 0 {
            return Err(PcdError::Header("no DATA line".into()));
        }
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut it = line.split_whitespace();
        let key = it.next().unwrap_or_default().to_ascii_uppercase();
        let rest: Vec<&str> = it.collect();
        let num = |s: &str| {
            s.parse::<usize>()
                .map_err(|_| PcdError::Header(format!("bad number {s:?} in {key}")))
        };
        match key.as_str() {
            "FIELDS" => names = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => sizes = rest.iter().map(|s| num(s)).collect::<Result<_, _>>()?,
            "TYPE" => {
                kinds = rest
                    .iter()
                    .map(|s| s.bytes().next().unwrap_or(b'?'))
                    .collect()
            }
            "COUNT" => counts = rest.iter().map(|s| num(s)).collect::<Result<_, _>>()?,
            "WIDTH" => width = rest.first().map(|s| num(s)).transpose()?,
            "HEIGHT" => height = rest.first().map(|s| num(s)).transpose()?,
            "POINTS" => points = rest.first().map(|s| num(s)).transpose()?,
            "DATA" => {
                data = rest.first().unwrap_or(&"").to_ascii_lowercase();
                break;
            }
            _ => {}
        }
    }
    if counts.is_empty() {
        counts = vec![1; names.len()];
    }
    if names.is_empty()
        || sizes.len() != names.len()
        || kinds.len() != names.len()
        || counts.len() != names.len()
    {
        return Err(PcdError::Header(
            "FIELDS, SIZE, TYPE and COUNT disagree".into(),
        ));
    }
    let n = points
        .or_else(|| Some(width? * height.unwrap_or(1)))
        .ok_or_else(|| PcdError::Header("no POINTS or WIDTH".into()))?;
    let fields: Vec<Field> = (0..names.len())
        .map(|i| Field {
            name: names[i].to_ascii_lowercase(),
            size: sizes[i],
            kind: kinds[i],
            count: counts[i],
        })
        .collect();
    for f in &fields {
        if !matches!(
            (f.kind, f.size),
            (b'F', 4 | 8) | (b'U' | b'I', 1 | 2 | 4 | 8)
        ) {
            return Err(PcdError::Header(format!(
                "field {} has TYPE/SIZE {}{}",
                f.name, f.kind as char, f.size
            )));
        }
    }
    let find = |cands: &[&str]| fields.iter().position(|f| cands.contains(&f.name.as_str()));
    let map = Mapping {
        x: find(&["x"]),
        y: find(&["y"]),
        z: find(&["z"]),
        intensity: find(&["intensity", "i"]),
        ring: find(&["ring", "channel", "laser_id"]),
        time: find(&["t", "time", "timestamp", "time_stamp"]),
    };
    if map.x.is_none() || map.y.is_none() || map.z.is_none() {
        return Err(PcdError::Header("no x y z fields".into()));
    }
    let mut values: Vec<Vec<f64>> = Vec::with_capacity(n.min(10_000_000));
    match data.as_str() {
        "binary" => {
            let stride: usize = fields.iter().map(Field::bytes).sum();
            let mut buf = Vec::new();
            r.read_to_end(&mut buf).map_err(io)?;
            if buf.len() < stride * n {
                return Err(PcdError::Data(format!(
                    "{} bytes for {n} points of {stride} bytes",
                    buf.len()
                )));
            }
            for rec in buf.chunks_exact(stride).take(n) {
                let mut off = 0;
                let mut row = Vec::with_capacity(fields.len());
                for f in &fields {
                    row.push(f.read(&rec[off..off + f.bytes()]));
                    off += f.bytes();
                }
                values.push(row);
            }
        }
        "ascii" => {
            for line in r.lines() {
                let line = line.map_err(io)?;
                let toks: Vec<&str> = line.split_whitespace().collect();
                if toks.is_empty() {
                    continue;
                }
                let mut row = Vec::with_capacity(fields.len());
                let mut k = 0;
                for f in &fields {
                    let tok = toks
                        .get(k)
                        .ok_or_else(|| PcdError::Data(format!("short line {line:?}")))?;
                    let v = if tok.eq_ignore_ascii_case("nan") {
                        f64::NAN
                    } else {
                        tok.parse::<f64>()
                            .map_err(|_| PcdError::Data(format!("bad value {tok:?}")))?
                    };
                    row.push(v);
                    k += f.count;
                }
                values.push(row);
                if values.len() == n {
                    break;
                }
            }
            if values.len() < n {
                return Err(PcdError::Data(format!("{} of {n} points", values.len())));
            }
        }
        other => return Err(PcdError::Unsupported(other.to_string())),
    }
    let get = |row: &[f64], i: Option<usize>| i.map(|i| row[i]).unwrap_or(0.0);
    let pts = values
        .iter()
        .map(|row| Point {
            x: get(row, map.x) as f32,
            y: get(row, map.y) as f32,
            z: get(row, map.z) as f32,
            intensity: get(row, map.intensity) as f32,
            ring: get(row, map.ring) as u16,
            t_s: get(row, map.time) as f32,
        })
        .collect();
    Ok(PcdCloud {
        points: pts,
        field_names: fields.into_iter().map(|f| f.name).collect(),
        values,
    })
}

/// Writes points as binary PCD v0.7 with fields `x y z intensity ring t`.
pub fn write_pcd(path: impl AsRef<Path>, points: &[Point]) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    write_pcd_to(&mut w, points)?;
    w.flush()
}

/// Writes binary PCD to any writer.
pub fn write_pcd_to(w: &mut impl Write, points: &[Point]) -> std::io::Result<()> {
    write!(
        w,
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity ring t\n\
         SIZE 4 4 4 4 2 4\nTYPE F F F F U F\nCOUNT 1 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        n = points.len()
    )?;
    let mut buf = Vec::with_capacity(points.len() * 22);
    for p in points {
        buf.extend_from_slice(&p.x.to_le_bytes());
        buf.extend_from_slice(&p.y.to_le_bytes());
        buf.extend_from_slice(&p.z.to_le_bytes());
        buf.extend_from_slice(&p.intensity.to_le_bytes());
        buf.extend_from_slice(&p.ring.to_le_bytes());
        buf.extend_from_slice(&p.t_s.to_le_bytes());
    }
    w.write_all(&buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_round_trip() {
        let pts = vec![
            Point {
                x: 1.0,
                y: -2.0,
                z: 0.5,
                intensity: 7.0,
                ring: 3,
                t_s: 0.05,
            },
            Point {
                x: f32::NAN,
                y: 0.0,
                z: 0.0,
                intensity: 0.0,
                ring: 15,
                t_s: 0.099,
            },
        ];
        let mut buf = Vec::new();
        write_pcd_to(&mut buf, &pts).unwrap();
        let back = parse_pcd(&buf[..]).unwrap().points;
        assert_eq!(back.len(), 2);
        assert_eq!(back[0], pts[0]);
        assert!(back[1].x.is_nan() && back[1].ring == 15);
    }

    #[test]
    fn ascii_with_extra_fields() {
        let txt = "VERSION .7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 9\n4 5 nan 9\n";
        let c = parse_pcd(txt.as_bytes()).unwrap();
        assert_eq!(c.points[0], Point::xyz(1.0, 2.0, 3.0));
        assert!(c.points[1].z.is_nan());
        assert_eq!(c.field_names, ["x", "y", "z", "rgb"]);
    }

    #[test]
    fn bad_files_are_errors() {
        assert!(matches!(
            parse_pcd(&b"VERSION .7\n"[..]),
            Err(PcdError::Header(_))
        ));
        let short = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 10\nPOINTS 10\nDATA binary\nabc";
        assert!(matches!(
            parse_pcd(short.as_bytes()),
            Err(PcdError::Data(_))
        ));
        let comp =
            "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA binary_compressed\n";
        assert!(matches!(
            parse_pcd(comp.as_bytes()),
            Err(PcdError::Unsupported(_))
        ));
        let odd = "FIELDS x y z\nSIZE 4 4 3\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA binary\n";
        assert!(matches!(
            parse_pcd(odd.as_bytes()),
            Err(PcdError::Header(_))
        ));
    }
}
