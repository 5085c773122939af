//! `GET /api/map/{datum_id}/pyramid/{level}/{tx}/{ty}.png`: the zoom pyramid's tiles
//! ([`crate::pyramid`]) as PNG. Level 0 is the merged tile `(tx, ty)`, level `L` the overview of
//! the `2^L x 2^L` merged tiles from `(tx * 2^L, ty * 2^L)`, in the datum's local metric frame
//! (`ty` grows northwards, as everywhere in the API). Each answer carries an `ETag`; the browser
//! revalidates (`no-cache`) and gets `304 Not Modified` while the tile is unchanged.

use std::sync::OnceLock;

use axum::extract::{Path as UrlPath, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use common::grid::TileIndex;

use super::{bad, internal, not_found, ApiResult, AppState};
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
    let etag = format!("\"{}-{}\"", run_tag(), t.version);
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
