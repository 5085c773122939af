//! axum REST + WebSocket API for the browser UI, exactly as `operator-station/API.md`, and the
//! UI's static files, served over TLS by [`tls`] when asked (always off loopback). Zones,
//! missions, alerts, the basemap and the map's zoom pyramid have their own modules.

mod alerts;
mod basemap;
mod missions;
mod pyramid;
mod role;
pub mod tls;
mod zones;

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path as UrlPath, Query, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use common::command::{check_goal, BoundsM, CommandLimits, RobotContext};
use common::grid::TileIndex;
use common::keys::{self, RobotId, Topic};
use common::msg::{
    self, DriveCmd, GoalCmd, GoalTarget, Route, RouteCmd, RouteDirection, RoutePoint, SpeedCmd,
    StopCmd,
};
use serde::Deserialize;
use serde_json::{json, Value};
use tower_http::services::ServeDir;

use crate::station::{now_unix_ms, route_row, Inner, VERSION};
use crate::store::{self, StoreOp};
pub use role::Role;

/// Shared state of the HTTP server.
#[derive(Clone)]
pub struct AppState {
    /// The station.
    pub inner: Arc<Inner>,
    /// Required bearer token, if any.
    pub token: Option<String>,
    /// The operator's background map, if given.
    pub basemap: Option<Arc<crate::basemap::Basemap>>,
    /// A station, or a read-only monitor (whose command routes are refused).
    pub role: Role,
}

/// An API error: status plus `{"error": ...}`, and the refusal's stable code when there is one
/// (`{"error": ..., "code": "goal_in_keep_out"}`).
#[derive(Debug)]
pub struct ApiError(pub StatusCode, pub String, pub Option<&'static str>);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        match self.2 {
            Some(code) => (self.0, Json(json!({"error": self.1, "code": code}))).into_response(),
            None => (self.0, Json(json!({"error": self.1}))).into_response(),
        }
    }
}

impl From<common::command::Refusal> for ApiError {
    fn from(r: common::command::Refusal) -> Self {
        ApiError(
            StatusCode::UNPROCESSABLE_ENTITY,
            r.message,
            Some(r.code.as_str()),
        )
    }
}

fn bad(m: impl Into<String>) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, m.into(), None)
}
fn not_found(m: impl Into<String>) -> ApiError {
    ApiError(StatusCode::NOT_FOUND, m.into(), None)
}
fn internal(m: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::INTERNAL_SERVER_ERROR, m.to_string(), None)
}

type ApiResult<T> = Result<T, ApiError>;

/// Where the UI's files are: `web/dist` if built, else `web/`; Leaflet from `web/node_modules`.
pub fn find_web_dir() -> Option<PathBuf> {
    let mut cands = Vec::new();
    if let Ok(cwd) = std::env::current_dir() {
        cands.push(cwd.join("web"));
    }
    if let Ok(exe) = std::env::current_exe() {
        for a in exe.ancestors().skip(1).take(4) {
            cands.push(a.join("web"));
        }
    }
    cands.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../web"));
    cands
        .into_iter()
        .find(|p| p.join("index.html").is_file() || p.join("dist/index.html").is_file())
}

/// The router: `/api/...` plus static files from `web` (None: API only).
pub fn router(state: AppState, web: Option<PathBuf>) -> Router {
    let api = Router::new()
        .route("/api/health", get(health))
        .route("/api/robots", get(robots))
        .route("/api/datums", get(datums))
        .route("/api/map/{datum_id}/tiles", get(tiles_index))
        .route("/api/map/{datum_id}/tile/{tx}/{typng}", get(tile_png))
        .route(
            "/api/map/{datum_id}/pyramid/{level}/{tx}/{typng}",
            get(pyramid::tile),
        )
        .route("/api/map/{datum_id}/history", get(pyramid::history_info))
        .route(
            "/api/map/{datum_id}/history/{t_unix_ms}/{level}/{tx}/{typng}",
            get(pyramid::history_tile),
        )
        .route("/api/sessions", get(sessions))
        .route("/api/sessions/{session_id}/track", get(track))
        .route("/api/routes", get(routes))
        .route("/api/routes/import", post(route_import))
        .route("/api/routes/{route_id}", get(route_get))
        .route("/api/routes/{route_id}/gpx", get(route_gpx))
        .route("/api/geo/convert", get(geo_convert))
        .route("/api/robots/{robot}/goal", post(cmd_goal))
        .route("/api/robots/{robot}/stop", post(cmd_stop))
        .route("/api/robots/{robot}/drive", post(cmd_drive))
        .route("/api/robots/{robot}/speed", post(cmd_speed))
        .route("/api/robots/{robot}/route", post(cmd_route))
        .route("/api/robots/{robot}/mission", post(missions::start_run))
        .route(
            "/api/robots/{robot}/mission/{action}",
            post(missions::run_action),
        )
        .route("/api/zones", get(zones::list).post(zones::create))
        .route(
            "/api/zones/{zone_id}",
            get(zones::get_one).delete(zones::delete),
        )
        .route("/api/missions", get(missions::list).post(missions::create))
        .route("/api/missions/import", post(missions::import))
        .route("/api/missions/runs", get(missions::runs))
        .route(
            "/api/missions/{mission_id}",
            get(missions::get_one)
                .put(missions::update)
                .delete(missions::delete),
        )
        .route("/api/missions/{mission_id}/gpx", get(missions::gpx))
        .route("/api/missions/{mission_id}/geojson", get(missions::geojson))
        .route("/api/alerts", get(alerts::list))
        .route("/api/alerts/ack", post(alerts::ack_all))
        .route("/api/alerts/{id}/ack", post(alerts::ack))
        .route("/api/basemap", get(basemap::info))
        .route("/api/basemap/{z}/{x}/{y}", get(basemap::tile))
        .route("/api/ws", get(ws))
        .fallback(|| async { not_found("no such API endpoint") })
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            role::refuse_commands,
        ))
        .layer(axum::middleware::from_fn(json_errors))
        .layer(axum::middleware::from_fn_with_state(state.clone(), auth))
        .with_state(state);
    let mut app = Router::new().merge(api);
    if let Some(web) = web {
        let leaflet = web.join("node_modules/leaflet/dist");
        if leaflet.is_dir() {
            app = app.nest_service("/vendor/leaflet", ServeDir::new(leaflet));
        }
        let root = if web.join("dist/index.html").is_file() {
            web.join("dist")
        } else {
            web
        };
        app = app.fallback_service(ServeDir::new(root));
    }
    app
}

async fn auth(State(st): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(tok) = &st.token {
        let header_ok = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(|t| t == tok)
            .unwrap_or(false);
        let query_ok = req
            .uri()
            .query()
            .map(|q| {
                q.split('&')
                    .any(|kv| kv.strip_prefix("token=").map(|t| t == tok).unwrap_or(false))
            })
            .unwrap_or(false);
        if !(header_ok || query_ok) {
            return ApiError(
                StatusCode::UNAUTHORIZED,
                "missing or wrong token".into(),
                None,
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// Errors that axum itself produces (405 wrong method with an empty body, 413 body too large as
/// plain text, 415, 422 ...) become `{"error": ...}` like every other API error, keeping their
/// status and headers (e.g. `Allow`), so the UI can always show the reason.
async fn json_errors(req: Request, next: Next) -> Response {
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let res = next.run(req).await;
    let status = res.status();
    let is_json = res
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return res;
    }
    let (mut parts, body) = res.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let detail = String::from_utf8_lossy(&text).trim().to_string();
    let reason = match (status, detail.is_empty()) {
        (StatusCode::METHOD_NOT_ALLOWED, _) => {
            let allow = parts
                .headers
                .get(header::ALLOW)
                .and_then(|v| v.to_str().ok())
                .unwrap_or("")
                .to_string();
            if allow.is_empty() {
                format!("{method} is not allowed on {path}")
            } else {
                format!("{method} is not allowed on {path} (allowed: {allow})")
            }
        }
        (_, false) => detail,
        (_, true) => status
            .canonical_reason()
            .unwrap_or("request failed")
            .to_string(),
    };
    let body = json!({ "error": reason }).to_string();
    parts.headers.insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static("application/json"),
    );
    parts.headers.remove(header::CONTENT_LENGTH);
    Response::from_parts(parts, axum::body::Body::from(body))
}

async fn health(State(st): State<AppState>) -> Json<Value> {
    let online = st
        .inner
        .fleet
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .online_count();
    let tiles: usize = st
        .inner
        .map
        .read()
        .unwrap_or_else(|p| p.into_inner())
        .datums
        .values()
        .map(|d| d.tiles.len())
        .sum();
    let mut h = json!({"ok": true, "version": VERSION, "robots_online": online, "tiles": tiles,
                       "decode_errors": st.inner.decode_errors.load(Ordering::Relaxed),
                       "restore": st.inner.restore.state()});
    if let (Some(h), Value::Object(role)) = (h.as_object_mut(), st.role.health()) {
        h.extend(role);
    }
    Json(h)
}

/// The robots list as in API.md (also used by the CLI).
pub fn robots_json(inner: &Inner) -> Value {
    let now = Instant::now();
    let f = inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
    let list: Vec<Value> = f
        .robots
        .iter()
        .map(|(id, r)| {
            let (rates, ages) = r.rates_and_ages(now);
            let path: Vec<[f32; 2]> = r
                .path
                .as_ref()
                .map(|p| p.points_m.iter().map(|&(x, y)| [x, y]).collect())
                .unwrap_or_default();
            json!({"robot": id, "online": r.online, "last_seen_unix_ms": r.last_seen_unix_ms,
                   "session": r.session, "datum_id": r.datum_id, "pose": r.pose, "status": r.status,
                   "path": path, "rates_hz": rates, "ages_ms": ages,
                   "pose_latency_ms": r.pose_latency.summary()})
        })
        .collect();
    Value::Array(list)
}

async fn robots(State(st): State<AppState>) -> Json<Value> {
    Json(robots_json(&st.inner))
}

async fn datums(State(st): State<AppState>) -> Json<Value> {
    let rows: Vec<_> = st
        .inner
        .datums
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .rows
        .values()
        .cloned()
        .collect();
    let map = st.inner.map.read().unwrap_or_else(|p| p.into_inner());
    let list: Vec<Value> = rows
        .iter()
        .map(|d| {
            let dm = map.datums.get(&d.datum_id);
            json!({"datum_id": d.datum_id, "lat_deg": d.lat_deg, "lon_deg": d.lon_deg, "h_m": d.h_m,
                   "tiles": dm.map(|m| m.tiles.len()).unwrap_or(0),
                   "bounds_m": dm.and_then(|m| m.bounds_m())})
        })
        .collect();
    Json(Value::Array(list))
}

async fn tiles_index(
    State(st): State<AppState>,
    UrlPath(datum_id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    let lattice = {
        let d = st.inner.datums.lock().unwrap_or_else(|p| p.into_inner());
        d.rows.get(&datum_id).map(crate::station::datum_lattice)
    };
    let map = st.inner.map.read().unwrap_or_else(|p| p.into_inner());
    let dm = map.datums.get(&datum_id);
    let lattice = lattice
        .or(dm.map(|d| d.lattice))
        .ok_or_else(|| not_found(format!("unknown datum {datum_id}")))?;
    let tiles: Vec<Value> = dm
        .map(|d| {
            d.tiles
                .iter()
                .map(|(i, t)| json!({"tx": i.tx, "ty": i.ty, "version": t.version}))
                .collect()
        })
        .unwrap_or_default();
    Ok(Json(
        json!({"cell_size_m": lattice.cell_size_f64(), "tile_cells": lattice.tile_cells, "tiles": tiles}),
    ))
}

async fn tile_png(
    State(st): State<AppState>,
    UrlPath((datum_id, tx, typng)): UrlPath<(String, i32, String)>,
) -> ApiResult<Response> {
    let ty: i32 = typng
        .strip_suffix(".png")
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("tile must be {tx}/{ty}.png"))?;
    let (tile, n) = {
        let map = st.inner.map.read().unwrap_or_else(|p| p.into_inner());
        let dm = map
            .datums
            .get(&datum_id)
            .ok_or_else(|| not_found(format!("unknown datum {datum_id}")))?;
        let t = dm
            .tiles
            .get(&TileIndex { tx, ty })
            .ok_or_else(|| not_found(format!("no tile {tx},{ty} in {datum_id}")))?;
        (t.clone(), dm.lattice.tile_cells)
    };
    let png = tokio::task::spawn_blocking(move || crate::merge::tile_png(&tile, n))
        .await
        .map_err(internal)?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "public, max-age=31536000, immutable"),
        ],
        png,
    )
        .into_response())
}

#[derive(Deserialize)]
struct RobotQuery {
    robot: Option<String>,
}

async fn read<T: Send + 'static>(
    st: &AppState,
    f: impl FnOnce(&rusqlite::Connection) -> Result<T, store::StoreError> + Send + 'static,
) -> ApiResult<T> {
    let inner = st.inner.clone();
    tokio::task::spawn_blocking(move || inner.read(f))
        .await
        .map_err(internal)?
        .map_err(internal)
}

async fn sessions(
    State(st): State<AppState>,
    Query(q): Query<RobotQuery>,
) -> ApiResult<Json<Value>> {
    let rows = read(&st, move |c| store::sessions(c, q.robot.as_deref())).await?;
    let live: Vec<(String, String)> = {
        let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
        f.robots
            .iter()
            .filter(|(_, r)| r.online)
            .filter_map(|(id, r)| {
                r.session
                    .as_ref()
                    .map(|s| (id.clone(), s.session_id.clone()))
            })
            .collect()
    };
    let list: Vec<Value> = rows
        .into_iter()
        .map(|r| {
            let is_live = live.iter().any(|(_, s)| *s == r.session_id);
            let mut v = serde_json::to_value(&r).unwrap_or(Value::Null);
            v["live"] = Value::Bool(is_live);
            v
        })
        .collect();
    Ok(Json(Value::Array(list)))
}

async fn track(
    State(st): State<AppState>,
    UrlPath(session_id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    let sid = session_id.clone();
    let (row, pts) = read(&st, move |c| {
        Ok((store::session(c, &sid)?, store::track(c, &sid)?))
    })
    .await?;
    let row = row.ok_or_else(|| not_found(format!("unknown session {session_id}")))?;
    let points: Vec<Value> = pts
        .iter()
        .map(|(t, x, y, yaw)| json!([t, x, y, yaw]))
        .collect();
    Ok(Json(
        json!({"session_id": row.session_id, "robot": row.robot, "datum_id": row.datum_id, "points": points}),
    ))
}

async fn routes(State(st): State<AppState>) -> ApiResult<Json<Value>> {
    let rows = read(&st, store::routes).await?;
    Ok(Json(serde_json::to_value(rows).map_err(internal)?))
}

async fn load_route(st: &AppState, route_id: &str) -> ApiResult<Route> {
    let id = route_id.to_string();
    let j = read(st, move |c| store::route_json(c, &id))
        .await?
        .ok_or_else(|| not_found(format!("unknown route {route_id}")))?;
    serde_json::from_str(&j).map_err(internal)
}

async fn route_get(
    State(st): State<AppState>,
    UrlPath(route_id): UrlPath<String>,
) -> ApiResult<Json<Route>> {
    Ok(Json(load_route(&st, &route_id).await?))
}

/// A route as GPX 1.1 (points without lat/lon are converted through the datum when known).
pub fn route_gpx_text(r: &Route) -> Result<String, String> {
    let mut out = String::from(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<gpx version=\"1.1\" creator=\"terranav\" xmlns=\"http://www.topografix.com/GPX/1/1\">\n",
    );
    out.push_str(&format!("<rte><name>{}</name>\n", xml_escape(&r.name)));
    for p in &r.points {
        let (lat, lon, h) = match (p.lat_deg, p.lon_deg) {
            (Some(la), Some(lo)) => (la, lo, p.h_m),
            _ => {
                let d = r.datum.ok_or("route has no datum: no lat/lon for GPX")?;
                let g = common::geo::enu_to_lla(&d, &nalgebra::Vector3::new(p.x_m, p.y_m, 0.0));
                (g.lat_deg, g.lon_deg, Some(g.h_m))
            }
        };
        out.push_str(&format!("<rtept lat=\"{lat:.9}\" lon=\"{lon:.9}\">"));
        if let Some(h) = h {
            out.push_str(&format!("<ele>{h:.3}</ele>"));
        }
        out.push_str("</rtept>\n");
    }
    out.push_str("</rte>\n</gpx>\n");
    Ok(out)
}

/// Escapes text for XML.
pub fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

async fn route_gpx(
    State(st): State<AppState>,
    UrlPath(route_id): UrlPath<String>,
) -> ApiResult<Response> {
    let r = load_route(&st, &route_id).await?;
    let gpx = route_gpx_text(&r).map_err(bad)?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/gpx+xml".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{}.gpx\"", route_id.replace('"', "")),
            ),
        ],
        gpx,
    )
        .into_response())
}

/// A route from GPX (route points, else track points, in file order) in the map frame of
/// `datum`: the inverse of [`route_gpx_text`].
pub fn route_from_gpx(
    bytes: &[u8],
    datum: &msg::Datum,
    name: &str,
    t_unix_ms: u64,
) -> Result<Route, String> {
    let g = gpx::read(std::io::Cursor::new(bytes)).map_err(|e| format!("GPX: {e}"))?;
    let mut wpts: Vec<&gpx::Waypoint> = Vec::new();
    for r in &g.routes {
        wpts.extend(r.points.iter());
    }
    for t in &g.tracks {
        for s in &t.segments {
            wpts.extend(s.points.iter());
        }
    }
    if wpts.is_empty() {
        return Err("GPX has no route or track points".into());
    }
    let points = wpts
        .iter()
        .map(|w| {
            let p = w.point();
            let ll = msg::Datum {
                lat_deg: p.y(),
                lon_deg: p.x(),
                h_m: w.elevation.unwrap_or(datum.h_m),
            };
            let e = common::geo::lla_to_enu(datum, &ll);
            RoutePoint {
                x_m: e.x,
                y_m: e.y,
                lat_deg: Some(ll.lat_deg),
                lon_deg: Some(ll.lon_deg),
                h_m: w.elevation,
                yaw_rad: 0.0,
                t_unix_ms,
            }
        })
        .collect();
    Ok(Route {
        route_id: format!("import-{t_unix_ms}"),
        name: name.to_string(),
        robot: String::new(),
        session_id: String::new(),
        datum: Some(*datum),
        points,
    })
}

#[derive(Deserialize)]
struct ImportQuery {
    name: Option<String>,
    datum_id: String,
}

async fn route_import(
    State(st): State<AppState>,
    Query(q): Query<ImportQuery>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let datum = st
        .inner
        .datums
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .geodetic(&q.datum_id)
        .ok_or_else(|| bad(format!("datum {} unknown or without lat/lon", q.datum_id)))?;
    let name = q.name.unwrap_or_else(|| "imported".into());
    let route = route_from_gpx(&body, &datum, &name, now_unix_ms()).map_err(bad)?;
    let row = route_row(&route, Some(q.datum_id.clone()));
    st.inner.store(StoreOp::Route {
        row: row.clone(),
        json: serde_json::to_string(&route).map_err(internal)?,
    });
    st.inner.flush_store_async().await;
    st.inner
        .emit(json!({"type": "route", "route": row}).to_string());
    Ok((
        StatusCode::CREATED,
        Json(serde_json::to_value(row).map_err(internal)?),
    ))
}

#[derive(Deserialize)]
struct ConvertQuery {
    datum_id: String,
    x: Option<f64>,
    y: Option<f64>,
    lat: Option<f64>,
    lon: Option<f64>,
}

async fn geo_convert(
    State(st): State<AppState>,
    Query(q): Query<ConvertQuery>,
) -> ApiResult<Json<Value>> {
    let datum = st
        .inner
        .datums
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .geodetic(&q.datum_id)
        .ok_or_else(|| bad(format!("datum {} unknown or without lat/lon", q.datum_id)))?;
    match (q.x, q.y, q.lat, q.lon) {
        (Some(x), Some(y), _, _) if x.is_finite() && y.is_finite() => {
            let g = common::geo::enu_to_lla(&datum, &nalgebra::Vector3::new(x, y, 0.0));
            Ok(Json(json!({"lat_deg": g.lat_deg, "lon_deg": g.lon_deg})))
        }
        (_, _, Some(lat), Some(lon))
            if (-90.0..=90.0).contains(&lat) && (-180.0..=180.0).contains(&lon) =>
        {
            let e = common::geo::lla_to_enu(
                &datum,
                &msg::Datum {
                    lat_deg: lat,
                    lon_deg: lon,
                    h_m: datum.h_m,
                },
            );
            Ok(Json(json!({"x": e.x, "y": e.y})))
        }
        _ => Err(bad("give x and y, or lat and lon (in range)")),
    }
}

// ---- commands ----

fn known_robot(st: &AppState, robot: &str) -> ApiResult<RobotId> {
    let id = RobotId::new(robot).map_err(|e| bad(e.to_string()))?;
    let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
    match f.robots.get(robot) {
        None => Err(not_found(format!("unknown robot {robot}"))),
        // Zenoh would drop the command without a word: say so instead of "sent".
        Some(r) if !r.online => Err(ApiError(
            StatusCode::CONFLICT,
            format!("robot {robot} is offline: command not sent"),
            Some(common::command::RefusalCode::RobotOffline.as_str()),
        )),
        Some(_) => Ok(id),
    }
}

/// Sends `cmd` to `robot` in its envelope (the station's sender id, next sequence, now).
async fn put<T: serde::Serialize>(
    st: &AppState,
    robot: &RobotId,
    topic: Topic,
    cmd: &T,
) -> ApiResult<()> {
    // A newer command replaces one still being followed up (never resend an old goal over it).
    st.inner.supersede(robot.as_str());
    let payload = msg::encode_cmd(st.inner.cmd_header(), cmd);
    crate::bus::put_command(&st.inner.session(), keys::key(robot, topic), payload)
        .await
        .map_err(internal)
}

fn accepted(sent: Value) -> (StatusCode, Json<Value>) {
    (
        StatusCode::ACCEPTED,
        Json(json!({"ok": true, "sent": sent})),
    )
}

fn json_body<T: serde::de::DeserializeOwned>(body: &Bytes) -> ApiResult<T> {
    let b: &[u8] = if body.is_empty() { b"{}" } else { body };
    serde_json::from_slice(b).map_err(|e| bad(format!("bad JSON body: {e}")))
}

/// Goal body: map x/y or lat/lon(/h).
#[derive(Deserialize)]
pub struct GoalBody {
    x: Option<f64>,
    y: Option<f64>,
    lat: Option<f64>,
    lon: Option<f64>,
    h: Option<f64>,
    tolerance_m: Option<f32>,
}

/// Builds and checks a goal target from the body.
pub fn goal_target(b: &GoalBody) -> Result<GoalTarget, String> {
    match (b.x, b.y, b.lat, b.lon) {
        (Some(x), Some(y), None, None) => {
            if !(x.is_finite() && y.is_finite()) {
                return Err("x and y must be finite".into());
            }
            Ok(GoalTarget::Map { x_m: x, y_m: y })
        }
        (None, None, Some(lat), Some(lon)) => {
            if !(lat.is_finite() && (-90.0..=90.0).contains(&lat)) {
                return Err(format!("latitude {lat} out of range"));
            }
            if !(lon.is_finite() && (-180.0..=180.0).contains(&lon)) {
                return Err(format!("longitude {lon} out of range"));
            }
            if let Some(h) = b.h {
                if !h.is_finite() {
                    return Err("height must be finite".into());
                }
            }
            Ok(GoalTarget::Gnss {
                lat_deg: lat,
                lon_deg: lon,
                h_m: b.h,
            })
        }
        _ => Err("give either {\"x\", \"y\"} or {\"lat\", \"lon\"}".into()),
    }
}

/// What the station knows of `robot` for the goal contract: its last pose (map frame and
/// WGS-84) and the merged map of its datum.
fn goal_context(st: &AppState, robot: &str) -> RobotContext {
    let (pose, datum_id) = {
        let f = st.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
        f.robots
            .get(robot)
            .map(|r| (r.pose.clone(), r.datum_id.clone()))
            .unwrap_or_default()
    };
    // While the stored map is still coming back its bounds would understate what is mapped and
    // refuse a good goal, so no position is given then and the distance check is left to the
    // robot, which checks the goal against its own map anyway.
    let restoring = !st.inner.restore.is_finished();
    let mapped = datum_id.and_then(|d| {
        let map = st.inner.map.read().unwrap_or_else(|p| p.into_inner());
        let b = map.datums.get(&d)?.bounds_m()?;
        Some(BoundsM {
            min_m: (b[0], b[1]),
            max_m: (b[2], b[3]),
        })
    });
    RobotContext {
        position_m: pose.as_ref().filter(|_| !restoring).map(|p| (p.x_m, p.y_m)),
        lat_lon_deg: pose.as_ref().and_then(|p| p.lat_lon_deg),
        mapped,
    }
}

async fn cmd_goal(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let id = known_robot(&st, &robot)?;
    let b: GoalBody = json_body(&body)?;
    let target = goal_target(&b).map_err(bad)?;
    let tol = b.tolerance_m.unwrap_or(0.0);
    if !(tol.is_finite() && (0.0..=100.0).contains(&tol)) {
        return Err(bad("tolerance_m must be 0-100"));
    }
    zones::check_goal(&st, &robot, &target)?;
    let cmd = GoalCmd {
        goal_id: st.inner.goal_seq.fetch_add(1, Ordering::Relaxed),
        target,
        tolerance_m: tol,
    };
    // The robot checks the same contract; refusing here already tells the operator at once
    // (a swapped lat/lon would otherwise leave as "sent" and come back as a refusal later).
    check_goal(&cmd, &CommandLimits::default(), &goal_context(&st, &robot))
        .map_err(ApiError::from)?;
    put(&st, &id, Topic::CmdGoal, &cmd).await?;
    st.inner
        .follow_up(&robot, crate::deliveries::Command::Goal(cmd.clone()));
    let sent = serde_json::to_value(&cmd).map_err(internal)?;
    st.inner.store(StoreOp::Goal {
        robot: robot.clone(),
        t_unix_ms: now_unix_ms(),
        goal_id: cmd.goal_id,
        json: sent.to_string(),
    });
    Ok(accepted(sent))
}

#[derive(Deserialize)]
struct StopBody {
    reason: Option<String>,
}

async fn cmd_stop(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let id = known_robot(&st, &robot)?;
    let b: StopBody = json_body(&body)?;
    let cmd = StopCmd {
        reason: b.reason.unwrap_or_else(|| "operator".into()),
    };
    put(&st, &id, Topic::CmdStop, &cmd).await?;
    st.inner
        .follow_up(&robot, crate::deliveries::Command::Stop(cmd.clone()));
    Ok(accepted(serde_json::to_value(&cmd).map_err(internal)?))
}

#[derive(Deserialize)]
struct DriveBody {
    v_mps: f32,
    omega_rps: f32,
    #[serde(default)]
    deadman: bool,
}

async fn cmd_drive(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let id = known_robot(&st, &robot)?;
    let b: DriveBody = json_body(&body)?;
    if !(b.v_mps.is_finite() && b.omega_rps.is_finite()) {
        return Err(bad("v_mps and omega_rps must be finite"));
    }
    let cmd = DriveCmd {
        seq: st.inner.drive_seq.fetch_add(1, Ordering::Relaxed),
        v_mps: b.v_mps,
        omega_rps: b.omega_rps,
        deadman: b.deadman,
    };
    put(&st, &id, Topic::CmdDrive, &cmd).await?;
    Ok(accepted(serde_json::to_value(&cmd).map_err(internal)?))
}

#[derive(Deserialize)]
struct SpeedBody {
    limit_mps: f32,
}

async fn cmd_speed(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let id = known_robot(&st, &robot)?;
    let b: SpeedBody = json_body(&body)?;
    if !(b.limit_mps.is_finite() && b.limit_mps > 0.0) {
        return Err(bad("limit_mps must be positive"));
    }
    let cmd = SpeedCmd {
        limit_mps: b.limit_mps,
    };
    put(&st, &id, Topic::CmdSpeed, &cmd).await?;
    Ok(accepted(serde_json::to_value(&cmd).map_err(internal)?))
}

#[derive(Deserialize)]
struct RouteBody {
    action: String,
    name: Option<String>,
    route_id: Option<String>,
    direction: Option<String>,
}

async fn cmd_route(
    State(st): State<AppState>,
    UrlPath(robot): UrlPath<String>,
    body: Bytes,
) -> ApiResult<(StatusCode, Json<Value>)> {
    let id = known_robot(&st, &robot)?;
    let b: RouteBody = json_body(&body)?;
    let cmd = match b.action.as_str() {
        "record" => {
            let name = b.name.unwrap_or_default();
            if name.trim().is_empty() {
                return Err(bad("record needs a name"));
            }
            RouteCmd::Record { name }
        }
        "stop_recording" => RouteCmd::StopRecording,
        "repeat" => {
            let rid = b.route_id.ok_or_else(|| bad("repeat needs route_id"))?;
            let route = load_route(&st, &rid).await?;
            let direction = match b.direction.as_deref().unwrap_or("reverse") {
                "reverse" => RouteDirection::Reverse,
                "forward" => RouteDirection::Forward,
                d => return Err(bad(format!("direction {d:?}: use reverse or forward"))),
            };
            RouteCmd::Repeat { route, direction }
        }
        "pause" => RouteCmd::Pause,
        "resume" => RouteCmd::Resume,
        "cancel" => RouteCmd::Cancel,
        a => return Err(bad(format!("unknown action {a:?}"))),
    };
    put(&st, &id, Topic::CmdRoute, &cmd).await?;
    let sent = match &cmd {
        RouteCmd::Repeat { route, direction } => {
            json!({"Repeat": {"route_id": route.route_id, "direction": direction}})
        }
        other => serde_json::to_value(other).map_err(internal)?,
    };
    Ok(accepted(sent))
}

// ---- WebSocket ----

async fn ws(State(st): State<AppState>, up: WebSocketUpgrade, _h: HeaderMap) -> Response {
    up.on_upgrade(move |socket| ws_session(st, socket))
}

async fn ws_session(st: AppState, mut socket: WebSocket) {
    let mut rx = st.inner.events.subscribe();
    let hello = json!({"type": "hello", "version": VERSION}).to_string();
    if socket.send(Message::Text(hello.into())).await.is_err() {
        return;
    }
    loop {
        tokio::select! {
            ev = rx.recv() => match ev {
                Ok(text) => {
                    if socket.send(Message::Text(text.as_ref().into())).await.is_err() {
                        break;
                    }
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    // A slow client missed events: a new hello makes it refetch the REST state.
                    tracing::warn!("websocket client lagged by {n} events");
                    let hello = json!({"type": "hello", "version": VERSION}).to_string();
                    if socket.send(Message::Text(hello.into())).await.is_err() {
                        break;
                    }
                }
                Err(_) => break,
            },
            m = socket.recv() => match m {
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                _ => {}
            },
        }
    }
}

#[cfg(test)]
mod gpx_tests {
    use super::*;

    fn taught() -> Route {
        let datum = msg::Datum {
            lat_deg: 50.08,
            lon_deg: 14.42,
            h_m: 240.0,
        };
        let points = (0..40)
            .map(|i| {
                let (x, y) = (f64::from(i) * 1.3 - 20.0, (f64::from(i) * 0.2).sin() * 6.0);
                let g = common::geo::enu_to_lla(&datum, &nalgebra::Vector3::new(x, y, 0.0));
                RoutePoint {
                    x_m: x,
                    y_m: y,
                    lat_deg: Some(g.lat_deg),
                    lon_deg: Some(g.lon_deg),
                    h_m: Some(g.h_m),
                    yaw_rad: 0.0,
                    t_unix_ms: 1_790_000_000_000,
                }
            })
            .collect();
        Route {
            route_id: "r1".into(),
            name: "home & <back>".into(),
            robot: "husky-1".into(),
            session_id: "s1".into(),
            datum: Some(datum),
            points,
        }
    }

    #[test]
    fn gpx_round_trip_gives_the_same_route() {
        let r = taught();
        let text = route_gpx_text(&r).unwrap();
        let back = route_from_gpx(text.as_bytes(), &r.datum.unwrap(), &r.name, 1).unwrap();
        assert_eq!(back.points.len(), r.points.len());
        for (a, b) in r.points.iter().zip(&back.points) {
            // 9 decimals of a degree are ~0.1 mm; heights are written to the millimetre.
            assert!(
                (a.x_m - b.x_m).abs() < 1e-3 && (a.y_m - b.y_m).abs() < 1e-3,
                "{a:?} {b:?}"
            );
            assert!((a.lat_deg.unwrap() - b.lat_deg.unwrap()).abs() < 1e-9);
            assert!((a.lon_deg.unwrap() - b.lon_deg.unwrap()).abs() < 1e-9);
            assert!((a.h_m.unwrap() - b.h_m.unwrap()).abs() < 1e-3);
        }
        // And once more: an imported route exports to the same file.
        let again = route_gpx_text(&Route {
            name: r.name.clone(),
            ..back
        })
        .unwrap();
        assert_eq!(again, text);
    }

    #[test]
    fn bad_gpx_is_a_clear_error() {
        let d = taught().datum.unwrap();
        let e = route_from_gpx(b"<gpx>oops", &d, "x", 1).unwrap_err();
        assert!(e.starts_with("GPX"), "{e}");
        let empty = "<?xml version=\"1.0\"?><gpx version=\"1.1\" creator=\"t\" xmlns=\"http://www.topografix.com/GPX/1/1\"></gpx>";
        let e = route_from_gpx(empty.as_bytes(), &d, "x", 1).unwrap_err();
        assert!(e.contains("no route or track points"), "{e}");
    }
}
