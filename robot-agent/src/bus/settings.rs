//! Where the Zenoh session connects and listens, and the configuration it is built from.

use std::path::PathBuf;

pub use common::bus_config::LEASE_MS;
use common::bus_config::{terranav_defaults, DefaultListen, SessionPlan};
use common::command::ReplayWindow;
use common::keys::RobotId;
use common::security::CertFiles;

use super::{secure, BusError, CommandLimits, DEFAULT_STATION_ENDPOINT};

/// Zenoh mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ZenohMode {
    /// Peer (default): connects to the given endpoints, others may connect to it.
    #[default]
    Peer,
    /// Client of a router (or of a peer that listens).
    Client,
}

/// Where the Zenoh session connects and listens.
#[derive(Clone, Debug, Default)]
pub struct ZenohSettings {
    /// A json5 Zenoh config file (`config/zenoh/*.json5`); the fields below override it.
    pub file: Option<PathBuf>,
    /// Mode when no file is given (a file's own `mode` wins).
    pub mode: Option<ZenohMode>,
    /// Endpoints to connect to, e.g. `tcp/127.0.0.1:7447`.
    pub connect: Vec<String>,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// The robot's certificates: TLS with mutual authentication and the robot's access rules
    /// (every endpoint must then be `quic/` or `tls/`). None: plain links, loopback only.
    pub tls: Option<CertFiles>,
}

impl ZenohSettings {
    /// Settings that connect to one endpoint (the station's listen endpoint).
    pub fn connect_to(endpoint: impl Into<String>) -> Self {
        Self {
            connect: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// Settings that listen on one endpoint (what the station does).
    pub fn listen_on(endpoint: impl Into<String>) -> Self {
        Self {
            listen: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// Builds the Zenoh config: the file (or terranav defaults), multicast scouting off, short
    /// lease so a vanished peer is declared gone within 2 s, fast reconnect, then the overrides
    /// (all from [`common::bus_config`], shared with the station), then TLS when certificates are given. Refuses plain endpoints off loopback (and, with
    /// certificates, anything but `quic/` or `tls/`).
    pub fn to_config(&self) -> Result<zenoh::Config, BusError> {
        let c = self.build_config()?;
        secure::check_endpoints(&c, self.tls.is_some())?;
        Ok(c)
    }

    fn build_config(&self) -> Result<zenoh::Config, BusError> {
        let mut c = match &self.file {
            Some(f) => zenoh::Config::from_file(f)
                .map_err(|e| BusError::Config(format!("{}: {e}", f.display())))?,
            None => zenoh::Config::default(),
        };
        // The mode only without a file (a file's own `mode` wins).
        let mode = match (self.file.is_none(), self.mode.unwrap_or_default()) {
            (false, _) => None,
            (true, ZenohMode::Peer) => Some("peer"),
            (true, ZenohMode::Client) => Some("client"),
        };
        let plan = SessionPlan {
            file_given: self.file.is_some(),
            mode,
            listen: &self.listen,
            connect: &self.connect,
            // A secure robot connects to the station and needs no listener; `--listen quic/...`
            // lets stations link to it directly.
            default_listen: if self.tls.is_some() {
                DefaultListen::Nowhere
            } else {
                DefaultListen::Loopback
            },
        };
        apply(&mut c, plan.settings())?;
        if let Some(files) = &self.tls {
            secure::apply_tls(&mut c, files)?;
        }
        Ok(c)
    }
}

fn apply(c: &mut zenoh::Config, kv: Vec<(&str, String)>) -> Result<(), BusError> {
    for (k, v) in kv {
        c.insert_json5(k, &v)
            .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))?;
    }
    Ok(())
}

/// The terranav defaults that `config/zenoh/*.json5` also spell out (shared with the station:
/// [`common::bus_config::terranav_defaults`]).
pub fn apply_terranav_defaults(c: &mut zenoh::Config) -> Result<(), BusError> {
    apply(c, terranav_defaults())
}

/// Everything [`RobotBus::open`](super::RobotBus::open) needs.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// This robot.
    pub robot: RobotId,
    /// Zenoh endpoints.
    pub zenoh: ZenohSettings,
    /// Command validation limits.
    pub limits: CommandLimits,
    /// How fresh a command must be (replays are refused).
    pub replay: ReplayWindow,
    /// What goes up the link first, and how much of it (`[bus] uplink_budget_kbps`).
    pub uplink: super::uplink::UplinkPolicy,
}

/// `[bus]` of `config/robot.toml`: what the robot sends over a slow link (`robot-agent run` and
/// `sim`; the command line overrides).
#[derive(Clone, Debug, serde::Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct BusFile {
    /// Everything the robot publishes, kilobits per second; 0 = unlimited.
    pub uplink_budget_kbps: f64,
    /// A tile held back this long goes before newer ones, seconds.
    pub uplink_max_wait_s: f64,
}

impl Default for BusFile {
    fn default() -> Self {
        let p = super::uplink::UplinkPolicy::default();
        Self {
            uplink_budget_kbps: p.budget_kbps,
            uplink_max_wait_s: p.max_wait_s,
        }
    }
}

impl BusFile {
    /// The uplink policy, `budget_kbps` overriding the file's budget; refuses a negative or
    /// non-finite value.
    pub fn uplink(
        &self,
        budget_kbps: Option<f64>,
    ) -> Result<super::uplink::UplinkPolicy, BusError> {
        let budget_kbps = budget_kbps.unwrap_or(self.uplink_budget_kbps);
        if !(budget_kbps.is_finite() && budget_kbps >= 0.0) {
            return Err(BusError::Config(format!(
                "uplink_budget_kbps = {budget_kbps}: must be 0 (unlimited) or a positive number"
            )));
        }
        if !(self.uplink_max_wait_s.is_finite() && self.uplink_max_wait_s > 0.0) {
            return Err(BusError::Config(format!(
                "uplink_max_wait_s = {}: must be positive",
                self.uplink_max_wait_s
            )));
        }
        Ok(super::uplink::UplinkPolicy {
            budget_kbps,
            max_wait_s: self.uplink_max_wait_s,
        })
    }
}

impl BusConfig {
    /// A robot connecting to the station's default endpoint.
    pub fn new(robot: RobotId) -> Self {
        Self {
            robot,
            zenoh: ZenohSettings::connect_to(DEFAULT_STATION_ENDPOINT),
            limits: CommandLimits::default(),
            replay: ReplayWindow::default(),
            uplink: super::uplink::UplinkPolicy::default(),
        }
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_uplink_budget_comes_from_the_file_unless_the_command_line_says_otherwise() {
        let file = BusFile {
            uplink_budget_kbps: 128.0,
            ..BusFile::default()
        };
        assert_eq!(file.uplink(None).unwrap().budget_kbps, 128.0);
        assert_eq!(file.uplink(Some(64.0)).unwrap().budget_kbps, 64.0);
        assert_eq!(
            file.uplink(Some(0.0)).unwrap().budget_kbps,
            0.0,
            "unlimited"
        );
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            let e = file.uplink(Some(bad)).unwrap_err().to_string();
            assert!(e.contains("uplink_budget_kbps"), "{e}");
        }
        let e = BusFile {
            uplink_max_wait_s: 0.0,
            ..BusFile::default()
        }
        .uplink(None)
        .unwrap_err()
        .to_string();
        assert!(e.contains("uplink_max_wait_s"), "{e}");
    }

    #[test]
    fn plain_endpoints_off_loopback_are_refused() {
        let e = ZenohSettings::connect_to("tcp/192.0.2.7:7447")
            .to_config()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("without --pki") && e.contains("pki issue"),
            "{e}"
        );
        let e = ZenohSettings::listen_on("tcp/0.0.0.0:7447")
            .to_config()
            .unwrap_err()
            .to_string();
        assert!(e.contains("listen on tcp/0.0.0.0:7447"), "{e}");
        // A secure robot needs quic/ (or tls/) everywhere; its default is to listen nowhere.
        let files = CertFiles::robot(std::path::Path::new("/nonexistent"));
        let secure = ZenohSettings {
            tls: Some(files.clone()),
            ..ZenohSettings::connect_to("quic/192.0.2.7:7447")
        };
        let c = secure.to_config().unwrap();
        assert_eq!(c.get_json("listen/endpoints").unwrap(), "[]");
        assert_eq!(
            c.get_json("transport/link/tls/enable_mtls").unwrap(),
            "true"
        );
        let plain_with_pki = ZenohSettings {
            tls: Some(files),
            ..ZenohSettings::connect_to("tcp/127.0.0.1:7447")
        };
        assert!(plain_with_pki.to_config().is_err());
    }

    #[test]
    fn config_has_multicast_off_and_short_lease() {
        let c = ZenohSettings::connect_to("tcp/127.0.0.1:7999")
            .to_config()
            .unwrap();
        let j = format!("{c}");
        assert!(j.contains("7999"), "{j}");
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(
            c.get_json("transport/link/tx/lease").unwrap(),
            LEASE_MS.to_string()
        );
        assert_eq!(
            c.get_json("listen/endpoints").unwrap(),
            r#"["tcp/127.0.0.1:0"]"#,
            "loopback only by default"
        );
    }

    #[test]
    fn shipped_zenoh_files_keep_the_lease_and_scouting_defaults() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/zenoh");
        for f in ["robot.json5", "station.json5", "router-client.json5"] {
            // Unchecked: router-client.json5 connects off loopback, which needs --pki.
            let c = ZenohSettings {
                file: Some(dir.join(f)),
                ..ZenohSettings::default()
            }
            .build_config()
            .unwrap_or_else(|e| panic!("{f}: {e}"));
            assert_eq!(
                c.get_json("transport/link/tx/lease").unwrap(),
                LEASE_MS.to_string(),
                "{f}"
            );
            assert_eq!(
                c.get_json("transport/link/tx/keep_alive").unwrap(),
                "4",
                "{f}"
            );
            assert_eq!(
                c.get_json("scouting/multicast/enabled").unwrap(),
                "false",
                "{f}"
            );
        }
    }
}
