//! `/api/alerts`: the alert list and acknowledgements.

use axum::extract::{Path as UrlPath, State};
use axum::Json;
use serde_json::{json, Value};

use super::{internal, not_found, ApiResult, AppState};
use crate::station::now_unix_ms;

/// `GET /api/alerts`: every alert, newest first.
pub async fn list(State(st): State<AppState>) -> ApiResult<Json<Value>> {
    let a = st.inner.alerts.lock().unwrap_or_else(|p| p.into_inner());
    Ok(Json(serde_json::to_value(a.list()).map_err(internal)?))
}

/// `POST /api/alerts/{id}/ack`.
pub async fn ack(State(st): State<AppState>, UrlPath(id): UrlPath<u64>) -> ApiResult<Json<Value>> {
    let alert = {
        let mut a = st.inner.alerts.lock().unwrap_or_else(|p| p.into_inner());
        if !a.ack(id, now_unix_ms()) {
            return Err(not_found(format!("unknown alert {id}")));
        }
        a.get(id).cloned()
    };
    if let Some(a) = &alert {
        st.inner.alert_changed(a);
    }
    Ok(Json(json!({"ok": true, "alert": alert})))
}

/// `POST /api/alerts/ack`: acknowledges every alert.
pub async fn ack_all(State(st): State<AppState>) -> Json<Value> {
    let now = now_unix_ms();
    let n = {
        let mut a = st.inner.alerts.lock().unwrap_or_else(|p| p.into_inner());
        let ids: Vec<u64> = a
            .list()
            .iter()
            .filter(|x| x.acked_unix_ms.is_none())
            .map(|x| x.id)
            .collect();
        for id in &ids {
            a.ack(*id, now);
            if let Some(x) = a.get(*id) {
                st.inner.store(crate::store::StoreOp::Alert {
                    id: *id,
                    json: serde_json::to_string(x).unwrap_or_default(),
                });
            }
        }
        ids.len()
    };
    st.inner.emit(json!({"type": "alerts"}).to_string());
    Json(json!({"ok": true, "acknowledged": n}))
}
