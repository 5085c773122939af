//! What the operator UI relies on from the station (issue 21), against `operator-station serve`
//! as a process and a synthetic robot (the real robot bus) over Zenoh on loopback: a route event
//! only after its row is readable, commands to an offline robot refused with 409, and JSON bodies
//! for the errors axum makes itself (405, 413).

mod station_support;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use common::msg::{Datum, Route, RoutePoint};
use serde_json::Value;
use station_support::*;

const LIMIT: Duration = Duration::from_secs(10);

fn synthetic_online(ports: &Ports, id: &str) -> robot_agent::bus::BusHandle {
    let bus = synthetic_robot(id, &ports.endpoint());
    bus.publish_session(&session(id, now_ms()));
    assert!(
        wait_for(LIMIT, || robot_entry(ports.http, id)
            .is_some_and(|r| r["online"] == true && !r["datum_id"].is_null())),
        "{id} never came online with a datum"
    );
    bus
}

fn route(id: &str, robot: &str, name: &str) -> Route {
    let points = (0..5)
        .map(|i| RoutePoint {
            x_m: f64::from(i),
            y_m: 0.0,
            lat_deg: None,
            lon_deg: None,
            h_m: None,
            yaw_rad: 0.0,
            t_unix_ms: now_ms(),
        })
        .collect();
    Route {
        route_id: id.into(),
        name: name.into(),
        robot: robot.into(),
        session_id: String::new(),
        datum: Some(Datum {
            lat_deg: 50.0,
            lon_deg: 14.0,
            h_m: 200.0,
        }),
        points,
    }
}

/// The browser refetches `GET /api/routes` when the `route` event arrives; the route must be in
/// that answer (it was not: the event went out before the database write).
#[test]
fn route_event_comes_after_the_route_is_stored() {
    let dir = tempfile::tempdir().unwrap();
    let ports = Ports::new();
    let _st = Station::start(ports, &dir.path().join("s.db"));
    let bus = synthetic_online(&ports, "rt-1");
    let (mut ws, _) =
        tungstenite::connect(format!("ws://127.0.0.1:{}/api/ws", ports.http)).expect("websocket");
    for n in 0..3 {
        let rid = format!("route-{n}");
        bus.publish_route(&route(&rid, "rt-1", &format!("lap {n}")));
        let t0 = Instant::now();
        loop {
            assert!(t0.elapsed() < LIMIT, "no route event for {rid}");
            let m = ws.read().expect("websocket open");
            let Ok(text) = m.to_text() else { continue };
            let v: Value = serde_json::from_str(text).unwrap_or(Value::Null);
            if v["type"] == "route" && v["route"]["route_id"] == rid.as_str() {
                break;
            }
        }
        // Exactly what web/app.js does on the event.
        let list = get_json(ports.http, "/api/routes");
        assert!(
            list.as_array()
                .unwrap()
                .iter()
                .any(|r| r["route_id"] == rid.as_str() && r["name"] == format!("lap {n}")),
            "route event for {rid} arrived but GET /api/routes lacks it: {list}"
        );
    }
}

/// A command to a robot the station knows but that is offline is refused with 409 and a JSON
/// reason, not answered 202 "sent" and dropped.
#[test]
fn commands_to_an_offline_robot_get_409() {
    let dir = tempfile::tempdir().unwrap();
    let ports = Ports::new();
    let _st = Station::start(ports, &dir.path().join("s.db"));
    let bus = synthetic_online(&ports, "off-1");
    let (st, body) = http(ports.http, "POST", "/api/robots/off-1/stop", "{}").unwrap();
    assert_eq!(st, 202, "online robot: {body}");
    drop(bus);
    assert!(wait_for(LIMIT, || robot_entry(ports.http, "off-1")
        .is_some_and(|r| r["online"] == false)));
    for (path, body) in [
        ("/api/robots/off-1/goal", r#"{"x": 1, "y": 2}"#),
        ("/api/robots/off-1/stop", "{}"),
        (
            "/api/robots/off-1/drive",
            r#"{"v_mps": 0.2, "omega_rps": 0, "deadman": true}"#,
        ),
        ("/api/robots/off-1/speed", r#"{"limit_mps": 0.3}"#),
    ] {
        let (st, text) = http(ports.http, "POST", path, body).unwrap();
        assert_eq!(st, 409, "{path}: {text}");
        let v: Value = serde_json::from_str(&text).expect("JSON error body");
        assert!(
            v["error"].as_str().unwrap_or("").contains("offline"),
            "{path}: {text}"
        );
    }
}

/// Sends `body_len` bytes without insisting that the server reads them all (it may answer 413
/// early); returns the status and body of the answer.
fn post_big(port: u16, path: &str, body_len: usize) -> (u16, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(LIMIT)).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nContent-Type: application/gpx+xml\r\nContent-Length: {body_len}\r\n\r\n"
    )
    .unwrap();
    let chunk = vec![b' '; 64 * 1024];
    let mut sent = 0;
    while sent < body_len {
        match s.write(&chunk[..chunk.len().min(body_len - sent)]) {
            Ok(n) => sent += n,
            Err(_) => break, // the server answered and closed: read what it said
        }
    }
    let mut buf = Vec::new();
    let _ = s.read_to_end(&mut buf);
    let text = String::from_utf8_lossy(&buf).to_string();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    (status, body)
}

/// Errors axum makes itself carry `{"error": ...}` like all others: 405 naming the method,
/// 413 for a 10 MB upload.
#[test]
fn method_not_allowed_and_too_large_are_json_errors() {
    let dir = tempfile::tempdir().unwrap();
    let ports = Ports::new();
    let _st = Station::start(ports, &dir.path().join("s.db"));
    let (st, text) = http(ports.http, "DELETE", "/api/robots/any/stop", "").unwrap();
    assert_eq!(st, 405, "{text}");
    let v: Value = serde_json::from_str(&text).expect("405 has a JSON body");
    let e = v["error"].as_str().unwrap_or("");
    assert!(e.contains("DELETE"), "{text}");
    let (st, text) = post_big(ports.http, "/api/routes/import?datum_id=d0", 10 << 20);
    assert_eq!(st, 413, "{text}");
    let v: Value = serde_json::from_str(&text).expect("413 has a JSON body");
    assert!(v["error"].as_str().is_some_and(|e| !e.is_empty()), "{text}");
}
