//! The Zenoh settings both sides build their sessions from: the terranav defaults (what
//! `config/zenoh/*.json5` also spell out) and the endpoint overrides of a command line, as
//! `(key, json5 value)` pairs in the order they are applied. The robot bus and the station's bus
//! apply them to a `zenoh::Config` with `insert_json5`; this crate needs no Zenoh.

/// Link lease (ms): a peer silent for this long is dropped and its liveliness tokens vanish.
/// Four keep-alives per lease; 1.5 s keeps detection of a frozen or unplugged robot under 2 s
/// (a killed process closes its TCP socket and is detected at once).
pub const LEASE_MS: u64 = 1500;

/// Zenoh's peer default listens on every interface (`tcp/[::]:0`); a session that only connects
/// (a robot, a CLI call, a test) needs at most a loopback port for peers on its own machine.
pub const LOOPBACK_LISTENER: &str = "[\"tcp/127.0.0.1:0\"]";

/// The terranav defaults of a session built without a file: multicast scouting off, the short
/// lease, and a fast reconnect (a lost endpoint is retried every 0.5-1 s, so a restarted station
/// is rejoined quickly).
pub fn terranav_defaults() -> Vec<(&'static str, String)> {
    vec![
        ("scouting/multicast/enabled", "false".to_string()),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
        ("transport/link/tx/keep_alive", "4".to_string()),
        (
            "connect/retry",
            "{period_init_ms: 500, period_max_ms: 1000, period_increase_factor: 1.5}".to_string(),
        ),
    ]
}

/// Which listener a session gets when none is given and no file says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DefaultListen {
    /// A loopback port ([`LOOPBACK_LISTENER`]).
    Loopback,
    /// None (a secure session that only connects: a plain loopback listener would be refused).
    Nowhere,
}

/// What a command line asks of a session: a json5 file (or the defaults), a mode, endpoints.
#[derive(Clone, Copy, Debug)]
pub struct SessionPlan<'a> {
    /// A json5 config file is the base (its own settings are kept where nothing overrides).
    pub file_given: bool,
    /// `"peer"`, `"client"` or `"router"`; None: the file's, or peer without a file.
    pub mode: Option<&'a str>,
    /// Endpoints to listen on (empty: the file's, or `default_listen` without a file).
    pub listen: &'a [String],
    /// Endpoints to connect to (empty: the file's, or none).
    pub connect: &'a [String],
    /// The listener without a file and without `listen`.
    pub default_listen: DefaultListen,
}

impl SessionPlan<'_> {
    /// The settings to apply, in order, on top of the file (or of Zenoh's own defaults). Whatever
    /// the file says, multicast scouting stays off: a fresh machine needs no network set-up and
    /// tests on one host must not find each other.
    pub fn settings(&self) -> Vec<(&'static str, String)> {
        let mut kv = Vec::new();
        if !self.file_given {
            kv.extend(terranav_defaults());
            kv.push(("mode", format!("{:?}", self.mode.unwrap_or("peer"))));
        } else if let Some(m) = self.mode {
            kv.push(("mode", format!("{m:?}")));
        }
        kv.push(("scouting/multicast/enabled", "false".to_string()));
        if !self.listen.is_empty() {
            kv.push(("listen/endpoints", json_list(self.listen)));
        } else if !self.file_given {
            let v = match self.default_listen {
                DefaultListen::Loopback => LOOPBACK_LISTENER.to_string(),
                DefaultListen::Nowhere => "[]".to_string(),
            };
            kv.push(("listen/endpoints", v));
        }
        if !self.connect.is_empty() {
            kv.push(("connect/endpoints", json_list(self.connect)));
        }
        kv
    }
}

fn json_list(v: &[String]) -> String {
    serde_json::Value::from(v.to_vec()).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn get<'a>(kv: &'a [(&str, String)], k: &str) -> Option<&'a str> {
        kv.iter()
            .rev()
            .find(|(key, _)| *key == k)
            .map(|(_, v)| v.as_str())
    }

    #[test]
    fn defaults_without_a_file_and_overrides_on_top_of_one() {
        let connect = ["tcp/127.0.0.1:7447".to_string()];
        let plain = SessionPlan {
            file_given: false,
            mode: None,
            listen: &[],
            connect: &connect,
            default_listen: DefaultListen::Loopback,
        };
        let kv = plain.settings();
        assert_eq!(get(&kv, "mode"), Some("\"peer\""));
        assert_eq!(get(&kv, "transport/link/tx/lease"), Some("1500"));
        assert_eq!(get(&kv, "listen/endpoints"), Some(LOOPBACK_LISTENER));
        assert_eq!(
            get(&kv, "connect/endpoints"),
            Some("[\"tcp/127.0.0.1:7447\"]")
        );
        let secure = SessionPlan {
            default_listen: DefaultListen::Nowhere,
            mode: Some("client"),
            ..plain
        };
        let kv = secure.settings();
        assert_eq!(get(&kv, "listen/endpoints"), Some("[]"));
        assert_eq!(get(&kv, "mode"), Some("\"client\""));
        // On a file: only scouting and what was given.
        let file = SessionPlan {
            file_given: true,
            mode: None,
            ..plain
        };
        let kv = file.settings();
        assert_eq!(get(&kv, "transport/link/tx/lease"), None);
        assert_eq!(get(&kv, "listen/endpoints"), None);
        assert_eq!(get(&kv, "mode"), None);
        assert_eq!(get(&kv, "scouting/multicast/enabled"), Some("false"));
    }
}
