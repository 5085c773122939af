//! PLY point clouds (vertex x y z and optional intensity; ascii or binary little-endian).

use crate::cloud::Point;
use std::io::{BufRead, BufReader};
use std::path::Path;

/// Why a PLY file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlyError {
    /// The file could not be read.
    #[error("reading PLY: {0}")]
    Io(#[from] std::io::Error),
    /// Unsupported or inconsistent header.
    #[error("bad PLY header: {0}")]
    Header(String),
    /// Data shorter than the header promises, or unparsable.
    #[error("bad PLY data: {0}")]
    Data(String),
}

/// Reads the vertices of a PLY file as points.
pub fn read_ply(path: impl AsRef<Path>) -> Result<Vec<Point>, PlyError> {
    parse_ply(BufReader::new(std::fs::File::open(path)?))
}

/// Parses PLY from a reader.
pub fn parse_ply(mut r: impl BufRead) -> Result<Vec<Point>, PlyError> {
    let mut format = String::new();
    let mut n_vertex = None;
    let mut in_vertex = false;
    let mut props: Vec<(String, usize, char)> = Vec::new(); // name, size, kind (f/i/u)
    let mut first = String::new();
    r.read_line(&mut first)?;
    if first.trim() != "ply" {
        return Err(PlyError::Header("missing 'ply' magic".into()));
    }
    loop {
        let mut line = String::new();
        if r.read_line(&mut line)? == 0 {
            return Err(PlyError::Header("no end_header".into()));
        }
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, ..] => format = f.to_string(),
            ["element", "vertex", n] => {
                n_vertex = Some(
                    n.parse::<usize>()
                        .map_err(|_| PlyError::Header("vertex count".into()))?,
                );
                in_vertex = true;
            }
            // Elements after the vertices (faces) are ignored; vertices come first in the file.
            ["element", ..] if n_vertex.is_some() => in_vertex = false,
            ["property", "list", ..] if in_vertex => {
                return Err(PlyError::Header("list property on vertex".into()))
            }
            ["property", ty, name] if in_vertex => {
                let (size, kind) = match *ty {
                    "float" | "float32" => (4, 'f'),
                    "double" | "float64" => (8, 'f'),
                    "uchar" | "uint8" => (1, 'u'),
                    "char" | "int8" => (1, 'i'),
                    "ushort" | "uint16" => (2, 'u'),
                    "short" | "int16" => (2, 'i'),
                    "uint" | "uint32" => (4, 'u'),
                    "int" | "int32" => (4, 'i'),
                    other => return Err(PlyError::Header(format!("property type {other}"))),
                };
                props.push((name.to_string(), size, kind));
            }
            ["end_header"] => break,
            _ => {}
        }
    }
    let n = n_vertex.ok_or_else(|| PlyError::Header("no vertex element".into()))?;
    let idx = |names: &[&str]| props.iter().position(|p| names.contains(&p.0.as_str()));
    let (ix, iy, iz) = match (idx(&["x"]), idx(&["y"]), idx(&["z"])) {
        (Some(a), Some(b), Some(c)) => (a, b, c),
        _ => return Err(PlyError::Header("vertex lacks x y z".into())),
    };
    let ii = idx(&["intensity", "scalar_intensity", "scalar_Intensity"]);
    let mut rows: Vec<Vec<f64>> = Vec::with_capacity(n.min(10_000_000));
    match format.as_str() {
        "binary_little_endian" => {
            let stride: usize = props.iter().map(|p| p.1).sum();
            let mut buf = vec![0u8; stride * n];
            r.read_exact(&mut buf)
                .map_err(|_| PlyError::Data("file shorter than header says".into()))?;
            for rec in buf.chunks_exact(stride) {
                let mut off = 0;
                let mut row = Vec::with_capacity(props.len());
                for (_, size, kind) in &props {
                    let b = &rec[off..off + size];
                    let v = match (kind, size) {
                        ('f', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                        ('f', 8) => {
                            f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
                        }
                        ('u', 1) => b[0] as f64,
                        ('i', 1) => b[0] as i8 as f64,
                        ('u', 2) => u16::from_le_bytes([b[0], b[1]]) as f64,
                        ('i', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
                        ('u', 4) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                        _ => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    };
                    row.push(v);
                    off += size;
                }
                rows.push(row);
            }
        }
        "ascii" => {
            for line in r.lines() {
                let line = line?;
                let vals: Result<Vec<f64>, _> =
                    line.split_whitespace().map(str::parse::<f64>).collect();
                let vals = vals.map_err(|_| PlyError::Data(format!("bad line {line:?}")))?;
                if vals.len() < props.len() {
                    continue;
                }
                rows.push(vals);
                if rows.len() == n {
                    break;
                }
            }
            if rows.len() < n {
                return Err(PlyError::Data(format!("{} of {n} vertices", rows.len())));
            }
        }
        other => return Err(PlyError::Header(format!("format {other} not supported"))),
    }
    Ok(rows
        .iter()
        .map(|r| Point {
            x: r[ix] as f32,
            y: r[iy] as f32,
            z: r[iz] as f32,
            intensity: ii.map(|i| r[i] as f32).unwrap_or(0.0),
            ..Point::default()
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary() {
        let a = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n";
        let p = parse_ply(a.as_bytes()).unwrap();
        assert_eq!(p[1], Point::xyz(4.0, 5.0, 6.0));
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float scalar_intensity\nend_header\n".to_vec();
        for v in [1.5f32, -2.0, 3.0, 9.0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        let p = parse_ply(&b[..]).unwrap();
        assert_eq!(p[0].intensity, 9.0);
        assert!(parse_ply(&b[..b.len() - 2]).is_err());
        assert!(parse_ply(&b"nope\n"[..]).is_err());
    }
}
