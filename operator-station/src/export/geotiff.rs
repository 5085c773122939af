//! The merged map of a datum as a GeoTIFF that GIS tools open in place: three float32 bands per
//! 0.2 m cell (1: ground height in metres, 2: class 0 unknown / 1 traversable / 2 obstacle /
//! 3 inflated, 3: planner cost 0-255), unknown cells NaN (`GDAL_NODATA`), north up.
//!
//! The map frame is ENU at the datum, which no EPSG code names. A transverse Mercator centred on
//! the datum (WGS 84, natural origin at the datum, no false easting or northing) is the map frame
//! to well within a millimetre over a kilometre, once its scale at the origin is `1 + h / R` (the
//! datum's height h over the ellipsoid, R its Gaussian radius: ENU distances are measured at the
//! datum's height, Mercator's on the ellipsoid). So cells need no resampling: the raster's pixels
//! are the map's cells and its geokeys describe that projection (GeoTIFF 1.0, user-defined
//! projected CRS).

use crate::merge::DatumMap;
use common::grid::CellState;
use common::msg::Datum;
use std::io::{Seek, Write};
use tiff::encoder::colortype::ColorType;
use tiff::encoder::TiffEncoder;
use tiff::tags::{PhotometricInterpretation, SampleFormat, Tag};

/// Three float32 samples per pixel: one grey value and two extra samples (the spec's way of
/// saying "bands that are not colour"; GDAL reads them as bands 1-3).
struct ThreeBands;

impl ColorType for ThreeBands {
    type Inner = f32;
    const TIFF_VALUE: PhotometricInterpretation = PhotometricInterpretation::BlackIsZero;
    const BITS_PER_SAMPLE: &'static [u16] = &[32, 32, 32];
    const SAMPLE_FORMAT: &'static [SampleFormat] = &[
        SampleFormat::IEEEFP,
        SampleFormat::IEEEFP,
        SampleFormat::IEEEFP,
    ];

    fn horizontal_predict(_: &[f32], _: &mut Vec<f32>) {
        unreachable!("written without a predictor")
    }
}

/// GeoTIFF tags.
const MODEL_PIXEL_SCALE: u16 = 33550;
const MODEL_TIEPOINT: u16 = 33922;
const GEO_KEY_DIRECTORY: u16 = 34735;
const GEO_DOUBLE_PARAMS: u16 = 34736;
const GEO_ASCII_PARAMS: u16 = 34737;
const GDAL_NODATA: u16 = 42113;
const EXTRA_SAMPLES: u16 = 338;

/// WGS 84 semi-major axis and flattening.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// The Gaussian radius of curvature `sqrt(M N)` at `lat_deg`, metres.
pub fn gaussian_radius_m(lat_deg: f64) -> f64 {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let s2 = lat_deg.to_radians().sin().powi(2);
    let w = (1.0 - e2 * s2).sqrt();
    let n = WGS84_A / w;
    let m = WGS84_A * (1.0 - e2) / (w * w * w);
    (m * n).sqrt()
}

/// What was written.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GeoTiffInfo {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// Map-frame x of the west edge, metres.
    pub west_m: f64,
    /// Map-frame y of the north edge, metres.
    pub north_m: f64,
    /// Cell edge, metres.
    pub cell_m: f64,
    /// Scale of the projection at its origin.
    pub scale_at_origin: f64,
}

/// Writes `dm` (a datum with a GNSS anchor `datum`) as a GeoTIFF to `out`.
pub fn write<W: Write + Seek>(
    dm: &DatumMap,
    datum: &Datum,
    datum_id: &str,
    out: W,
) -> anyhow::Result<GeoTiffInfo> {
    let first = dm
        .tiles
        .keys()
        .next()
        .ok_or_else(|| anyhow::anyhow!("datum {datum_id} has no tiles"))?;
    let (mut tx0, mut ty0, mut tx1, mut ty1) = (first.tx, first.ty, first.tx, first.ty);
    for t in dm.tiles.keys() {
        tx0 = tx0.min(t.tx);
        ty0 = ty0.min(t.ty);
        tx1 = tx1.max(t.tx);
        ty1 = ty1.max(t.ty);
    }
    let n = usize::from(dm.lattice.tile_cells);
    let width = (tx1 - tx0 + 1) as usize * n;
    let height = (ty1 - ty0 + 1) as usize * n;
    anyhow::ensure!(
        width * height <= 400_000_000,
        "the map is {width} x {height} cells: too large for one GeoTIFF"
    );
    let mut px = vec![f32::NAN; width * height * 3];
    for (i, t) in &dm.tiles {
        if t.cells.len() != n * n {
            continue;
        }
        for r in 0..n {
            // Raster rows run north to south; tile rows south to north.
            let row = height - 1 - ((i.ty - ty0) as usize * n + r);
            for c in 0..n {
                let cell = &t.cells[r * n + c];
                if cell.state == CellState::Unknown {
                    continue;
                }
                let col = (i.tx - tx0) as usize * n + c;
                let at = (row * width + col) * 3;
                px[at] = f32::from(cell.height_cm) / 100.0;
                px[at + 1] = f32::from(cell.state as u8);
                px[at + 2] = f32::from(cell.cost);
            }
        }
    }
    let s = dm.lattice.cell_size_f64();
    let west = f64::from(tx0) * n as f64 * s;
    let north = f64::from(ty1 + 1) * n as f64 * s;
    let k0 = 1.0 + datum.h_m / gaussian_radius_m(datum.lat_deg);
    let citation = format!(
        "terranav map frame of datum {datum_id}: ENU at {:.9},{:.9},{:.3} as transverse Mercator at the datum|",
        datum.lat_deg, datum.lon_deg, datum.h_m
    );
    let pcs = "WGS 84 / terranav ENU at datum|";
    let ascii = format!("{citation}{pcs}");
    // Key directory: version 1.1.0, then (key, location, count, value or offset), keys ascending.
    let keys: Vec<[u16; 4]> = vec![
        [1024, 0, 1, 1], // GTModelType: projected
        [1025, 0, 1, 1], // GTRasterType: pixel is area
        [1026, GEO_ASCII_PARAMS, citation.len() as u16, 0],
        [2048, 0, 1, 4326],  // GeographicType: WGS 84
        [3072, 0, 1, 32767], // ProjectedCSType: user-defined
        [
            3073,
            GEO_ASCII_PARAMS,
            pcs.len() as u16,
            citation.len() as u16,
        ],
        [3074, 0, 1, 32767],             // Projection: user-defined
        [3075, 0, 1, 1],                 // ProjCoordTrans: transverse Mercator
        [3076, 0, 1, 9001],              // ProjLinearUnits: metre
        [3080, GEO_DOUBLE_PARAMS, 1, 0], // ProjNatOriginLong
        [3081, GEO_DOUBLE_PARAMS, 1, 1], // ProjNatOriginLat
        [3082, GEO_DOUBLE_PARAMS, 1, 2], // ProjFalseEasting
        [3083, GEO_DOUBLE_PARAMS, 1, 3], // ProjFalseNorthing
        [3092, GEO_DOUBLE_PARAMS, 1, 4], // ProjScaleAtNatOrigin
    ];
    let mut dir: Vec<u16> = vec![1, 1, 0, keys.len() as u16];
    dir.extend(keys.iter().flatten());
    let doubles = [datum.lon_deg, datum.lat_deg, 0.0, 0.0, k0];

    let mut enc = TiffEncoder::new(out)?;
    let mut img = enc.new_image::<ThreeBands>(width as u32, height as u32)?;
    let e = img.encoder();
    e.write_tag(Tag::Unknown(EXTRA_SAMPLES), &[0u16, 0][..])?;
    e.write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[s, s, 0.0][..])?;
    e.write_tag(
        Tag::Unknown(MODEL_TIEPOINT),
        &[0.0, 0.0, 0.0, west, north, 0.0][..],
    )?;
    e.write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &dir[..])?;
    e.write_tag(Tag::Unknown(GEO_DOUBLE_PARAMS), &doubles[..])?;
    e.write_tag(Tag::Unknown(GEO_ASCII_PARAMS), ascii.as_str())?;
    e.write_tag(Tag::Unknown(GDAL_NODATA), "nan")?;
    img.write_data(&px)?;
    Ok(GeoTiffInfo {
        width: width as u32,
        height: height as u32,
        west_m: west,
        north_m: north,
        cell_m: s,
        scale_at_origin: k0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::merge::MergedMap;
    use common::grid::{Cell, Lattice, Tile, TileIndex};

    #[test]
    fn cells_land_north_up_with_their_georeference() {
        let mut t = Tile::new(TileIndex { tx: 0, ty: -1 }, Lattice::default());
        // The tile's south-west cell.
        *t.get_mut(0, 0) = Cell {
            state: CellState::Obstacle,
            cost: 254,
            height_cm: 125,
            hits: 2,
            stamp_s: 1,
            rev: 0,
        };
        let mut m = MergedMap::default();
        m.restore("d0", t);
        let datum = Datum {
            lat_deg: 48.0,
            lon_deg: 11.0,
            h_m: 500.0,
        };
        let mut buf = std::io::Cursor::new(Vec::new());
        let info = write(&m.datums["d0"], &datum, "d0", &mut buf).unwrap();
        assert_eq!((info.width, info.height), (64, 64));
        assert_eq!((info.west_m, info.north_m), (0.0, 0.0));
        assert!((info.scale_at_origin - 1.0000785).abs() < 1e-6);
        buf.set_position(0);
        let mut dec = tiff::decoder::Decoder::new(buf).unwrap();
        let tie = dec.get_tag_f64_vec(Tag::Unknown(MODEL_TIEPOINT)).unwrap();
        assert_eq!(tie[3..5], [0.0, 0.0]);
        let keys = dec
            .get_tag_u16_vec(Tag::Unknown(GEO_KEY_DIRECTORY))
            .unwrap();
        assert_eq!(keys[3] as usize * 4 + 4, keys.len());
        let tiff::decoder::DecodingResult::F32(px) = dec.read_image().unwrap() else {
            panic!("float32 bands");
        };
        // South-west cell: the last row, first column.
        let at = (63 * 64) * 3;
        assert_eq!(&px[at..at + 3], &[1.25, 2.0, 254.0]);
        assert!(px[0].is_nan());
    }
}
