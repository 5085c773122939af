//! Where the Zenoh session connects and listens, and the configuration it is built from.

use std::path::PathBuf;

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
    /// (every endpoint must then be `tls/`). None: plain links, loopback only.
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
    /// lease so a vanished peer is declared gone within 2 s, fast reconnect, then the overrides,
    /// then TLS when certificates are given. Refuses plain endpoints off loopback (and, with
    /// certificates, anything but `tls/`).
    pub fn to_config(&self) -> Result<zenoh::Config, BusError> {
        let c = self.build_config()?;
        secure::check_endpoints(&c, self.tls.is_some())?;
        Ok(c)
    }

    fn build_config(&self) -> Result<zenoh::Config, BusError> {
        let mut c = match &self.file {
            Some(f) => zenoh::Config::from_file(f)
                .map_err(|e| BusError::Config(format!("{}: {e}", f.display())))?,
            None => {
                let mut c = zenoh::Config::default();
                apply_terranav_defaults(&mut c)?;
                c
            }
        };
        let set = |c: &mut zenoh::Config, k: &str, v: &str| {
            c.insert_json5(k, v)
                .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))
        };
        if self.file.is_none() {
            let mode = match self.mode.unwrap_or_default() {
                ZenohMode::Peer => "\"peer\"",
                ZenohMode::Client => "\"client\"",
            };
            set(&mut c, "mode", mode)?;
        }
        // Whatever the file says, never scout by multicast: a fresh machine needs no network set-up
        // and tests on one host must not find each other.
        set(&mut c, "scouting/multicast/enabled", "false")?;
        if !self.connect.is_empty() {
            let v = serde_json::to_string(&self.connect)
                .map_err(|e| BusError::Config(e.to_string()))?;
            set(&mut c, "connect/endpoints", &v)?;
        }
        if !self.listen.is_empty() {
            let v =
                serde_json::to_string(&self.listen).map_err(|e| BusError::Config(e.to_string()))?;
            set(&mut c, "listen/endpoints", &v)?;
        } else if self.file.is_none() && self.tls.is_some() {
            // A secure robot connects to the station and needs no listener; `--listen tls/...`
            // lets stations link to it directly.
            set(&mut c, "listen/endpoints", "[]")?;
        } else if self.file.is_none() {
            // Zenoh's peer default listens on every interface (`tcp/[::]:0`); the robot connects
            // to the station, so it only needs a loopback port for peers on its own machine.
            set(&mut c, "listen/endpoints", "[\"tcp/127.0.0.1:0\"]")?;
        }
        if let Some(files) = &self.tls {
            secure::apply_tls(&mut c, files)?;
        }
        Ok(c)
    }
}

/// Link lease (ms): a peer silent for this long is dropped and its liveliness tokens vanish.
/// Four keep-alives per lease; 1.5 s keeps detection of a frozen or unplugged robot under 2 s
/// (a killed process closes its TCP socket and is detected at once).
pub const LEASE_MS: u64 = 1500;

/// The terranav defaults that `config/zenoh/*.json5` also spell out.
pub fn apply_terranav_defaults(c: &mut zenoh::Config) -> Result<(), BusError> {
    let kv = [
        ("scouting/multicast/enabled", "false".to_string()),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
        ("transport/link/tx/keep_alive", "4".to_string()),
        // Retry a lost endpoint every 0.5-1 s so a restarted station is rejoined quickly.
        (
            "connect/retry",
            "{period_init_ms: 500, period_max_ms: 1000, period_increase_factor: 1.5}".to_string(),
        ),
    ];
    for (k, v) in kv {
        c.insert_json5(k, &v)
            .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))?;
    }
    Ok(())
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
        // A secure robot needs tls/ everywhere; its default is to listen nowhere.
        let files = CertFiles::robot(std::path::Path::new("/nonexistent"));
        let secure = ZenohSettings {
            tls: Some(files.clone()),
            ..ZenohSettings::connect_to("tls/192.0.2.7:7447")
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
