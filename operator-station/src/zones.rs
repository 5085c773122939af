//! Zones as the station keeps them: keep-out and slow polygons drawn by the operator (or
//! imported as GeoJSON), in WGS-84 when their datum has one and always in the map frame of the
//! datum they were drawn on; GeoJSON in and out; and each robot's [`ZoneSet`] in its own map
//! frame (what goes on `terranav/<robot>/zones`).
//!
//! Pure data and conversions: the API reads and writes, the station publishes.

use common::msg::{Datum, Session, Zone, ZoneKind, ZoneSet};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

/// A zone as stored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZoneRecord {
    /// Id, `z-<unix ms>-<n>`.
    pub zone_id: String,
    /// Name given by the operator.
    pub name: String,
    /// `keep_out` or `slow`.
    pub kind: String,
    /// Speed cap of a slow zone, m/s.
    pub speed_mps: Option<f32>,
    /// The datum whose map frame `polygon_m` is in.
    pub datum_id: String,
    /// Corners in that map frame, metres.
    pub polygon_m: Vec<(f64, f64)>,
    /// Corners as (lat, lon) degrees, when the datum has a position on Earth.
    pub polygon_ll: Option<Vec<(f64, f64)>>,
}

impl ZoneRecord {
    /// The wire kind.
    pub fn wire_kind(&self) -> ZoneKind {
        match (self.kind.as_str(), self.speed_mps) {
            ("slow", Some(v)) => ZoneKind::Slow { speed_mps: v },
            _ => ZoneKind::KeepOut,
        }
    }

    /// The polygon in the map frame of `datum_id` (whose position on Earth is `datum`, if
    /// any): as drawn when it is the zone's own datum, else through latitude and longitude;
    /// None when the frames cannot be related (a local frame without GNSS).
    pub fn polygon_in(&self, datum_id: &str, datum: Option<&Datum>) -> Option<Vec<(f64, f64)>> {
        if datum_id == self.datum_id {
            return Some(self.polygon_m.clone());
        }
        let (ll, d) = (self.polygon_ll.as_ref()?, datum?);
        Some(
            ll.iter()
                .map(|&(lat, lon)| {
                    let e = common::geo::lla_to_enu(
                        d,
                        &Datum {
                            lat_deg: lat,
                            lon_deg: lon,
                            h_m: d.h_m,
                        },
                    );
                    (e.x, e.y)
                })
                .collect(),
        )
    }

    /// The zone as a GeoJSON Feature: in lon/lat when known, else in the map frame of its
    /// datum; `frame`: force the map frame of this datum (None: the zone cannot be shown there).
    pub fn to_feature(&self, frame: Option<(&str, Option<&Datum>)>) -> Option<Value> {
        let ring: Vec<[f64; 2]> = match frame {
            Some((id, d)) => self
                .polygon_in(id, d)?
                .into_iter()
                .map(|(x, y)| [x, y])
                .collect(),
            None => match &self.polygon_ll {
                Some(ll) => ll.iter().map(|&(lat, lon)| [lon, lat]).collect(),
                None => self.polygon_m.iter().map(|&(x, y)| [x, y]).collect(),
            },
        };
        let mut closed = ring.clone();
        if let Some(first) = ring.first() {
            closed.push(*first);
        }
        let crs_note = match (frame, &self.polygon_ll) {
            (Some((id, _)), _) => format!("map:{id}"),
            (None, Some(_)) => "wgs84".to_string(),
            (None, None) => format!("map:{}", self.datum_id),
        };
        Some(json!({
            "type": "Feature",
            "id": self.zone_id,
            "geometry": {"type": "Polygon", "coordinates": [closed]},
            "properties": {
                "zone_id": self.zone_id, "name": self.name, "kind": self.kind,
                "speed_mps": self.speed_mps, "datum_id": self.datum_id, "coordinates": crs_note,
                "polygon_m": self.polygon_m,
            }
        }))
    }
}

/// Why a zone could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ZoneError(pub String);

fn zerr(m: impl Into<String>) -> ZoneError {
    ZoneError(m.into())
}

/// The frame the coordinates of a posted zone are in.
#[derive(Clone, Debug, PartialEq)]
pub enum PostFrame {
    /// GeoJSON's own: longitude, latitude.
    Wgs84,
    /// Map x, y of this datum (with its position on Earth, if any).
    Map(String, Option<Datum>),
}

/// Reads a GeoJSON Feature (or each Feature of a FeatureCollection) with a Polygon geometry and
/// `properties.kind` `keep_out` or `slow` (with `speed_mps`) into zone records. `datum`: the
/// datum the map-frame polygon is kept in (for WGS-84 input: the one to draw on).
pub fn from_geojson(
    text: &str,
    frame: &PostFrame,
    datum: (&str, Option<&Datum>),
    id_base: &str,
) -> Result<Vec<ZoneRecord>, ZoneError> {
    let gj: geojson::GeoJson = text
        .parse()
        .map_err(|e| zerr(format!("not GeoJSON: {e}")))?;
    let features: Vec<geojson::Feature> = match gj {
        geojson::GeoJson::Feature(f) => vec![f],
        geojson::GeoJson::FeatureCollection(c) => c.features,
        geojson::GeoJson::Geometry(_) => {
            return Err(zerr(
                "a bare geometry: send a Feature with properties.kind (keep_out or slow)",
            ))
        }
    };
    if features.is_empty() {
        return Err(zerr("no features"));
    }
    features
        .iter()
        .enumerate()
        .map(|(i, f)| feature_to_zone(f, frame, datum, &format!("{id_base}-{i}")))
        .collect()
}

fn feature_to_zone(
    f: &geojson::Feature,
    frame: &PostFrame,
    (datum_id, datum): (&str, Option<&Datum>),
    id: &str,
) -> Result<ZoneRecord, ZoneError> {
    let prop = |k: &str| f.properties.as_ref().and_then(|p| p.get(k));
    let kind = prop("kind")
        .and_then(Value::as_str)
        .ok_or_else(|| zerr("properties.kind is missing: keep_out or slow"))?;
    let speed_mps = match kind {
        "keep_out" => None,
        "slow" => {
            let v = prop("speed_mps")
                .and_then(Value::as_f64)
                .ok_or_else(|| zerr("a slow zone needs properties.speed_mps"))?;
            if !(v.is_finite() && v > 0.0 && v <= 10.0) {
                return Err(zerr(format!("speed_mps {v} must be within (0, 10] m/s")));
            }
            Some(v as f32)
        }
        k => return Err(zerr(format!("kind {k:?}: use keep_out or slow"))),
    };
    let name = prop("name")
        .and_then(Value::as_str)
        .map(str::to_string)
        .unwrap_or_else(|| format!("{} zone", kind.replace('_', "-")));
    if name.chars().count() > common::command::MAX_ZONE_NAME {
        return Err(zerr("name longer than 200 characters"));
    }
    let geom = f
        .geometry
        .as_ref()
        .ok_or_else(|| zerr("the feature has no geometry"))?;
    let ring = match &geom.value {
        geojson::Value::Polygon(rings) => rings
            .first()
            .ok_or_else(|| zerr("the polygon has no ring"))?
            .clone(),
        other => {
            return Err(zerr(format!(
                "geometry {}: a zone is a Polygon",
                other.type_name()
            )))
        }
    };
    let mut pts: Vec<(f64, f64)> = ring
        .iter()
        .map(|p| match p.as_slice() {
            [a, b, ..] => Ok((*a, *b)),
            _ => Err(zerr("a position needs two numbers")),
        })
        .collect::<Result<_, _>>()?;
    // GeoJSON rings repeat the first position at the end.
    if pts.len() > 1 && pts.first() == pts.last() {
        pts.pop();
    }
    let (polygon_m, polygon_ll) = match frame {
        PostFrame::Wgs84 => {
            if pts
                .iter()
                .any(|&(lon, lat)| !(lat.abs() <= 90.0 && lon.abs() <= 180.0))
            {
                return Err(zerr(
                    "longitude/latitude out of range (GeoJSON is [lon, lat])",
                ));
            }
            let d = datum.ok_or_else(|| {
                zerr(format!(
                    "datum {datum_id} has no position on Earth: post map x/y with ?frame=map&datum_id={datum_id}"
                ))
            })?;
            let ll: Vec<(f64, f64)> = pts.iter().map(|&(lon, lat)| (lat, lon)).collect();
            let m = ll
                .iter()
                .map(|&(lat, lon)| {
                    let e = common::geo::lla_to_enu(
                        d,
                        &Datum {
                            lat_deg: lat,
                            lon_deg: lon,
                            h_m: d.h_m,
                        },
                    );
                    (e.x, e.y)
                })
                .collect();
            (m, Some(ll))
        }
        PostFrame::Map(_, d) => {
            let ll = d.map(|d| {
                pts.iter()
                    .map(|&(x, y)| {
                        let g = common::geo::enu_to_lla(&d, &nalgebra::Vector3::new(x, y, 0.0));
                        (g.lat_deg, g.lon_deg)
                    })
                    .collect()
            });
            (pts.clone(), ll)
        }
    };
    common::zone::check_polygon(&polygon_m).map_err(|e| zerr(format!("zone {name:?}: {e}")))?;
    Ok(ZoneRecord {
        zone_id: id.to_string(),
        name,
        kind: kind.to_string(),
        speed_mps,
        datum_id: datum_id.to_string(),
        polygon_m,
        polygon_ll,
    })
}

/// The zone set a robot must obey, in the map frame of its session (on datum `datum_id`).
pub fn zone_set_for(
    zones: &[ZoneRecord],
    version: u64,
    session: &Session,
    datum_id: &str,
) -> ZoneSet {
    let datum = session.datum;
    ZoneSet {
        version,
        session_id: session.session_id.clone(),
        zones: zones
            .iter()
            .filter_map(|z| {
                Some(Zone {
                    zone_id: z.zone_id.clone(),
                    name: z.name.clone(),
                    kind: z.wire_kind(),
                    polygon_m: z.polygon_in(datum_id, datum.as_ref())?,
                })
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn datum() -> Datum {
        Datum {
            lat_deg: 47.3769,
            lon_deg: 8.5417,
            h_m: 408.0,
        }
    }

    #[test]
    fn map_frame_zones_convert_to_wgs84_and_back() {
        let text = r#"{"type":"Feature","properties":{"kind":"slow","speed_mps":0.2,"name":"gate"},
            "geometry":{"type":"Polygon","coordinates":[[[4,-2],[8,-2],[8,2],[4,2],[4,-2]]]}}"#;
        let d = datum();
        let z = from_geojson(
            text,
            &PostFrame::Map("d0".into(), Some(d)),
            ("d0", Some(&d)),
            "z1",
        )
        .unwrap();
        assert_eq!(z.len(), 1);
        assert_eq!(z[0].polygon_m.len(), 4);
        assert_eq!(z[0].wire_kind(), ZoneKind::Slow { speed_mps: 0.2 });
        // Out as WGS-84 GeoJSON, in again: the same polygon to a millimetre.
        let f = z[0].to_feature(None).unwrap();
        let again =
            from_geojson(&f.to_string(), &PostFrame::Wgs84, ("d0", Some(&d)), "z2").unwrap();
        for (a, b) in z[0].polygon_m.iter().zip(&again[0].polygon_m) {
            assert!(
                (a.0 - b.0).abs() < 1e-3 && (a.1 - b.1).abs() < 1e-3,
                "{a:?} {b:?}"
            );
        }
        // Another datum 10 m east sees it 10 m further west.
        let east = common::geo::enu_to_lla(&d, &nalgebra::Vector3::new(10.0, 0.0, 0.0));
        let d1 = Datum {
            lat_deg: east.lat_deg,
            lon_deg: east.lon_deg,
            h_m: d.h_m,
        };
        let p = z[0].polygon_in("d1", Some(&d1)).unwrap();
        assert!((p[0].0 - (4.0 - 10.0)).abs() < 0.01, "{p:?}");
        // A local frame cannot take a zone of another datum.
        assert!(z[0].polygon_in("local-x", None).is_none());
    }

    #[test]
    fn bad_zones_are_clear_errors() {
        let d = datum();
        let f = |body: &str| {
            from_geojson(body, &PostFrame::Wgs84, ("d0", Some(&d)), "z")
                .unwrap_err()
                .0
        };
        assert!(f("nope").contains("not GeoJSON"));
        assert!(f(r#"{"type":"Feature","properties":{},"geometry":{"type":"Polygon","coordinates":[[[8.54,47.37],[8.55,47.37],[8.55,47.38],[8.54,47.37]]]}}"#).contains("kind"));
        assert!(f(r#"{"type":"Feature","properties":{"kind":"slow"},"geometry":{"type":"Polygon","coordinates":[[[8.54,47.37],[8.55,47.37],[8.55,47.38],[8.54,47.37]]]}}"#).contains("speed_mps"));
        assert!(f(r#"{"type":"Feature","properties":{"kind":"keep_out"},"geometry":{"type":"Point","coordinates":[8.54,47.37]}}"#).contains("Polygon"));
        assert!(f(r#"{"type":"Feature","properties":{"kind":"keep_out"},"geometry":{"type":"Polygon","coordinates":[[[47.37,98.54],[47.38,98.55],[47.39,98.54],[47.37,98.54]]]}}"#).contains("range"));
    }
}
