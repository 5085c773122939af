//! `/api/missions`: saved waypoint missions (JSON, GPX, GeoJSON), and their runs on robots.

use axum::body::Bytes;
use axum::extract::{Path as UrlPath, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::{json, Value};

use super::{bad, internal, json_body, known_robot, not_found, ApiError, ApiResult, AppState};
use crate::missions::runner::{Run, SendAs};
use crate::missions::{self, Mission, MissionFrame};
use crate::station::now_unix_ms;
use crate::store::StoreOp;

fn geodetic(st: &AppState, datum_id: &str) -> ApiResult<Option<common::msg::Datum>> {
    let d = st.inner.datums.lock().unwrap_or_else(|p| p.into_inner());
    if !d.rows.contains_key(datum_id) {
        return Err(bad(format!("unknown datum {datum_id}")));
    }
    Ok(d.geodetic(datum_id))
}

async fn save(st: &AppState, mut m: Mission) -> ApiResult<Mission> {
    let d = geodetic(st, &m.datum_id)?;
    m.normalise(d.as_ref()).map_err(bad)?;
    m.saved_unix_ms = now_unix_ms();
    st.inner.store(StoreOp::Mission {
        mission_id: m.mission_id.clone(),
        name: m.name.clone(),
        saved_unix_ms: m.saved_unix_ms,
        json: serde_json::to_string(&m).map_err(internal)?,
    });
    st.inner.flush_store_async().await;
    st.inner
        .missions
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(m.mission_id.clone(), m.clone());
    st.inner
        .emit(json!({"type": "missions", "mission_id": m.mission_id}).to_string());
    Ok(m)
}

fn new_id() -> String {
    format!("m-{}", now_unix_ms())
}

/// `GET /api/missions`: summaries, newest first.
pub async fn list(State(st): State<AppState>) -> Json<Value> {
    let m = st.inner.missions.lock().unwrap_or_else(|p| p.into_inner());
    let mut v: Vec<&Mission> = m.values().collect();
    v.sort_by_key(|m| std::cmp::Reverse(m.saved_unix_ms));
    Json(Value::Array(v.iter().map(|m| m.summary()).collect()))
}

fn find(st: &AppState, id: &str) -> ApiResult<Mission> {
    st.inner
        .missions
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .get(id)
        .cloned()
        .ok_or_else(|| not_found(format!("unknown mission {id}")))
}

/// `GET /api/missions/{id}`.
pub async fn get_one(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> ApiResult<Json<Mission>> {
    Ok(Json(find(&st, &id)?))
}

/// `POST /api/missions` with a mission (no id): 201 with the saved mission.
pub async fn create(
    State(st): State<AppState>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Mission>)> {
    let mut m: Mission = json_body(&body)?;
    m.mission_id = new_id();
    Ok((StatusCode::CREATED, Json(save(&st, m).await?)))
}

/// `PUT /api/missions/{id}`: replaces it.
pub async fn update(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
    body: Bytes,
) -> ApiResult<Json<Mission>> {
    find(&st, &id)?;
    let mut m: Mission = json_body(&body)?;
    m.mission_id = id;
    Ok(Json(save(&st, m).await?))
}

/// `DELETE /api/missions/{id}`.
pub async fn delete(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    if st
        .inner
        .missions
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .remove(&id)
        .is_none()
    {
        return Err(not_found(format!("unknown mission {id}")));
    }
    st.inner.store(StoreOp::DeleteMission(id.clone()));
    st.inner.flush_store_async().await;
    st.inner
        .emit(json!({"type": "missions", "mission_id": id}).to_string());
    Ok(Json(json!({"ok": true, "deleted": id})))
}

/// `?format=gpx|geojson&datum_id=D&name=N`.
#[derive(Deserialize)]
pub struct ImportQuery {
    format: Option<String>,
    datum_id: String,
    name: Option<String>,
}

/// `POST /api/missions/import`: a GPX or GeoJSON body becomes a saved mission.
pub async fn import(
    State(st): State<AppState>,
    Query(q): Query<ImportQuery>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Mission>)> {
    let d = geodetic(&st, &q.datum_id)?.ok_or_else(|| {
        bad(format!(
            "datum {} has no position on Earth: GPX and GeoJSON need one",
            q.datum_id
        ))
    })?;
    let name = q.name.unwrap_or_default();
    let looks_json = body.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{');
    let mut m = match q.format.as_deref() {
        Some("gpx") => missions::from_gpx(&body, &name, &q.datum_id, &d),
        Some("geojson") => {
            let text = std::str::from_utf8(&body).map_err(|_| bad("the body is not UTF-8"))?;
            missions::from_geojson(text, &name, &q.datum_id, &d)
        }
        None if looks_json => {
            let text = std::str::from_utf8(&body).map_err(|_| bad("the body is not UTF-8"))?;
            missions::from_geojson(text, &name, &q.datum_id, &d)
        }
        None => missions::from_gpx(&body, &name, &q.datum_id, &d),
        Some(f) => return Err(bad(format!("format {f:?}: use gpx or geojson"))),
    }
    .map_err(bad)?;
    m.mission_id = new_id();
    Ok((StatusCode::CREATED, Json(save(&st, m).await?)))
}

/// `GET /api/missions/{id}/gpx`.
pub async fn gpx(State(st): State<AppState>, UrlPath(id): UrlPath<String>) -> ApiResult<Response> {
    let m = find(&st, &id)?;
    let text = missions::to_gpx(&m).map_err(bad)?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/gpx+xml".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{id}.gpx\""),
            ),
        ],
        text,
    )
        .into_response())
}

/// `GET /api/missions/{id}/geojson`.
pub async fn geojson(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> ApiResult<Response> {
    let m = find(&st, &id)?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/geo+json".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{id}.geojson\""),
            ),
        ],
        missions::to_geojson(&m).to_string(),
    )
        .into_response())
}

/// `GET /api/missions/runs`: the last run of each robot.
pub async fn runs(State(st): State<AppState>) -> Json<Value> {
    let r = st.inner.runs.lock().unwrap_or_else(|p| p.into_inner());
    Json(Value::Array(
        r.values()
            .map(|r| serde_json::to_value(r).unwrap_or(Value::Null))
            .collect(),
    ))
}

#[derive(Deserialize)]
struct StartBody {
    mission_id: String,
}

/// `POST /api/robots/{robot}/mission` `{"mission_id"}`: starts the mission on the robot.
pub async fn start_run(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    known_robot(&st, &robot)?;
    let b: StartBody = json_body(&body)?;
    let m = find(&st, &b.mission_id)?;
    let robot_datum = {
        let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
        f.robots.get(&robot).and_then(|r| r.datum_id.clone())
    };
    let geodetic_wps = m.waypoints.iter().all(|w| w.lat_deg.is_some());
    let send_as = match (m.frame, robot_datum.as_deref() == Some(m.datum_id.as_str())) {
        (MissionFrame::Gnss, _) => SendAs::Gnss,
        (MissionFrame::Map, true) => SendAs::MapXy,
        (MissionFrame::Map, false) if geodetic_wps => SendAs::Gnss,
        _ => {
            return Err(ApiError(
                StatusCode::CONFLICT,
                format!(
                    "mission {:?} is drawn on datum {} and {robot} is on {}: neither has a position on Earth to convert through",
                    m.name,
                    m.datum_id,
                    robot_datum.as_deref().unwrap_or("no datum yet")
                ),
                None,
            ))
        }
    };
    // Every waypoint must be allowed before the first one is sent.
    if let Some(set) = st.inner.zone_set(&robot) {
        if send_as == SendAs::MapXy {
            for (i, w) in m.waypoints.iter().enumerate() {
                common::command::check_goal_zones((w.x_m, w.y_m), &set.zones).map_err(
                    |mut r| {
                        r.message = format!("mission: waypoint {}: {}", i + 1, r.message);
                        r
                    },
                )?;
            }
        }
    }
    let run = Run::new(&robot, m, send_as, now_unix_ms());
    let v = serde_json::to_value(&run).map_err(internal)?;
    st.inner
        .runs
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(robot.clone(), run);
    st.inner
        .emit(json!({"type": "mission_run", "run": v}).to_string());
    Ok((StatusCode::ACCEPTED, Json(json!({"ok": true, "run": v}))))
}

/// `POST /api/robots/{robot}/mission/{continue|cancel}`.
pub async fn run_action(
    State(st): State<AppState>,
    UrlPath((robot, action)): UrlPath<(String, String)>,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let now = now_unix_ms();
    let (acts, v) = {
        let mut runs = st.inner.runs.lock().unwrap_or_else(|p| p.into_inner());
        let run = runs
            .get_mut(&robot)
            .filter(|r| !r.ended())
            .ok_or_else(|| not_found(format!("no mission running on {robot}")))?;
        let acts = match action.as_str() {
            "continue" => {
                let mut next = || {
                    st.inner
                        .goal_seq
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                };
                let a = run.resume(now, &mut next);
                if a.is_empty() && !run.ended() {
                    return Err(bad("the mission is not waiting for the operator"));
                }
                a
            }
            "cancel" => run.cancel(now),
            a => return Err(bad(format!("unknown action {a:?}: continue or cancel"))),
        };
        (acts, serde_json::to_value(&*run).map_err(internal)?)
    };
    for a in acts {
        st.inner.send_run_action(&robot, a).await;
    }
    st.inner
        .emit(json!({"type": "mission_run", "run": v}).to_string());
    Ok((StatusCode::ACCEPTED, Json(json!({"ok": true, "run": v}))))
}
