//! A background map the operator brings (`--basemap PATH`): a folder of `{z}/{x}/{y}.png|jpg|webp`
//! tiles (XYZ, or TMS when the folder has gdal2tiles' `tilemapresource.xml`) or an MBTiles
//! file (SQLite; its rows are TMS). Served to the browser as XYZ tiles from the station itself:
//! nothing is fetched from the network.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rusqlite::{params, Connection, OpenFlags, OptionalExtension};
use serde::Serialize;

/// What the browser needs to place the tiles.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BasemapInfo {
    /// The file or folder name.
    pub name: String,
    /// `png`, `jpg` or `webp`.
    pub format: String,
    /// Lowest zoom level with tiles.
    pub min_zoom: u8,
    /// Highest zoom level with tiles.
    pub max_zoom: u8,
    /// `[west, south, east, north]` degrees, when known.
    pub bounds: Option<[f64; 4]>,
    /// How the source numbers rows (`xyz` or `tms`); the API always serves XYZ.
    pub scheme: String,
}

/// Why the basemap cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BasemapError {
    /// Not a folder of tiles or an MBTiles file.
    #[error("{0}")]
    Unusable(String),
    /// The MBTiles file could not be read.
    #[error("mbtiles: {0}")]
    Sql(#[from] rusqlite::Error),
    /// The folder could not be read.
    #[error("basemap folder: {0}")]
    Io(#[from] std::io::Error),
}

enum Source {
    Dir { root: PathBuf, tms: bool },
    MbTiles(Mutex<Connection>),
}

/// An opened basemap.
pub struct Basemap {
    info: BasemapInfo,
    source: Source,
}

fn content_type(format: &str) -> &'static str {
    match format {
        "jpg" | "jpeg" => "image/jpeg",
        "webp" => "image/webp",
        _ => "image/png",
    }
}

impl Basemap {
    /// Opens a tile folder or an MBTiles file.
    pub fn open(path: &Path) -> Result<Self, BasemapError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if path.is_dir() {
            Self::open_dir(path, name)
        } else if path.is_file() {
            Self::open_mbtiles(path, name)
        } else {
            Err(BasemapError::Unusable(format!(
                "--basemap {}: no such file or folder",
                path.display()
            )))
        }
    }

    fn open_dir(root: &Path, name: String) -> Result<Self, BasemapError> {
        let mut zooms: Vec<u8> = std::fs::read_dir(root)?
            .filter_map(Result::ok)
            .filter(|e| e.path().is_dir())
            .filter_map(|e| e.file_name().to_str()?.parse::<u8>().ok())
            .filter(|z| *z <= 24)
            .collect();
        zooms.sort_unstable();
        let (Some(&min_zoom), Some(&max_zoom)) = (zooms.first(), zooms.last()) else {
            return Err(BasemapError::Unusable(format!(
                "--basemap {}: no zoom folders (expected {{z}}/{{x}}/{{y}}.png)",
                root.display()
            )));
        };
        // The format of the first tile found.
        let mut format = None;
        'find: for x in std::fs::read_dir(root.join(min_zoom.to_string()))?.filter_map(Result::ok) {
            if let Ok(ys) = std::fs::read_dir(x.path()) {
                for y in ys.filter_map(Result::ok) {
                    if let Some(ext) = y.path().extension().and_then(|e| e.to_str()) {
                        format = Some(ext.to_ascii_lowercase());
                        break 'find;
                    }
                }
            }
        }
        let format = format.ok_or_else(|| {
            BasemapError::Unusable(format!("--basemap {}: no tile images", root.display()))
        })?;
        let tms = root.join("tilemapresource.xml").is_file();
        Ok(Self {
            info: BasemapInfo {
                name,
                format,
                min_zoom,
                max_zoom,
                bounds: None,
                scheme: if tms { "tms" } else { "xyz" }.into(),
            },
            source: Source::Dir {
                root: root.to_path_buf(),
                tms,
            },
        })
    }

    fn open_mbtiles(path: &Path, name: String) -> Result<Self, BasemapError> {
        let c = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )?;
        let meta = |k: &str| -> Result<Option<String>, rusqlite::Error> {
            c.query_row(
                "SELECT value FROM metadata WHERE name = ?1",
                params![k],
                |r| r.get(0),
            )
            .optional()
        };
        let format = meta("format")
            .map_err(|e| {
                BasemapError::Unusable(format!(
                    "--basemap {}: not an MBTiles file ({e})",
                    path.display()
                ))
            })?
            .unwrap_or_else(|| "png".into())
            .to_ascii_lowercase();
        let (zmin, zmax): (Option<i64>, Option<i64>) = c.query_row(
            "SELECT min(zoom_level), max(zoom_level) FROM tiles",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )?;
        let (Some(zmin), Some(zmax)) = (zmin, zmax) else {
            return Err(BasemapError::Unusable(format!(
                "--basemap {}: the MBTiles file has no tiles",
                path.display()
            )));
        };
        let bounds = meta("bounds")?.and_then(|b| {
            let v: Vec<f64> = b.split(',').filter_map(|t| t.trim().parse().ok()).collect();
            (v.len() == 4).then(|| [v[0], v[1], v[2], v[3]])
        });
        Ok(Self {
            info: BasemapInfo {
                name,
                format,
                min_zoom: zmin.clamp(0, 24) as u8,
                max_zoom: zmax.clamp(0, 24) as u8,
                bounds,
                scheme: "tms".into(),
            },
            source: Source::MbTiles(Mutex::new(c)),
        })
    }

    /// What the browser needs.
    pub fn info(&self) -> &BasemapInfo {
        &self.info
    }

    /// The MIME type of the tiles.
    pub fn content_type(&self) -> &'static str {
        content_type(&self.info.format)
    }

    /// Tile (z, x, y) in XYZ numbering (row 0 north), if the source has it.
    pub fn tile(&self, z: u8, x: u32, y: u32) -> Result<Option<Vec<u8>>, BasemapError> {
        if z > 24 || u64::from(x) >= 1u64 << z || u64::from(y) >= 1u64 << z {
            return Ok(None);
        }
        let tms_y = (1u32 << z) - 1 - y;
        match &self.source {
            Source::Dir { root, tms } => {
                let row = if *tms { tms_y } else { y };
                let p = root
                    .join(z.to_string())
                    .join(x.to_string())
                    .join(format!("{row}.{}", self.info.format));
                match std::fs::read(&p) {
                    Ok(b) => Ok(Some(b)),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                    Err(e) => Err(e.into()),
                }
            }
            Source::MbTiles(c) => {
                let c = c.lock().unwrap_or_else(|p| p.into_inner());
                Ok(c.query_row(
                    "SELECT tile_data FROM tiles WHERE zoom_level = ?1 AND tile_column = ?2 AND tile_row = ?3",
                    params![z, x, tms_y],
                    |r| r.get(0),
                )
                .optional()?)
            }
        }
    }
}

/// The XYZ tile holding (lat, lon) at zoom `z` (Web Mercator).
pub fn tile_of(lat_deg: f64, lon_deg: f64, z: u8) -> (u32, u32) {
    let n = f64::from(1u32 << z);
    let x = ((lon_deg + 180.0) / 360.0 * n).floor();
    let lat = lat_deg.to_radians();
    let y = ((1.0 - (lat.tan() + 1.0 / lat.cos()).ln() / std::f64::consts::PI) / 2.0 * n).floor();
    (x.clamp(0.0, n - 1.0) as u32, y.clamp(0.0, n - 1.0) as u32)
}

/// The north-west corner of XYZ tile (x, y) at zoom `z`, as (lat, lon) degrees.
pub fn tile_corner(z: u8, x: u32, y: u32) -> (f64, f64) {
    let n = f64::from(1u32 << z);
    let lon = f64::from(x) / n * 360.0 - 180.0;
    let lat = (std::f64::consts::PI * (1.0 - 2.0 * f64::from(y) / n))
        .sinh()
        .atan()
        .to_degrees();
    (lat, lon)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_numbers_round_trip() {
        let (x, y) = tile_of(47.3769, 8.5417, 18);
        let (lat0, lon0) = tile_corner(18, x, y);
        let (lat1, lon1) = tile_corner(18, x + 1, y + 1);
        assert!(lat1 < 47.3769 && 47.3769 <= lat0, "{lat0} {lat1}");
        assert!(lon0 <= 8.5417 && 8.5417 < lon1);
    }

    #[test]
    fn folders_and_mbtiles_serve_xyz() {
        let dir = tempfile::tempdir().unwrap();
        let xyz = dir.path().join("xyz");
        std::fs::create_dir_all(xyz.join("3/2")).unwrap();
        std::fs::write(xyz.join("3/2/5.png"), b"png!").unwrap();
        let b = Basemap::open(&xyz).unwrap();
        assert_eq!(b.info().scheme, "xyz");
        assert_eq!((b.info().min_zoom, b.info().max_zoom), (3, 3));
        assert_eq!(b.tile(3, 2, 5).unwrap().as_deref(), Some(&b"png!"[..]));
        assert_eq!(b.tile(3, 2, 4).unwrap(), None);
        assert_eq!(b.tile(3, 9, 0).unwrap(), None, "out of range");

        let mb = dir.path().join("m.mbtiles");
        let c = Connection::open(&mb).unwrap();
        c.execute_batch(
            "CREATE TABLE metadata (name TEXT, value TEXT);
             CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB);
             INSERT INTO metadata VALUES ('format', 'jpg'), ('bounds', '8.5,47.3,8.6,47.4');",
        )
        .unwrap();
        // XYZ (3, 2, 5) is TMS row 8 - 1 - 5 = 2.
        c.execute(
            "INSERT INTO tiles VALUES (3, 2, 2, ?1)",
            params![&b"jpg!"[..]],
        )
        .unwrap();
        drop(c);
        let b = Basemap::open(&mb).unwrap();
        assert_eq!(b.content_type(), "image/jpeg");
        assert_eq!(b.info().bounds, Some([8.5, 47.3, 8.6, 47.4]));
        assert_eq!(b.tile(3, 2, 5).unwrap().as_deref(), Some(&b"jpg!"[..]));
        assert!(Basemap::open(&dir.path().join("none")).is_err());
    }
}
