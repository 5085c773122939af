//! Waypoint missions: what the operator draws (or imports) and the station keeps and runs.
//!
//! A mission is an ordered list of waypoints on one datum's map, each with its position in that
//! map frame (and in WGS-84 when the datum has one) and actions done on arrival: set the speed
//! limit, wait N seconds, pause until the operator says go on. A `gnss` mission sends its
//! waypoints as lat/lon goals (any robot with a fix can run it); a `map` mission as map x/y.
//! [`runner`] runs one on a robot.
//!
//! GPX (`<rte>` route points, else track points) and GeoJSON (a LineString Feature, or Point
//! Features in order, with the actions in `properties`) go both ways.

pub mod runner;

use common::msg::Datum;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

/// One waypoint and what to do there.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Waypoint {
    /// Map x (east) in the mission's datum, metres.
    pub x_m: f64,
    /// Map y (north), metres.
    pub y_m: f64,
    /// Latitude, degrees, when the datum has a position on Earth.
    #[serde(default)]
    pub lat_deg: Option<f64>,
    /// Longitude, degrees.
    #[serde(default)]
    pub lon_deg: Option<f64>,
    /// On arrival: set the robot's speed limit to this, m/s (it applies to the legs after).
    #[serde(default)]
    pub speed_mps: Option<f32>,
    /// On arrival: wait this long, seconds.
    #[serde(default)]
    pub wait_s: f64,
    /// On arrival: wait for the operator to continue.
    #[serde(default)]
    pub pause: bool,
}

/// How waypoints are sent to the robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MissionFrame {
    /// As map x/y (robots on the mission's datum, or converted through lat/lon).
    #[default]
    Map,
    /// As GNSS lat/lon goals (the robot converts through its own datum).
    Gnss,
}

/// A mission as stored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Mission {
    /// Id (`m-<unix ms>`), given by the station.
    #[serde(default)]
    pub mission_id: String,
    /// Name.
    pub name: String,
    /// The datum whose map the waypoints were drawn on.
    pub datum_id: String,
    /// How waypoints are sent.
    #[serde(default)]
    pub frame: MissionFrame,
    /// Waypoints in order.
    pub waypoints: Vec<Waypoint>,
    /// Saved, Unix ms.
    #[serde(default)]
    pub saved_unix_ms: u64,
}

/// Most waypoints of one mission.
pub const MAX_WAYPOINTS: usize = 1000;

impl Mission {
    /// Checks the mission and fills in lat/lon from x/y (or x/y from lat/lon) through `datum`.
    pub fn normalise(&mut self, datum: Option<&Datum>) -> Result<(), String> {
        if self.name.trim().is_empty() || self.name.chars().count() > 200 {
            return Err("a mission needs a name of 1-200 characters".into());
        }
        if self.waypoints.is_empty() || self.waypoints.len() > MAX_WAYPOINTS {
            return Err(format!(
                "{} waypoints: a mission needs 1 to {MAX_WAYPOINTS}",
                self.waypoints.len()
            ));
        }
        if self.frame == MissionFrame::Gnss && datum.is_none() {
            return Err(format!(
                "datum {} has no position on Earth: a GNSS mission needs one",
                self.datum_id
            ));
        }
        for (i, w) in self.waypoints.iter_mut().enumerate() {
            let n = i + 1;
            if !(w.x_m.is_finite() && w.y_m.is_finite()) {
                return Err(format!("waypoint {n}: x and y must be finite"));
            }
            if !(w.wait_s.is_finite() && (0.0..=86_400.0).contains(&w.wait_s)) {
                return Err(format!("waypoint {n}: wait_s must be 0-86400"));
            }
            if let Some(v) = w.speed_mps {
                if !(v.is_finite() && v > 0.0 && v <= 10.0) {
                    return Err(format!("waypoint {n}: speed_mps must be within (0, 10]"));
                }
            }
            if let Some(d) = datum {
                let g = common::geo::enu_to_lla(d, &nalgebra::Vector3::new(w.x_m, w.y_m, 0.0));
                w.lat_deg = Some(g.lat_deg);
                w.lon_deg = Some(g.lon_deg);
            } else {
                w.lat_deg = None;
                w.lon_deg = None;
            }
        }
        Ok(())
    }

    /// Straight-line length through the waypoints, metres.
    pub fn length_m(&self) -> f64 {
        self.waypoints
            .windows(2)
            .map(|w| (w[1].x_m - w[0].x_m).hypot(w[1].y_m - w[0].y_m))
            .sum()
    }

    /// The summary the list shows.
    pub fn summary(&self) -> Value {
        json!({"mission_id": self.mission_id, "name": self.name, "datum_id": self.datum_id,
               "frame": self.frame, "waypoints": self.waypoints.len(), "length_m": self.length_m(),
               "saved_unix_ms": self.saved_unix_ms})
    }
}

fn ll_to_xy(d: &Datum, lat: f64, lon: f64) -> (f64, f64) {
    let e = common::geo::lla_to_enu(
        d,
        &Datum {
            lat_deg: lat,
            lon_deg: lon,
            h_m: d.h_m,
        },
    );
    (e.x, e.y)
}

fn wp_at(d: &Datum, lat: f64, lon: f64) -> Result<Waypoint, String> {
    if !(lat.is_finite() && lon.is_finite() && lat.abs() <= 90.0 && lon.abs() <= 180.0) {
        return Err(format!("position ({lat}, {lon}) out of range"));
    }
    let (x, y) = ll_to_xy(d, lat, lon);
    Ok(Waypoint {
        x_m: x,
        y_m: y,
        lat_deg: Some(lat),
        lon_deg: Some(lon),
        speed_mps: None,
        wait_s: 0.0,
        pause: false,
    })
}

/// Reads a GPX file's route points (else its track points, else its waypoints) as a mission on
/// `datum`. The actions survive a round trip in each point's `<desc>` (`wait=5 speed=0.3 pause`).
pub fn from_gpx(bytes: &[u8], name: &str, datum_id: &str, d: &Datum) -> Result<Mission, String> {
    let g = gpx::read(std::io::Cursor::new(bytes)).map_err(|e| format!("GPX: {e}"))?;
    let mut pts: Vec<&gpx::Waypoint> = g.routes.iter().flat_map(|r| r.points.iter()).collect();
    if pts.is_empty() {
        pts = g
            .tracks
            .iter()
            .flat_map(|t| t.segments.iter().flat_map(|s| s.points.iter()))
            .collect();
    }
    if pts.is_empty() {
        pts = g.waypoints.iter().collect();
    }
    if pts.is_empty() {
        return Err("GPX has no route, track or waypoints".into());
    }
    let waypoints = pts
        .iter()
        .map(|w| {
            let p = w.point();
            let mut wp = wp_at(d, p.y(), p.x())?;
            if let Some(desc) = &w.description {
                apply_action_text(&mut wp, desc);
            }
            Ok(wp)
        })
        .collect::<Result<Vec<_>, String>>()?;
    let name = if name.is_empty() {
        g.routes
            .first()
            .and_then(|r| r.name.clone())
            .unwrap_or_else(|| "imported".into())
    } else {
        name.to_string()
    };
    Ok(Mission {
        mission_id: String::new(),
        name,
        datum_id: datum_id.to_string(),
        frame: MissionFrame::Map,
        waypoints,
        saved_unix_ms: 0,
    })
}

/// `wait=5 speed=0.3 pause` for a waypoint's actions (GPX `<desc>`).
pub fn action_text(w: &Waypoint) -> String {
    let mut parts = Vec::new();
    if w.wait_s > 0.0 {
        parts.push(format!("wait={}", w.wait_s));
    }
    if let Some(v) = w.speed_mps {
        parts.push(format!("speed={v}"));
    }
    if w.pause {
        parts.push("pause".into());
    }
    parts.join(" ")
}

fn apply_action_text(w: &mut Waypoint, text: &str) {
    for tok in text.split_whitespace() {
        match tok.split_once('=') {
            Some(("wait", v)) => w.wait_s = v.parse().unwrap_or(0.0),
            Some(("speed", v)) => w.speed_mps = v.parse().ok(),
            None if tok == "pause" => w.pause = true,
            _ => {}
        }
    }
}

/// The mission as GPX 1.1 (a route; actions in each point's `<desc>`).
pub fn to_gpx(m: &Mission) -> Result<String, String> {
    let mut out = String::from(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<gpx version=\"1.1\" creator=\"terranav\" xmlns=\"http://www.topografix.com/GPX/1/1\">\n",
    );
    out.push_str(&format!(
        "<rte><name>{}</name>\n",
        crate::api::xml_escape(&m.name)
    ));
    for (i, w) in m.waypoints.iter().enumerate() {
        let (Some(lat), Some(lon)) = (w.lat_deg, w.lon_deg) else {
            return Err(format!(
                "datum {} has no position on Earth: no lat/lon for GPX",
                m.datum_id
            ));
        };
        out.push_str(&format!(
            "<rtept lat=\"{lat:.9}\" lon=\"{lon:.9}\"><name>{}</name>",
            i + 1
        ));
        let a = action_text(w);
        if !a.is_empty() {
            out.push_str(&format!("<desc>{a}</desc>"));
        }
        out.push_str("</rtept>\n");
    }
    out.push_str("</rte>\n</gpx>\n");
    Ok(out)
}

/// The mission as a GeoJSON FeatureCollection: one Point per waypoint (in order, actions in
/// properties) and the LineString through them.
pub fn to_geojson(m: &Mission) -> Value {
    let pos = |w: &Waypoint| match (w.lat_deg, w.lon_deg) {
        (Some(la), Some(lo)) => json!([lo, la]),
        _ => json!([w.x_m, w.y_m]),
    };
    let mut features: Vec<Value> = m
        .waypoints
        .iter()
        .enumerate()
        .map(|(i, w)| {
            json!({"type": "Feature", "geometry": {"type": "Point", "coordinates": pos(w)},
                   "properties": {"index": i, "wait_s": w.wait_s, "speed_mps": w.speed_mps, "pause": w.pause}})
        })
        .collect();
    features.push(json!({"type": "Feature",
        "geometry": {"type": "LineString", "coordinates": m.waypoints.iter().map(pos).collect::<Vec<_>>()},
        "properties": {"name": m.name, "mission_id": m.mission_id, "datum_id": m.datum_id, "frame": m.frame}}));
    json!({"type": "FeatureCollection", "features": features})
}

/// Reads a GeoJSON mission (lon/lat): Point features in order (actions from their properties),
/// else the first LineString's positions.
pub fn from_geojson(text: &str, name: &str, datum_id: &str, d: &Datum) -> Result<Mission, String> {
    let gj: geojson::GeoJson = text.parse().map_err(|e| format!("not GeoJSON: {e}"))?;
    let features = match gj {
        geojson::GeoJson::FeatureCollection(c) => c.features,
        geojson::GeoJson::Feature(f) => vec![f],
        geojson::GeoJson::Geometry(g) => vec![geojson::Feature {
            geometry: Some(g),
            ..geojson::Feature::default()
        }],
    };
    let mut points = Vec::new();
    let mut line = None;
    let mut line_name = None;
    for f in &features {
        let Some(g) = &f.geometry else { continue };
        let props = f.properties.as_ref();
        match &g.value {
            geojson::Value::Point(p) if p.len() >= 2 => {
                let mut w = wp_at(d, p[1], p[0])?;
                if let Some(pr) = props {
                    w.wait_s = pr.get("wait_s").and_then(Value::as_f64).unwrap_or(0.0);
                    w.speed_mps = pr
                        .get("speed_mps")
                        .and_then(Value::as_f64)
                        .map(|v| v as f32);
                    w.pause = pr.get("pause").and_then(Value::as_bool).unwrap_or(false);
                }
                points.push(w);
            }
            geojson::Value::LineString(ls) if line.is_none() => {
                line = Some(
                    ls.iter()
                        .map(|p| match p.as_slice() {
                            [lon, lat, ..] => wp_at(d, *lat, *lon),
                            _ => Err("a position needs two numbers".to_string()),
                        })
                        .collect::<Result<Vec<_>, String>>()?,
                );
                line_name = props
                    .and_then(|p| p.get("name"))
                    .and_then(Value::as_str)
                    .map(str::to_string);
            }
            _ => {}
        }
    }
    let waypoints = if points.is_empty() {
        line.ok_or("GeoJSON has no Point or LineString features")?
    } else {
        points
    };
    Ok(Mission {
        mission_id: String::new(),
        name: if name.is_empty() {
            line_name.unwrap_or_else(|| "imported".into())
        } else {
            name.to_string()
        },
        datum_id: datum_id.to_string(),
        frame: MissionFrame::Map,
        waypoints,
        saved_unix_ms: 0,
    })
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

    fn mission() -> Mission {
        let wp = |x: f64, y: f64| Waypoint {
            x_m: x,
            y_m: y,
            lat_deg: None,
            lon_deg: None,
            speed_mps: None,
            wait_s: 0.0,
            pause: false,
        };
        let mut m = Mission {
            mission_id: "m-1".into(),
            name: "square & back".into(),
            datum_id: "d0".into(),
            frame: MissionFrame::Map,
            waypoints: vec![wp(3.0, 0.0), wp(6.0, 0.0), wp(6.0, 4.0), wp(3.0, 4.0)],
            saved_unix_ms: 1,
        };
        m.waypoints[1].wait_s = 2.5;
        m.waypoints[2].speed_mps = Some(0.3);
        m.waypoints[3].pause = true;
        m.normalise(Some(&datum())).unwrap();
        m
    }

    fn same(a: &Mission, b: &Mission) {
        assert_eq!(a.waypoints.len(), b.waypoints.len());
        for (p, q) in a.waypoints.iter().zip(&b.waypoints) {
            assert!(
                (p.x_m - q.x_m).abs() < 1e-3 && (p.y_m - q.y_m).abs() < 1e-3,
                "{p:?} {q:?}"
            );
            assert_eq!(
                (p.wait_s, p.speed_mps, p.pause),
                (q.wait_s, q.speed_mps, q.pause)
            );
        }
    }

    #[test]
    fn gpx_and_geojson_round_trip_with_actions() {
        let m = mission();
        let g = to_gpx(&m).unwrap();
        let back = from_gpx(g.as_bytes(), "", "d0", &datum()).unwrap();
        assert_eq!(back.name, m.name);
        same(&m, &back);
        let j = to_geojson(&m).to_string();
        let back = from_geojson(&j, "x", "d0", &datum()).unwrap();
        same(&m, &back);
        assert!((m.length_m() - 10.0).abs() < 1e-9);
    }

    #[test]
    fn bad_missions_are_clear_errors() {
        let mut m = mission();
        m.waypoints[0].wait_s = -1.0;
        assert!(m
            .normalise(Some(&datum()))
            .unwrap_err()
            .contains("waypoint 1"));
        let mut m = mission();
        m.waypoints.clear();
        assert!(m.normalise(None).unwrap_err().contains("waypoints"));
        let mut m = mission();
        m.frame = MissionFrame::Gnss;
        assert!(m.normalise(None).unwrap_err().contains("GNSS"));
        assert!(from_gpx(b"<gpx", "", "d0", &datum())
            .unwrap_err()
            .starts_with("GPX"));
        assert!(from_geojson("{}", "", "d0", &datum()).is_err());
    }
}
