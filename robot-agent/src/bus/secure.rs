//! The robot's side of secure links: TLS with mutual authentication against the fleet CA, the
//! access rules on the robot's own session (`common::security::robot_acl`: only a station
//! certificate commands or reads it; it publishes only under its own prefix), and the refusal of
//! plain links off loopback.
//!
//! The rules run on the robot's session, not only at a station or router, because peers link
//! directly: whoever reaches the robot's session meets them.

use std::path::{Path, PathBuf};

use common::keys::RobotId;
use common::security::{self, CertFiles, Side};

use super::BusError;

fn set(c: &mut zenoh::Config, k: &str, v: &str) -> Result<(), BusError> {
    c.insert_json5(k, v)
        .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))
}

/// The robot's certificate files in `dir`: either a robot folder as `pki issue` writes it (copied
/// to the robot), or a whole fleet PKI folder holding `robots/<robot>/` (one machine, the demo).
/// Every file must exist, and the certificate must have been issued to `robot`.
pub fn robot_files(dir: &Path, robot: &RobotId) -> Result<CertFiles, BusError> {
    let fleet = security::FleetDir::new(dir).robot_dir(robot);
    let folder: PathBuf = if fleet.join("robot.crt").is_file() {
        fleet
    } else {
        dir.to_path_buf()
    };
    let files = CertFiles::robot(&folder);
    for f in files.all() {
        if !f.is_file() {
            return Err(BusError::Config(format!(
                "--pki {}: {} is missing (operator-station pki issue --robot {robot} --dir PKI \
                 writes PKI/robots/{robot}/ with ca.crt, robot.crt and robot.key; copy that folder \
                 to the robot)",
                dir.display(),
                f.display()
            )));
        }
    }
    let (id, _) = robot_identity(&files.cert)?;
    if &id != robot {
        return Err(BusError::Config(format!(
            "{} was issued to robot {id}, not {robot}: the station would refuse everything this \
             robot publishes",
            files.cert.display()
        )));
    }
    Ok(files)
}

/// The robot id and serial a robot certificate was issued to (its common name).
pub fn robot_identity(cert: &Path) -> Result<(RobotId, u32), BusError> {
    let bad = |what: String| BusError::Config(format!("{}: {what}", cert.display()));
    let pem = std::fs::read(cert).map_err(|e| bad(e.to_string()))?;
    let (_, pem) =
        x509_parser::pem::parse_x509_pem(&pem).map_err(|e| bad(format!("not PEM: {e}")))?;
    let x509 = pem
        .parse_x509()
        .map_err(|e| bad(format!("not a certificate: {e}")))?;
    let cn = x509
        .subject()
        .iter_common_name()
        .next()
        .and_then(|a| a.as_str().ok())
        .unwrap_or_default()
        .to_string();
    security::parse_robot_cn(&cn).ok_or_else(|| {
        bad(format!(
            "not a robot certificate of a terranav fleet (common name {cn:?})"
        ))
    })
}

/// Turns TLS with mutual authentication on.
pub fn apply_tls(c: &mut zenoh::Config, files: &CertFiles) -> Result<(), BusError> {
    for (k, v) in security::tls_settings(files) {
        set(c, k, &v)?;
    }
    Ok(())
}

/// Puts the robot's access rules on its session.
pub fn apply_robot_acl(c: &mut zenoh::Config, robot: &RobotId) -> Result<(), BusError> {
    set(c, "access_control", &security::robot_acl(robot).to_string())
}

/// Refuses the config when it would listen on or connect to a plain link off loopback (or, when
/// `secure`, anything but `quic/` or `tls/`), with what to do instead; warns once per `tls/`
/// endpoint (see [`security::SECURE_SCHEME`]).
pub fn check_endpoints(c: &zenoh::Config, secure: bool) -> Result<(), BusError> {
    let eps = security::config_endpoints(|k| c.get_json(k).map_err(|e| e.to_string()))
        .map_err(BusError::Config)?;
    security::check_endpoints(Side::Robot, secure, &eps).map_err(|e| BusError::Refused(e.0))?;
    for w in security::tls_link_warnings(&eps) {
        tracing::warn!("{w}");
    }
    Ok(())
}
