//! The station's side of secure links: TLS with mutual authentication with the station's
//! certificate, the station's access rules built from the fleet register (each admitted robot
//! only under its own prefix; revoked and unknown certificates nowhere), and the refusal of plain
//! links off loopback. `serve` re-reads the register when it changes ([`RegisterWatch`]) and
//! re-opens the station's session with the new rules.

use std::path::Path;

use common::security::{self, FleetDir, Side};

use crate::pki;

fn set(c: &mut zenoh::Config, k: &str, v: &str) -> anyhow::Result<()> {
    c.insert_json5(k, v)
        .map_err(|e| anyhow::anyhow!("zenoh config {k} = {v}: {e}"))
}

/// Turns on TLS with the station's certificate and, unless `client_only`, the station's access
/// rules from the register in `dir` (a CLI call that only connects needs no rules of its own: the
/// robots' rules admit it by its station certificate).
pub fn apply(c: &mut zenoh::Config, dir: &Path, client_only: bool) -> anyhow::Result<()> {
    let fleet = pki::require_fleet(dir)?;
    for (k, v) in security::tls_settings(&fleet.station()) {
        set(c, k, &v)?;
    }
    if !client_only {
        set(c, "access_control", &station_acl(&fleet)?.to_string())?;
    }
    Ok(())
}

/// The station's access rules for the robots the register admits now.
pub fn station_acl(fleet: &FleetDir) -> anyhow::Result<serde_json::Value> {
    let reg = pki::read_register(fleet)?;
    let now_s = crate::station::now_unix_ms() as i64 / 1000;
    let admitted = reg.admitted(now_s);
    tracing::info!(
        robots = ?admitted.iter().map(|a| a.robot.as_str()).collect::<Vec<_>>(),
        "access rules: admitted robots"
    );
    Ok(security::station_acl(&admitted))
}

/// Refuses a config that would listen on or connect to a plain link off loopback (or, when
/// `secure`, anything but `quic/` or `tls/`), with what to do instead; warns once per `tls/`
/// endpoint (see [`security::SECURE_SCHEME`]).
pub fn check_endpoints(c: &zenoh::Config, secure: bool) -> anyhow::Result<()> {
    let eps = security::config_endpoints(|k| c.get_json(k).map_err(|e| e.to_string()))
        .map_err(|e| anyhow::anyhow!(e))?;
    security::check_endpoints(Side::Station, secure, &eps).map_err(|e| anyhow::anyhow!(e.0))?;
    for w in security::tls_link_warnings(&eps) {
        tracing::warn!("{w}");
    }
    Ok(())
}

/// Notices when the fleet register changes (an issue or a revocation while the station runs).
pub struct RegisterWatch {
    fleet: FleetDir,
    last: Option<Vec<u8>>,
}

impl RegisterWatch {
    /// Watches the register of the PKI folder `dir`, as it is now.
    pub fn new(dir: &Path) -> Self {
        let fleet = FleetDir::new(dir);
        let last = std::fs::read(fleet.register()).ok();
        Self { fleet, last }
    }

    /// True once after each change of the register's content.
    pub fn changed(&mut self) -> bool {
        let now = std::fs::read(self.fleet.register()).ok();
        if now != self.last {
            self.last = now;
            return true;
        }
        false
    }
}
