//! Exports from the station's store for tools outside terranav: a session as MCAP (Foxglove,
//! Lichtblick) and the merged map as a GeoTIFF (QGIS, GDAL).

pub mod geotiff;
pub mod mcap;
