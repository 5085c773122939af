//! Whether this station may command: a station does, a monitor (`serve --monitor NAME`) only
//! watches. A monitor's API refuses every command route with 403 and the stable code
//! `monitor_read_only`, counted in `/api/health` (which also names the role, so the UI can turn
//! its command controls off). This is a courtesy to the operator, not the enforcement: the
//! station's and router's access rules drop a monitor's puts, and robots admit it to nothing.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use common::command::{Refusal, RefusalCode};
use serde_json::{json, Value};

use super::{ApiError, AppState};

/// The station's role and the count of command requests it refused for it.
#[derive(Clone, Debug, Default)]
pub struct Role {
    monitor: Option<String>,
    refused: Arc<AtomicU64>,
}

impl Role {
    /// A station (`None`) or the read-only monitor `name`.
    pub fn new(monitor: Option<String>) -> Self {
        Self {
            monitor,
            refused: Arc::default(),
        }
    }

    /// True for a monitor.
    pub fn read_only(&self) -> bool {
        self.monitor.is_some()
    }

    /// What `/api/health` says of the role.
    pub fn health(&self) -> Value {
        json!({
            "role": if self.read_only() { "monitor" } else { "station" },
            "monitor": self.monitor,
            "commands_refused_read_only": self.refused.load(Ordering::Relaxed),
        })
    }
}

/// True when `method path` sends something to robots: any POST under `/api/robots/` (goal, stop,
/// drive, speed, route, mission and its actions) and changes to the zone set (pushed to robots).
/// The station's own records (missions library, route import, alert acks) are not commands.
pub fn is_command(method: &Method, path: &str) -> bool {
    let write = *method != Method::GET && *method != Method::HEAD && *method != Method::OPTIONS;
    write
        && (path.starts_with("/api/robots/")
            || path == "/api/zones"
            || path.starts_with("/api/zones/"))
}

/// Refuses command routes on a monitor.
pub async fn refuse_commands(State(st): State<AppState>, req: Request, next: Next) -> Response {
    if st.role.read_only() && is_command(req.method(), req.uri().path()) {
        st.role.refused.fetch_add(1, Ordering::Relaxed);
        let name = st.role.monitor.as_deref().unwrap_or_default();
        let mut e = ApiError::from(Refusal::new(
            RefusalCode::MonitorReadOnly,
            format!(
                "{} {}: this is the read-only monitor {name}: it watches the fleet and sends no \
                 commands; command from the operator station",
                req.method(),
                req.uri().path()
            ),
        ));
        e.0 = StatusCode::FORBIDDEN;
        return e.into_response();
    }
    next.run(req).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_routes_are_told_from_reads_and_local_records() {
        for (m, p) in [
            (Method::POST, "/api/robots/r1/goal"),
            (Method::POST, "/api/robots/r1/stop"),
            (Method::POST, "/api/robots/r1/drive"),
            (Method::POST, "/api/robots/r1/speed"),
            (Method::POST, "/api/robots/r1/route"),
            (Method::POST, "/api/robots/r1/mission"),
            (Method::POST, "/api/robots/r1/mission/cancel"),
            (Method::POST, "/api/zones"),
            (Method::DELETE, "/api/zones/3"),
        ] {
            assert!(is_command(&m, p), "{m} {p}");
        }
        for (m, p) in [
            (Method::GET, "/api/robots"),
            (Method::GET, "/api/zones"),
            (Method::GET, "/api/health"),
            (Method::POST, "/api/missions"),
            (Method::POST, "/api/routes/import"),
            (Method::POST, "/api/alerts/ack"),
        ] {
            assert!(!is_command(&m, p), "{m} {p}");
        }
        assert!(!Role::new(None).read_only());
        assert_eq!(Role::new(Some("m1".into())).health()["role"], "monitor");
    }
}
