//! The station's side of secure links: TLS with mutual authentication with the station's
//! certificate, the station's access rules built from the fleet register (each admitted robot
//! only under its own prefix; revoked and unknown certificates nowhere), and the refusal of plain
//! links off loopback. `serve` re-reads the register when it changes ([`RegisterWatch`]) and
//! re-opens the station's session with the new rules. A monitor (a read-only station, `serve
//! --monitor NAME`) holds its own certificate instead and is a Zenoh client of a station or
//! router, whose rules let it watch and never command.

use std::path::{Path, PathBuf};

use common::security::{self, CertFiles, FleetDir, Side};

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

/// The station's access rules for the robots and monitors the register admits now.
pub fn station_acl(fleet: &FleetDir) -> anyhow::Result<serde_json::Value> {
    let reg = pki::read_register(fleet)?;
    let now_s = crate::station::now_unix_ms() as i64 / 1000;
    let admitted = reg.admitted(now_s);
    let monitors = reg.admitted_monitors(now_s);
    tracing::info!(
        robots = ?admitted.iter().map(|a| a.robot.as_str()).collect::<Vec<_>>(),
        monitors = ?monitors.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(),
        "access rules: admitted robots and read-only monitors"
    );
    Ok(security::station_acl(&admitted, &monitors))
}

/// The monitor's certificate files in `dir`: a monitor folder as `pki add-monitor` writes it
/// (copied to the monitor's machine), or a whole fleet PKI folder holding `monitors/<name>/`.
/// Every file must exist and the certificate must have been issued to monitor `name`.
pub fn monitor_files(dir: &Path, name: &str) -> anyhow::Result<CertFiles> {
    security::check_monitor_name(name).map_err(|e| anyhow::anyhow!(e))?;
    let in_fleet = FleetDir::new(dir).monitor_dir(name);
    let folder: PathBuf = if in_fleet.join("monitor.crt").is_file() {
        in_fleet
    } else {
        dir.to_path_buf()
    };
    let files = CertFiles::monitor(&folder);
    for f in files.all() {
        if !f.is_file() {
            anyhow::bail!(
                "--pki {} --monitor {name}: {} is missing (`operator-station pki add-monitor \
                 --name {name} --dir PKI` writes PKI/monitors/{name}/ with ca.crt, monitor.crt and \
                 monitor.key; copy that folder to the monitor's machine)",
                dir.display(),
                f.display()
            );
        }
    }
    let cn = common_name(&files.cert)?;
    match security::parse_monitor_cn(&cn) {
        Some((n, _)) if n == name => Ok(files),
        Some((n, _)) => anyhow::bail!(
            "{} was issued to monitor {n}, not {name}",
            files.cert.display()
        ),
        None => anyhow::bail!(
            "{} is not a monitor certificate (common name {cn:?}); make one with \
             `operator-station pki add-monitor --name {name} --dir PKI`",
            files.cert.display()
        ),
    }
}

/// The subject common name of a PEM certificate.
fn common_name(cert: &Path) -> anyhow::Result<String> {
    let pem = std::fs::read(cert).map_err(|e| anyhow::anyhow!("{}: {e}", cert.display()))?;
    let (_, pem) = x509_parser::pem::parse_x509_pem(&pem)
        .map_err(|e| anyhow::anyhow!("{}: not PEM: {e}", cert.display()))?;
    let x509 = pem
        .parse_x509()
        .map_err(|e| anyhow::anyhow!("{}: not a certificate: {e}", cert.display()))?;
    let cn = x509
        .subject()
        .iter_common_name()
        .next()
        .and_then(|a| a.as_str().ok())
        .unwrap_or_default()
        .to_string();
    Ok(cn)
}

/// Turns a station config into a monitor's: TLS with the monitor's own certificate, Zenoh client
/// mode (a client is served by the station or router it connects to and links to nothing else,
/// so everything it sees has passed that side's rules) and no listener. It sets no access rules
/// of its own: what keeps a monitor from commanding is the others' rules, which a modified
/// monitor binary cannot change.
pub fn apply_monitor(c: &mut zenoh::Config, dir: &Path, name: &str) -> anyhow::Result<()> {
    let files = monitor_files(dir, name)?;
    for (k, v) in security::tls_settings(&files) {
        set(c, k, &v)?;
    }
    set(c, "mode", "\"client\"")?;
    set(c, "listen/endpoints", "[]")
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
