//! `/api/basemap`: the operator's background map, served from disk (XYZ numbering).

use axum::extract::{Path as UrlPath, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::Json;

use super::{bad, internal, not_found, ApiResult, AppState};
use crate::basemap::BasemapInfo;

/// `GET /api/basemap`: what the browser needs to place the tiles; 404 without `--basemap`.
pub async fn info(State(st): State<AppState>) -> ApiResult<Json<BasemapInfo>> {
    st.basemap
        .as_ref()
        .map(|b| Json(b.info().clone()))
        .ok_or_else(|| not_found("no basemap: start the station with --basemap PATH"))
}

/// `GET /api/basemap/{z}/{x}/{y}[.ext]`: one tile, 404 where the source has none.
pub async fn tile(
    State(st): State<AppState>,
    UrlPath((z, x, y)): UrlPath<(u8, u32, String)>,
) -> ApiResult<Response> {
    let b = st
        .basemap
        .clone()
        .ok_or_else(|| not_found("no basemap: start the station with --basemap PATH"))?;
    let y: u32 = y
        .split('.')
        .next()
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("tile must be {z}/{x}/{y}[.png]"))?;
    let b2 = b.clone();
    let data = tokio::task::spawn_blocking(move || b2.tile(z, x, y))
        .await
        .map_err(internal)?
        .map_err(internal)?
        .ok_or_else(|| not_found(format!("no basemap tile {z}/{x}/{y}")))?;
    Ok((
        [
            (header::CONTENT_TYPE, b.content_type()),
            (header::CACHE_CONTROL, "public, max-age=3600"),
        ],
        data,
    )
        .into_response())
}
