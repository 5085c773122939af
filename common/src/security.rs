//! Who may do what on the terranav key space, and where the fleet's certificates live.
//!
//! Both sides agree on this, so it lives here as plain data: the identities (certificate common
//! names), the access rules each side enforces on its own Zenoh session (Zenoh's
//! `access_control` JSON), the TLS settings of mutual authentication, the layout of a PKI folder,
//! and which endpoints are loopback. The robot bus and the station apply it; nothing here opens a
//! file or a socket.
//!
//! Identities are common names no public CA can issue (they contain `:`, which no DNS name does):
//! Zenoh's TLS client also trusts the Web PKI roots, so a name like `station.example.com` could
//! be bought; `terranav:station` cannot.

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::keys::{self, RobotId};

/// Common name of the operator station's certificate: the only identity robots take commands from.
pub const STATION_CN: &str = "terranav:station";

/// Prefix of a robot certificate's common name: `terranav:robot:<id>:<serial>`.
const ROBOT_CN_PREFIX: &str = "terranav:robot:";

/// Prefix of a monitor certificate's common name: `terranav:monitor:<name>:<serial>`. A monitor is
/// a read-only station: stations and routers that read the register admit it to subscribe and
/// query, never to put; robots name no monitor at all, so a monitor linked straight to a robot
/// gets nothing from it and commands nothing.
const MONITOR_CN_PREFIX: &str = "terranav:monitor:";

/// Checks a monitor name (`pki add-monitor --name`): the robot id alphabet (`[a-z0-9-]+`, at most
/// 64 characters), so it is safe in a common name, a folder name and an access-rule id.
pub fn check_monitor_name(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "monitor name {name:?}: use 1-64 characters of a-z, 0-9 and -"
        ))
    }
}

/// Common name of the `serial`-th certificate issued to monitor `name`.
pub fn monitor_cn(name: &str, serial: u32) -> String {
    format!("{MONITOR_CN_PREFIX}{name}:{serial}")
}

/// The name and serial of a monitor certificate's common name.
pub fn parse_monitor_cn(cn: &str) -> Option<(String, u32)> {
    let (name, serial) = cn.strip_prefix(MONITOR_CN_PREFIX)?.rsplit_once(':')?;
    check_monitor_name(name).ok()?;
    Some((name.to_string(), serial.parse().ok()?))
}

/// Common name of the `serial`-th certificate issued to `robot`. Each issue gets a new serial, so
/// a revoked (or superseded) certificate never matches the station's rules again.
pub fn robot_cn(robot: &RobotId, serial: u32) -> String {
    format!("{ROBOT_CN_PREFIX}{robot}:{serial}")
}

/// The robot id and serial of a robot certificate's common name.
pub fn parse_robot_cn(cn: &str) -> Option<(RobotId, u32)> {
    let (id, serial) = cn.strip_prefix(ROBOT_CN_PREFIX)?.rsplit_once(':')?;
    Some((RobotId::new(id).ok()?, serial.parse().ok()?))
}

/// The files of a fleet's PKI folder (`operator-station pki init --dir DIR`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FleetDir {
    /// The folder.
    pub root: PathBuf,
}

impl FleetDir {
    /// The PKI folder at `root`.
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }
    /// The fleet CA's certificate (public: every robot has a copy).
    pub fn ca_cert(&self) -> PathBuf {
        self.root.join("ca/ca.crt")
    }
    /// The fleet CA's private key (0600; it never leaves the station's machine).
    pub fn ca_key(&self) -> PathBuf {
        self.root.join("ca/ca.key")
    }
    /// The station's certificate and key.
    pub fn station(&self) -> CertFiles {
        CertFiles {
            ca: self.ca_cert(),
            cert: self.root.join("station/station.crt"),
            key: self.root.join("station/station.key"),
        }
    }
    /// The folder of one robot's files (what is copied to the robot).
    pub fn robot_dir(&self, robot: &RobotId) -> PathBuf {
        self.root.join("robots").join(robot.as_str())
    }
    /// The folder of one monitor's files (`monitors/<name>/`: `ca.crt`, `monitor.crt`,
    /// `monitor.key`; copied to the monitor's machine).
    pub fn monitor_dir(&self, name: &str) -> PathBuf {
        self.root.join("monitors").join(name)
    }
    /// The fleet register: every certificate issued, and which are revoked.
    pub fn register(&self) -> PathBuf {
        self.root.join("fleet.toml")
    }
}

/// What one side's TLS needs: the fleet CA, its own certificate and key (PEM files).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CertFiles {
    /// The fleet CA certificate: the only CA the peer's certificate may chain to.
    pub ca: PathBuf,
    /// This side's certificate.
    pub cert: PathBuf,
    /// This side's private key.
    pub key: PathBuf,
}

impl CertFiles {
    /// The files of a robot folder as `pki issue` writes it (`robots/<id>/` of the fleet folder,
    /// copied to the robot): `ca.crt`, `robot.crt`, `robot.key`.
    pub fn robot(dir: &Path) -> Self {
        Self {
            ca: dir.join("ca.crt"),
            cert: dir.join("robot.crt"),
            key: dir.join("robot.key"),
        }
    }

    /// The files of a monitor folder as `pki add-monitor` writes it (`monitors/<name>/`):
    /// `ca.crt`, `monitor.crt`, `monitor.key`.
    pub fn monitor(dir: &Path) -> Self {
        Self {
            ca: dir.join("ca.crt"),
            cert: dir.join("monitor.crt"),
            key: dir.join("monitor.key"),
        }
    }

    /// Every file, for "missing file" checks.
    pub fn all(&self) -> [&Path; 3] {
        [&self.ca, &self.cert, &self.key]
    }
}

/// The link scheme of secure endpoints in defaults, advice and shipped configs. QUIC carries the
/// same mutual TLS 1.3 authentication as `tls/` (Zenoh reads both from `transport/link/tls`), but
/// its send and receive streams are separate objects: Zenoh's `tls/` link reads and writes one
/// rustls session from two tasks at once (eclipse-zenoh/zenoh#2557), which aborted a robot in our
/// CI with a corrupted allocation. `tls/` stays accepted for peers that speak nothing else.
pub const SECURE_SCHEME: &str = "quic";

/// Whether `proto` is a link scheme that carries the fleet's mutual TLS authentication.
pub fn is_secure_scheme(proto: &str) -> bool {
    matches!(proto, "quic" | "tls")
}

/// A warning for each `tls/` endpoint (see [`SECURE_SCHEME`] for why), to log once at start.
pub fn tls_link_warnings(endpoints: &[(Direction, String)]) -> Vec<String> {
    endpoints
        .iter()
        .filter(|(_, ep)| protocol(ep) == "tls")
        .map(|(_, ep)| {
            format!(
                "{ep}: Zenoh's tls/ link shares one TLS session between its reader and writer \
                 tasks (eclipse-zenoh/zenoh#2557) and can abort the process; prefer {SECURE_SCHEME}/{}",
                ep.split_once('/').map_or(ep.as_str(), |(_, a)| a)
            )
        })
        .collect()
}

/// Zenoh settings (key, json5 value) for TLS with mutual authentication against the fleet CA,
/// both when this side listens and when it connects. Names are verified on connect (the station's
/// certificate names the hosts it is reached by), and a link closes when a certificate expires.
/// Zenoh's `quic/` and `tls/` links both read these keys.
pub fn tls_settings(files: &CertFiles) -> Vec<(&'static str, String)> {
    let path = |p: &Path| Value::String(p.display().to_string()).to_string();
    vec![
        ("transport/link/tls/root_ca_certificate", path(&files.ca)),
        ("transport/link/tls/listen_certificate", path(&files.cert)),
        ("transport/link/tls/listen_private_key", path(&files.key)),
        ("transport/link/tls/connect_certificate", path(&files.cert)),
        ("transport/link/tls/connect_private_key", path(&files.key)),
        ("transport/link/tls/enable_mtls", "true".into()),
        ("transport/link/tls/verify_name_on_connect", "true".into()),
        ("transport/link/tls/close_link_on_expiration", "true".into()),
    ]
}

/// Every message kind Zenoh's access control knows.
const ALL_MESSAGES: [&str; 9] = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

fn rule(id: &str, flow: &str, messages: &[&str], key_exprs: &[String]) -> Value {
    json!({"id": id, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": key_exprs})
}

/// The access rules of a robot's own session (`access_control`), default deny: only a station
/// certificate may put commands to `terranav/<robot>/cmd/**`, query the robot, and subscribe to
/// (read) what it publishes; the robot itself publishes and answers only under
/// `terranav/<robot>/`. Anyone else (another robot, an unknown certificate, no certificate, a plain
/// TCP link) gets nothing in either direction.
pub fn robot_acl(robot: &RobotId) -> Value {
    let own = keys::robot_all(robot);
    let all = keys::all();
    // What the station sends a robot: its commands and its zone set (pushed, or asked for by
    // the robot when it starts).
    let zones = keys::key(robot, keys::Topic::Zones);
    let inbox = [keys::robot_commands(robot), zones.clone()];
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": [
            rule("station-commands", "ingress", &["put"], &inbox),
            rule("station-answers-zones", "ingress", &["reply", "declare_queryable"],
                 std::slice::from_ref(&zones)),
            rule("station-queries", "ingress", &["query"], std::slice::from_ref(&own)),
            rule("station-subscribes", "ingress",
                 &["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
                 std::slice::from_ref(&all)),
            rule("robot-publishes", "egress",
                 &["put", "reply", "declare_queryable", "liveliness_token"],
                 std::slice::from_ref(&own)),
            rule("robot-takes-commands", "egress", &["declare_subscriber"], &inbox),
            rule("robot-asks-zones", "egress", &["query"], std::slice::from_ref(&zones)),
        ],
        "subjects": [{"id": "station", "cert_common_names": [STATION_CN]}],
        "policies": [{
            "id": "station-commands-this-robot",
            "subjects": ["station"],
            "rules": ["station-commands", "station-answers-zones", "station-queries",
                      "station-subscribes", "robot-publishes", "robot-takes-commands",
                      "robot-asks-zones"],
        }],
    })
}

/// A robot the station admits: its id and the common name of its current certificate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdmittedRobot {
    /// Robot id.
    pub robot: RobotId,
    /// Common name of its one valid certificate.
    pub cn: String,
}

/// A monitor the station (or router) admits: its name and the common name of its current
/// certificate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdmittedMonitor {
    /// Monitor name.
    pub name: String,
    /// Common name of its one valid certificate.
    pub cn: String,
}

/// What a monitor may send a station or router: declarations of subscribers and liveliness
/// subscribers, liveliness queries and queries (reads), never a put, delete, reply or queryable.
const MONITOR_READS: [&str; 4] = [
    "declare_subscriber",
    "declare_liveliness_subscriber",
    "liveliness_query",
    "query",
];

/// What a station or router forwards to a monitor: the samples, replies, queryables and
/// liveliness tokens of the fleet (everything there is to watch).
const MONITOR_SEES: [&str; 5] = [
    "put",
    "delete",
    "reply",
    "declare_queryable",
    "liveliness_token",
];

/// The access rules of the station's session (and of `operator-station router`), default deny:
/// other station sessions (CLI calls with the station certificate) may do anything under
/// `terranav/`; each admitted robot may publish, answer queries and declare its liveliness only
/// under its own prefix, and receives only its own commands; each admitted monitor may subscribe
/// to and query everything under `terranav/` and sees what is published there, but none of its
/// puts (commands, zones, poses) is taken. Revoked, superseded and unknown certificates match no
/// subject.
pub fn station_acl(robots: &[AdmittedRobot], monitors: &[AdmittedMonitor]) -> Value {
    let all = keys::all();
    let mut rules = vec![
        rule(
            "station-in",
            "ingress",
            &ALL_MESSAGES,
            std::slice::from_ref(&all),
        ),
        rule(
            "station-out",
            "egress",
            &ALL_MESSAGES,
            std::slice::from_ref(&all),
        ),
    ];
    let mut subjects = vec![json!({"id": "station", "cert_common_names": [STATION_CN]})];
    let mut policies = vec![json!({
        "id": "stations", "subjects": ["station"], "rules": ["station-in", "station-out"],
    })];
    for r in robots {
        let id = r.robot.as_str();
        let own = keys::robot_all(&r.robot);
        let zones = keys::key(&r.robot, keys::Topic::Zones);
        let inbox = [keys::robot_commands(&r.robot), zones.clone()];
        let names = [
            format!("{id}-publishes"),
            format!("{id}-subscribes"),
            format!("{id}-commanded"),
            format!("{id}-queried"),
            format!("{id}-watched"),
            format!("{id}-asks-zones"),
            format!("{id}-zones-answered"),
        ];
        rules.push(rule(
            &names[0],
            "ingress",
            &["put", "reply", "declare_queryable", "liveliness_token"],
            std::slice::from_ref(&own),
        ));
        rules.push(rule(&names[1], "ingress", &["declare_subscriber"], &inbox));
        rules.push(rule(&names[2], "egress", &["put"], &inbox));
        rules.push(rule(
            &names[3],
            "egress",
            &["query"],
            std::slice::from_ref(&own),
        ));
        rules.push(rule(
            &names[4],
            "egress",
            &[
                "declare_subscriber",
                "declare_liveliness_subscriber",
                "liveliness_query",
            ],
            std::slice::from_ref(&all),
        ));
        rules.push(rule(
            &names[5],
            "ingress",
            &["query"],
            std::slice::from_ref(&zones),
        ));
        rules.push(rule(
            &names[6],
            "egress",
            &["reply", "declare_queryable"],
            std::slice::from_ref(&zones),
        ));
        let subject = format!("robot-{id}");
        subjects.push(json!({"id": subject, "cert_common_names": [r.cn]}));
        policies.push(json!({"id": format!("robot-{id}"), "subjects": [subject], "rules": names}));
    }
    if !monitors.is_empty() {
        rules.push(rule(
            "monitor-reads",
            "ingress",
            &MONITOR_READS,
            std::slice::from_ref(&all),
        ));
        rules.push(rule(
            "monitor-sees",
            "egress",
            &MONITOR_SEES,
            std::slice::from_ref(&all),
        ));
        let cns: Vec<&str> = monitors.iter().map(|m| m.cn.as_str()).collect();
        subjects.push(json!({"id": "monitors", "cert_common_names": cns}));
        policies.push(json!({
            "id": "monitors-read-only", "subjects": ["monitors"],
            "rules": ["monitor-reads", "monitor-sees"],
        }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

/// Which binary is asking, for the set-up advice in [`EndpointRefused`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// `operator-station` (serve, demo, CLI commands).
    Station,
    /// `robot-agent`.
    Robot,
}

/// Whether an endpoint listens or connects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// A listen endpoint.
    Listen,
    /// A connect endpoint.
    Connect,
}

/// An endpoint refused at start, with what to do instead.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct EndpointRefused(pub String);

/// True when `endpoint`'s address is loopback: `127.0.0.0/8`, `::1` or `localhost`. Everything
/// else (other addresses, `0.0.0.0`, `[::]`, host names) reaches a network.
pub fn is_loopback_endpoint(endpoint: &str) -> bool {
    let Some((_, rest)) = endpoint.split_once('/') else {
        return false;
    };
    // proto/address[?metadata][#config]; the address is host:port or [v6]:port.
    let address = rest.split(['?', '#']).next().unwrap_or_default();
    let host = match address.rsplit_once(':') {
        Some((h, _)) => h,
        None => address,
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.eq_ignore_ascii_case("localhost") {
        return true;
    }
    host.parse::<std::net::IpAddr>()
        .is_ok_and(|ip| ip.is_loopback())
}

fn protocol(endpoint: &str) -> &str {
    endpoint.split_once('/').map_or("", |(p, _)| p)
}

fn advice(side: Side) -> &'static str {
    match side {
        Side::Station => {
            "set up the fleet's certificates once with `operator-station pki init --dir pki` \
             (and `pki issue --robot ID --dir pki` per robot), then run \
             `operator-station serve --pki pki --zenoh-listen quic/0.0.0.0:7447`; \
             or keep Zenoh on 127.0.0.1 (the default)"
        }
        Side::Robot => {
            "on the station run `operator-station pki issue --robot ID --dir pki`, copy \
             pki/robots/ID/ to the robot, then run with `--pki DIR --connect quic/STATION:7447`; \
             or keep Zenoh on 127.0.0.1"
        }
    }
}

/// Checks the Zenoh endpoints a process is about to use. Without a PKI (`secure` false) every
/// endpoint must be loopback TCP or UDP: a plain link off loopback lets anyone on that network
/// read every pose and drive the robots. With a PKI every endpoint must be `quic/` or `tls/`
/// (mutual TLS against the fleet CA).
pub fn check_endpoints(
    side: Side,
    secure: bool,
    endpoints: &[(Direction, String)],
) -> Result<(), EndpointRefused> {
    for (dir, ep) in endpoints {
        let verb = match dir {
            Direction::Listen => "listen on",
            Direction::Connect => "connect to",
        };
        let proto = protocol(ep);
        if secure {
            if !is_secure_scheme(proto) {
                return Err(EndpointRefused(format!(
                    "refusing to {verb} {ep} with --pki: secure links are QUIC (or TLS) with \
                     mutual authentication, give it as {SECURE_SCHEME}/{}",
                    ep.split_once('/').map_or(ep.as_str(), |(_, a)| a)
                )));
            }
        } else if is_secure_scheme(proto) {
            return Err(EndpointRefused(format!(
                "refusing to {verb} {ep} without --pki: {proto}/ needs the fleet's certificates; {}",
                advice(side)
            )));
        } else if !matches!(proto, "tcp" | "udp") {
            return Err(EndpointRefused(format!(
                "refusing to {verb} {ep}: only tcp/ and udp/ on loopback, or {SECURE_SCHEME}/ with --pki"
            )));
        } else if !is_loopback_endpoint(ep) {
            return Err(EndpointRefused(format!(
                "refusing to {verb} {ep} without --pki: a plain link off loopback lets anyone on \
                 that network read every pose and drive the robots; {}",
                advice(side)
            )));
        }
    }
    Ok(())
}

/// The endpoints a Zenoh config listens on and connects to, read through `get_json` (the
/// config's `get_json`, so this crate needs no Zenoh): its `listen/endpoints` and
/// `connect/endpoints`. An error names the key.
pub fn config_endpoints(
    get_json: impl Fn(&str) -> Result<String, String>,
) -> Result<Vec<(Direction, String)>, String> {
    let mut eps = Vec::new();
    for (dir, key) in [
        (Direction::Listen, "listen/endpoints"),
        (Direction::Connect, "connect/endpoints"),
    ] {
        let json = get_json(key).map_err(|e| format!("zenoh config {key}: {e}"))?;
        let v: Value =
            serde_json::from_str(&json).map_err(|e| format!("zenoh config {key}: {e}"))?;
        eps.extend(endpoints_in_json(&v).into_iter().map(|e| (dir, e)));
    }
    Ok(eps)
}

/// The endpoints of a Zenoh `listen/endpoints` or `connect/endpoints` JSON value as Zenoh
/// reports it: a list, or a list per mode (`{"router": [...], "peer": [...]}`): every one found.
pub fn endpoints_in_json(v: &Value) -> Vec<String> {
    match v {
        Value::String(s) => vec![s.clone()],
        Value::Array(a) => a.iter().flat_map(endpoints_in_json).collect(),
        Value::Object(o) => o.values().flat_map(endpoints_in_json).collect(),
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rid(s: &str) -> RobotId {
        RobotId::new(s).unwrap()
    }

    fn monitor(name: &str, serial: u32) -> AdmittedMonitor {
        AdmittedMonitor {
            name: name.into(),
            cn: monitor_cn(name, serial),
        }
    }

    /// The rules of `acl` that the subject with common name `cn` gets: (flow, message, key) rows.
    fn grants(acl: &Value, cn: &str) -> Vec<(String, String, String)> {
        let subjects: Vec<&str> = acl["subjects"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| {
                s["cert_common_names"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|c| c == cn)
            })
            .map(|s| s["id"].as_str().unwrap())
            .collect();
        let mut out = Vec::new();
        for p in acl["policies"].as_array().unwrap() {
            let applies = p["subjects"]
                .as_array()
                .unwrap()
                .iter()
                .any(|s| subjects.contains(&s.as_str().unwrap()));
            if !applies {
                continue;
            }
            for rid in p["rules"].as_array().unwrap() {
                let r = acl["rules"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .find(|r| r["id"] == *rid)
                    .unwrap();
                assert_eq!(r["permission"], "allow");
                for f in r["flows"].as_array().unwrap() {
                    for m in r["messages"].as_array().unwrap() {
                        for k in r["key_exprs"].as_array().unwrap() {
                            out.push((
                                f.as_str().unwrap().to_string(),
                                m.as_str().unwrap().to_string(),
                                k.as_str().unwrap().to_string(),
                            ));
                        }
                    }
                }
            }
        }
        out
    }

    #[test]
    fn monitor_names_and_common_names() {
        assert_eq!(monitor_cn("ops-laptop", 2), "terranav:monitor:ops-laptop:2");
        assert_eq!(
            parse_monitor_cn("terranav:monitor:ops-laptop:2"),
            Some(("ops-laptop".into(), 2))
        );
        assert_eq!(parse_monitor_cn(STATION_CN), None);
        assert_eq!(parse_monitor_cn(&robot_cn(&rid("m1"), 1)), None);
        assert!(parse_robot_cn(&monitor_cn("m1", 1)).is_none());
        for bad in ["", "Ops", "a b", "a:b", "../x", &"a".repeat(65)] {
            assert!(check_monitor_name(bad).is_err(), "{bad}");
        }
        assert!(check_monitor_name("ops-2").is_ok());
    }

    #[test]
    fn a_monitor_reads_everything_and_puts_nothing_at_a_station_or_router() {
        let robots = [AdmittedRobot {
            robot: rid("r1"),
            cn: robot_cn(&rid("r1"), 1),
        }];
        let acl = station_acl(&robots, &[monitor("m1", 1), monitor("m2", 3)]);
        for cn in [monitor_cn("m1", 1), monitor_cn("m2", 3)] {
            let g = grants(&acl, &cn);
            let has = |f: &str, m: &str| {
                g.iter()
                    .any(|(gf, gm, k)| gf == f && gm == m && k == "terranav/**")
            };
            // Reads: subscribe, query, liveliness; and it is sent what is published.
            for m in MONITOR_READS {
                assert!(has("ingress", m), "{cn} {m}");
            }
            for m in ["put", "reply", "liveliness_token"] {
                assert!(has("egress", m), "{cn} {m}");
            }
            // Never takes a put, delete, reply, queryable or liveliness token from it: no command,
            // no zone set, no forged pose, no answer to a robot's zone query.
            for m in [
                "put",
                "delete",
                "reply",
                "declare_queryable",
                "liveliness_token",
            ] {
                assert!(
                    !g.iter().any(|(f, gm, _)| f == "ingress" && gm == m),
                    "{cn} may send {m}"
                );
            }
        }
        // A superseded or revoked monitor certificate (not in the list) gets nothing.
        assert!(grants(&acl, &monitor_cn("m1", 2)).is_empty());
        assert!(grants(&acl, &monitor_cn("m3", 1)).is_empty());
        // The station certificate keeps every right, a robot only its own prefix.
        assert!(grants(&acl, STATION_CN)
            .iter()
            .any(|(f, m, _)| f == "ingress" && m == "put"));
        let r1 = grants(&acl, &robot_cn(&rid("r1"), 1));
        assert!(r1
            .iter()
            .filter(|(f, m, _)| f == "ingress" && m == "put")
            .all(|(_, _, k)| k == "terranav/r1/**"));
        // No monitor: no monitor subject at all (the rules are as before).
        let plain = station_acl(&robots, &[]);
        assert!(!plain.to_string().contains("monitor"));
    }

    #[test]
    fn a_robot_names_no_monitor_so_a_monitor_gets_nothing_from_it() {
        let acl = robot_acl(&rid("r1"));
        assert!(grants(&acl, &monitor_cn("m1", 1)).is_empty());
        let station = grants(&acl, STATION_CN);
        assert!(station
            .iter()
            .any(|(f, m, k)| f == "ingress" && m == "put" && k == "terranav/r1/cmd/**"));
    }

    #[test]
    fn robot_common_names_round_trip_and_are_not_dns_names() {
        let cn = robot_cn(&rid("husky-1"), 3);
        assert_eq!(cn, "terranav:robot:husky-1:3");
        assert_eq!(parse_robot_cn(&cn), Some((rid("husky-1"), 3)));
        assert_eq!(parse_robot_cn(STATION_CN), None);
        assert_eq!(parse_robot_cn("terranav:robot:Bad:1"), None);
        assert!(cn.contains(':') && STATION_CN.contains(':'));
    }

    #[test]
    fn loopback_endpoints_are_recognised() {
        for ep in [
            "tcp/127.0.0.1:7447",
            "tcp/127.0.0.2:7447",
            "udp/[::1]:7447",
            "tcp/localhost:7447",
            "tcp/127.0.0.1:0#iface=lo",
            "tls/127.0.0.1:7447?prio=1",
        ] {
            assert!(is_loopback_endpoint(ep), "{ep}");
        }
        for ep in [
            "tcp/0.0.0.0:7447",
            "tcp/[::]:0",
            "tcp/192.168.1.20:7447",
            "tcp/station.local:7447",
            "tcp/10.0.0.1:7447",
            "nonsense",
        ] {
            assert!(!is_loopback_endpoint(ep), "{ep}");
        }
    }

    #[test]
    fn plain_links_off_loopback_are_refused_with_advice() {
        use Direction::*;
        let ok = [(Listen, "tcp/127.0.0.1:7447".to_string())];
        assert!(check_endpoints(Side::Station, false, &ok).is_ok());
        let e = check_endpoints(Side::Station, false, &[(Listen, "tcp/0.0.0.0:7447".into())])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("listen on tcp/0.0.0.0:7447")
                && e.contains("pki init")
                && e.contains("--pki"),
            "{e}"
        );
        let e = check_endpoints(Side::Robot, false, &[(Connect, "tcp/10.0.0.5:7447".into())])
            .unwrap_err()
            .to_string();
        assert!(e.contains("connect to") && e.contains("pki issue"), "{e}");
        assert!(check_endpoints(
            Side::Robot,
            false,
            &[(Connect, "quic/127.0.0.1:7447".into())]
        )
        .is_err());
        // With a PKI: QUIC or TLS everywhere, loopback or not.
        for ep in ["quic/10.0.0.5:7447", "tls/10.0.0.5:7447"] {
            assert!(check_endpoints(Side::Robot, true, &[(Connect, ep.into())]).is_ok());
        }
        let e = check_endpoints(Side::Robot, true, &[(Connect, "tcp/127.0.0.1:7447".into())])
            .unwrap_err()
            .to_string();
        assert!(e.contains("quic/127.0.0.1:7447"), "{e}");
    }

    #[test]
    fn tls_links_are_warned_about_and_quic_links_are_not() {
        use Direction::*;
        let eps = [
            (Listen, "quic/0.0.0.0:7447".to_string()),
            (Connect, "tls/10.0.0.5:7447".to_string()),
        ];
        let w = tls_link_warnings(&eps);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("zenoh#2557") && w[0].contains("quic/10.0.0.5:7447"),
            "{w:?}"
        );
    }

    #[test]
    fn endpoints_are_found_in_any_zenoh_shape() {
        let v = json!({"router": ["tcp/[::]:7447"], "peer": ["tcp/[::]:0"], "client": []});
        assert_eq!(endpoints_in_json(&v), vec!["tcp/[::]:0", "tcp/[::]:7447"]);
        assert_eq!(
            endpoints_in_json(&json!(["tls/1.2.3.4:1"])),
            vec!["tls/1.2.3.4:1"]
        );
    }

    #[test]
    fn acls_name_every_rule_they_use_and_deny_by_default() {
        let acls = [
            robot_acl(&rid("r1")),
            station_acl(
                &[
                    AdmittedRobot {
                        robot: rid("r1"),
                        cn: robot_cn(&rid("r1"), 1),
                    },
                    AdmittedRobot {
                        robot: rid("r2"),
                        cn: robot_cn(&rid("r2"), 4),
                    },
                ],
                &[monitor("m1", 2)],
            ),
        ];
        for acl in acls {
            assert_eq!(acl["default_permission"], "deny");
            let rules: Vec<&str> = acl["rules"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r["id"].as_str().unwrap())
                .collect();
            let subjects: Vec<&str> = acl["subjects"]
                .as_array()
                .unwrap()
                .iter()
                .map(|s| s["id"].as_str().unwrap())
                .collect();
            for p in acl["policies"].as_array().unwrap() {
                for r in p["rules"].as_array().unwrap() {
                    assert!(rules.contains(&r.as_str().unwrap()), "{r}");
                }
                for s in p["subjects"].as_array().unwrap() {
                    assert!(subjects.contains(&s.as_str().unwrap()), "{s}");
                }
            }
        }
        let r = robot_acl(&rid("r1")).to_string();
        assert!(r.contains("terranav/r1/cmd/**") && !r.contains("terranav/r2"));
    }

    #[test]
    fn a_configs_endpoints_are_read_from_both_keys_and_a_bad_one_is_named() {
        let eps = config_endpoints(|k| {
            Ok(match k {
                "listen/endpoints" => r#"{"router": ["tcp/0.0.0.0:7447"], "peer": []}"#,
                _ => r#"["tls/10.0.0.2:7447"]"#,
            }
            .to_owned())
        })
        .unwrap();
        assert_eq!(
            eps,
            vec![
                (Direction::Listen, "tcp/0.0.0.0:7447".to_owned()),
                (Direction::Connect, "tls/10.0.0.2:7447".to_owned()),
            ]
        );
        let e =
            config_endpoints(|k| Ok(if k.starts_with("connect") { "{" } else { "[]" }.to_owned()))
                .unwrap_err();
        assert!(e.contains("connect/endpoints"), "{e}");
    }
}
