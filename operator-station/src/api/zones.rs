//! `/api/zones`: keep-out and slow zones as GeoJSON, and the station's own goal check against
//! them (the robot checks again: it may have zones the station does not know of yet).

use axum::body::Bytes;
use axum::extract::{Path as UrlPath, Query, State};
use axum::http::StatusCode;
use axum::Json;
use common::msg::{Datum, GoalTarget};
use serde::Deserialize;
use serde_json::{json, Value};

use super::{bad, not_found, ApiResult, AppState};
use crate::station::now_unix_ms;
use crate::store::StoreOp;
use crate::zones::{from_geojson, PostFrame};

/// `?frame=map&datum_id=D` (map x/y of datum D) or nothing / `?datum_id=D` (lon/lat, drawn on D).
#[derive(Deserialize)]
pub struct FrameQuery {
    frame: Option<String>,
    datum_id: Option<String>,
}

fn datum_of(st: &AppState, id: &str) -> ApiResult<Option<Datum>> {
    let d = st.inner.datums.lock().unwrap_or_else(|p| p.into_inner());
    if !d.rows.contains_key(id) {
        return Err(not_found(format!("unknown datum {id}")));
    }
    Ok(d.geodetic(id))
}

/// The datum to draw lon/lat zones on when none is named: the first with a position on Earth.
fn default_geodetic_datum(st: &AppState) -> Option<(String, Datum)> {
    let d = st.inner.datums.lock().unwrap_or_else(|p| p.into_inner());
    d.rows
        .keys()
        .find_map(|id| d.geodetic(id).map(|g| (id.clone(), g)))
}

/// `GET /api/zones[?frame=map&datum_id=D]`: a FeatureCollection.
pub async fn list(
    State(st): State<AppState>,
    Query(q): Query<FrameQuery>,
) -> ApiResult<Json<Value>> {
    let frame = match (q.frame.as_deref(), q.datum_id) {
        (Some("map"), Some(id)) => Some((id.clone(), datum_of(&st, &id)?)),
        (Some("map"), None) => return Err(bad("frame=map needs datum_id")),
        (Some("wgs84") | None, _) => None,
        (Some(f), _) => return Err(bad(format!("frame {f:?}: use map or wgs84"))),
    };
    let z = st.inner.zones.lock().unwrap_or_else(|p| p.into_inner());
    let features: Vec<Value> = z
        .records
        .iter()
        .filter_map(|r| r.to_feature(frame.as_ref().map(|(id, d)| (id.as_str(), d.as_ref()))))
        .collect();
    Ok(Json(
        json!({"type": "FeatureCollection", "version": z.version, "features": features}),
    ))
}

/// `GET /api/zones/{id}`: one Feature.
pub async fn get_one(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    let z = st.inner.zones.lock().unwrap_or_else(|p| p.into_inner());
    z.records
        .iter()
        .find(|r| r.zone_id == id)
        .and_then(|r| r.to_feature(None))
        .map(Json)
        .ok_or_else(|| not_found(format!("unknown zone {id}")))
}

/// `POST /api/zones[?frame=map&datum_id=D]` with a GeoJSON Feature or FeatureCollection.
pub async fn create(
    State(st): State<AppState>,
    Query(q): Query<FrameQuery>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let text = std::str::from_utf8(&body).map_err(|_| bad("the body is not UTF-8"))?;
    let (frame, datum_id, datum) = match (q.frame.as_deref(), q.datum_id) {
        (Some("map"), Some(id)) => {
            let d = datum_of(&st, &id)?;
            (PostFrame::Map(id.clone(), d), id, d)
        }
        (Some("map"), None) => return Err(bad("frame=map needs datum_id")),
        (Some("wgs84") | None, Some(id)) => {
            let d = datum_of(&st, &id)?;
            (PostFrame::Wgs84, id, d)
        }
        (Some("wgs84") | None, None) => {
            let (id, d) = default_geodetic_datum(&st).ok_or_else(|| {
                bad("no datum with a position on Earth yet: post map x/y with ?frame=map&datum_id=D")
            })?;
            (PostFrame::Wgs84, id, Some(d))
        }
        (Some(f), _) => return Err(bad(format!("frame {f:?}: use map or wgs84"))),
    };
    let base = format!("z-{}", now_unix_ms());
    let recs =
        from_geojson(text, &frame, (&datum_id, datum.as_ref()), &base).map_err(|e| bad(e.0))?;
    for r in &recs {
        st.inner.store(StoreOp::Zone {
            zone_id: r.zone_id.clone(),
            json: serde_json::to_string(r).map_err(super::internal)?,
        });
    }
    st.inner
        .zones
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .records
        .extend(recs.iter().cloned());
    st.inner.flush_store_async().await;
    st.inner.zones_changed();
    let features: Vec<Value> = recs.iter().filter_map(|r| r.to_feature(None)).collect();
    Ok((
        StatusCode::CREATED,
        Json(json!({"type": "FeatureCollection", "features": features})),
    ))
}

/// `DELETE /api/zones/{id}`.
pub async fn delete(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    let removed = {
        let mut z = st.inner.zones.lock().unwrap_or_else(|p| p.into_inner());
        let n = z.records.len();
        z.records.retain(|r| r.zone_id != id);
        n != z.records.len()
    };
    if !removed {
        return Err(not_found(format!("unknown zone {id}")));
    }
    st.inner.store(StoreOp::DeleteZone(id.clone()));
    st.inner.flush_store_async().await;
    st.inner.zones_changed();
    Ok(Json(json!({"ok": true, "deleted": id})))
}

/// Refuses a goal inside a keep-out zone before it is sent (422, code `goal_in_keep_out`).
pub fn check_goal(st: &AppState, robot: &str, target: &GoalTarget) -> ApiResult<()> {
    let Some(set) = st.inner.zone_set(robot) else {
        return Ok(());
    };
    let goal = match *target {
        GoalTarget::Map { x_m, y_m } => (x_m, y_m),
        GoalTarget::Gnss {
            lat_deg, lon_deg, ..
        } => {
            let session = {
                let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
                f.robots.get(robot).and_then(|r| r.session.clone())
            };
            let Some(d) = session.and_then(|s| s.datum) else {
                return Ok(());
            };
            let e = common::geo::lla_to_enu(
                &d,
                &Datum {
                    lat_deg,
                    lon_deg,
                    h_m: d.h_m,
                },
            );
            (e.x, e.y)
        }
    };
    common::command::check_goal_zones(goal, &set.zones)?;
    Ok(())
}
