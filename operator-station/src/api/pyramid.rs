//! `GET /api/map/{datum_id}/pyramid/{level}/{tx}/{ty}.png`: the zoom pyramid's tiles
//! ([`crate::pyramid`]) as PNG. Level 0 is the merged tile `(tx, ty)`, level `L` the overview of
//! the `2^L x 2^L` merged tiles from `(tx * 2^L, ty * 2^L)`, in the datum's local metric frame
//! (`ty` grows northwards, as everywhere in the API). Each answer carries an `ETag`; the browser
//! revalidates (`no-cache`) and gets `304 Not Modified` while the tile is unchanged.
//!
//! `GET /api/map/{datum_id}/history/{t_unix_ms}/{level}/{tx}/{ty}.png`: the same tiles of the
//! merged map as it was at `t_unix_ms` ([`crate::history`]); `GET /api/map/{datum_id}/history`:
//! what the history holds.

use std::sync::{Arc, OnceLock};

use axum::extract::{Path as UrlPath, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use common::grid::TileIndex;

use axum::Json;
use serde_json::{json, Value};

use super::{bad, internal, not_found, read, ApiResult, AppState};
use crate::pyramid::PyramidTile;
use crate::pyramid::MAX_LEVEL;
use crate::station::now_unix_ms;

/// Tags of one station run differ from those of any other (another database may have a tile of
/// the same datum id, level and version).
fn run_tag() -> u64 {
    static START: OnceLock<u64> = OnceLock::new();
    *START.get_or_init(now_unix_ms)
}

pub(super) async fn tile(
    State(st): State<AppState>,
    UrlPath((datum_id, level, tx, typng)): UrlPath<(String, u8, i32, String)>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ty: i32 = typng
        .strip_suffix(".png")
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("tile must be {level}/{tx}/{ty}.png"))?;
    if level > MAX_LEVEL {
        return Err(bad(format!("level must be 0-{MAX_LEVEL}")));
    }
    let inner = st.inner.clone();
    let did = datum_id.clone();
    // Building a cold overview walks every merged tile beneath it: off the async workers.
    let found = tokio::task::spawn_blocking(move || {
        let map = inner.map.read().unwrap_or_else(|p| p.into_inner());
        let mut pyramid = inner.pyramid.lock().unwrap_or_else(|p| p.into_inner());
        pyramid.tile(&map, &did, level, TileIndex { tx, ty })
    })
    .await
    .map_err(internal)?;
    let t = found.ok_or_else(|| {
        not_found(format!(
            "no map beneath level {level} tile {tx},{ty} of {datum_id}"
        ))
    })?;
    png_response(&format!("\"{}-{}\"", run_tag(), t.version), t, &headers).await
}

/// The PNG of `t` tagged `etag`, or 304 when the browser holds it.
async fn png_response(etag: &str, t: Arc<PyramidTile>, headers: &HeaderMap) -> ApiResult<Response> {
    let etag = etag.to_string();
    let fresh = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|e| e.trim() == etag));
    let cache = [
        (header::ETAG, etag),
        (header::CACHE_CONTROL, "no-cache".to_string()),
    ];
    if fresh {
        return Ok((StatusCode::NOT_MODIFIED, cache).into_response());
    }
    let png = tokio::task::spawn_blocking(move || t.png())
        .await
        .map_err(internal)?;
    Ok((
        cache,
        [(header::CONTENT_TYPE, "image/png")],
        png.as_ref().clone(),
    )
        .into_response())
}

fn parse_ty(typng: &str) -> ApiResult<i32> {
    typng
        .strip_suffix(".png")
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("tile must be {level}/{tx}/{ty}.png"))
}

pub(super) async fn history_tile(
    State(st): State<AppState>,
    UrlPath((datum_id, t_unix_ms, level, tx, typng)): UrlPath<(String, u64, u8, i32, String)>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ty = parse_ty(&typng)?;
    if level > MAX_LEVEL {
        return Err(bad(format!("level must be 0-{MAX_LEVEL}")));
    }
    let did = datum_id.clone();
    let key = read(&st, move |c| crate::store::history_key(c, &did, t_unix_ms)).await?;
    let Some(t_key_ms) = key else {
        return Err(not_found(format!(
            "no map history of {datum_id} at or before {t_unix_ms}"
        )));
    };
    let inner = st.inner.clone();
    let did = datum_id.clone();
    // A state not drawn recently is read and decoded whole (once), off the async workers.
    let found = tokio::task::spawn_blocking(move || {
        let snap = inner.history.get_or_make(&did, t_key_ms, || {
            let rows = inner
                .read(|c| crate::store::tiles_at(c, &did, t_key_ms))
                .unwrap_or_else(|e| {
                    tracing::warn!("map history of {did} at {t_key_ms} unreadable: {e}");
                    Vec::new()
                });
            crate::history::Snapshot::from_rows(&did, t_key_ms, rows)
        });
        snap.tile(level, TileIndex { tx, ty })
    })
    .await
    .map_err(internal)?;
    let t = found.ok_or_else(|| {
        not_found(format!(
            "no map beneath level {level} tile {tx},{ty} of {datum_id} at {t_unix_ms}"
        ))
    })?;
    png_response(
        &format!("\"{}-h{t_key_ms}-{}\"", run_tag(), t.version),
        t,
        &headers,
    )
    .await
}

pub(super) async fn history_info(
    State(st): State<AppState>,
    UrlPath(datum_id): UrlPath<String>,
) -> ApiResult<Json<Value>> {
    let did = datum_id.clone();
    let span = read(&st, move |c| crate::store::history_span(c, &did)).await?;
    let (first, last, rows, bytes) = match span {
        Some((a, b, n, by)) => (json!(a), json!(b), n, by),
        None => (Value::Null, Value::Null, 0, 0),
    };
    Ok(Json(json!({
        "datum_id": datum_id,
        "period_s": st.inner.map_history_s,
        "first_unix_ms": first,
        "last_unix_ms": last,
        "rows": rows,
        "bytes": bytes,
    })))
}
