//! The fleet's certificates: `operator-station pki init | issue | revoke`.
//!
//! One CA per fleet, made and kept on the station's machine (`ca/ca.key`, 0600, never copied);
//! the station's certificate (common name `terranav:station`, the only identity robots take
//! commands from) and one certificate per robot issue (`terranav:robot:<id>:<serial>`), written to
//! `robots/<id>/` with a copy of the CA certificate, to be copied to the robot. Every issue and
//! revocation is in the register (`fleet.toml`, [`register`]), which the station reads to know
//! whom to admit. Keys are ECDSA P-256, written 0600 in 0700 folders, and never printed or stored
//! anywhere else (not in the station's database).
//!
//! Zenoh has no revocation list check: a revoked robot's certificate still chains to the CA, so
//! revocation works through the station's access rules, which name each admitted robot's current
//! certificate. A revoked certificate (or one superseded by a re-issue) matches no rule: its links
//! carry nothing in either direction, and the robot shows offline. The running station re-reads
//! the register when it changes and re-opens its session, so a revoked robot is dropped at once
//! and refused at every later connection.

pub mod register;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use common::keys::RobotId;
use common::security::{self, FleetDir};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};
use serde::Serialize;
use time::{Duration, OffsetDateTime};

use register::{Issued, Kind, Register};

/// Validity of the fleet CA, days.
pub const CA_DAYS: i64 = 3650;
/// Validity of the station's certificate, days.
pub const STATION_DAYS: i64 = 730;
/// Default validity of a robot certificate, days (`pki issue --days`).
pub const ROBOT_DAYS: i64 = 365;

/// Names every certificate we make answers to besides the ones given: what a process on the same
/// machine connects to.
const LOOPBACK_NAMES: [&str; 3] = ["localhost", "127.0.0.1", "::1"];

/// What `pki init` made.
#[derive(Debug, Serialize)]
pub struct InitReport {
    /// The PKI folder.
    pub dir: PathBuf,
    /// CA certificate.
    pub ca_cert: PathBuf,
    /// Station certificate.
    pub station_cert: PathBuf,
    /// Names (DNS names, addresses) the station's certificate is valid for.
    pub station_names: Vec<String>,
}

/// What `pki issue` made.
#[derive(Debug, Serialize)]
pub struct IssueReport {
    /// Robot id.
    pub robot: String,
    /// Issue number.
    pub serial: u32,
    /// Common name.
    pub cn: String,
    /// The folder to copy to the robot.
    pub robot_dir: PathBuf,
    /// End of validity, Unix seconds.
    pub not_after_unix_s: i64,
    /// The robot's previous certificate, now superseded (refused by the station), if any.
    pub superseded_serial: Option<u32>,
}

/// What `pki revoke` did.
#[derive(Debug, Serialize)]
pub struct RevokeReport {
    /// Robot id.
    pub robot: String,
    /// Certificates newly marked revoked.
    pub revoked: usize,
    /// Whether the station's copy of the robot's files was deleted.
    pub deleted_robot_dir: bool,
}

fn now() -> OffsetDateTime {
    OffsetDateTime::now_utc()
}

/// Validity from a day ago (clocks of robots in the field lag) to `days` from now.
fn validity(params: &mut CertificateParams, days: i64) {
    params.not_before = now() - Duration::days(1);
    params.not_after = now() + Duration::days(days);
}

fn names(extra: &[String]) -> Vec<String> {
    let mut v: Vec<String> = LOOPBACK_NAMES.iter().map(|s| s.to_string()).collect();
    for n in extra {
        let n = n.trim().to_string();
        if !n.is_empty() && !v.contains(&n) {
            v.push(n);
        }
    }
    v
}

/// The machine's host name, when the system says (the station's certificate names it, so
/// browsers and robots may reach the station by it).
fn host_name() -> Option<String> {
    let h = std::fs::read_to_string("/proc/sys/kernel/hostname").ok()?;
    let h = h.trim();
    (!h.is_empty() && h != "localhost").then(|| h.to_string())
}

fn leaf_params(cn: &str, sans: Vec<String>, days: i64) -> anyhow::Result<CertificateParams> {
    let mut p = CertificateParams::new(sans).context("certificate names")?;
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationName, "terranav fleet");
    dn.push(DnType::CommonName, cn);
    p.distinguished_name = dn;
    p.is_ca = IsCa::NoCa;
    p.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    // Both: a station or robot is the TLS server when it listens and the client when it connects.
    p.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    p.use_authority_key_identifier_extension = true;
    validity(&mut p, days);
    Ok(p)
}

/// Creates `dir` (0700 on Unix) and its parents.
fn private_dir(dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("create {}", dir.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
            .with_context(|| format!("chmod 700 {}", dir.display()))?;
    }
    Ok(())
}

/// Writes a file readable by its owner only (0600 on Unix), replacing it atomically.
fn write_private(path: &Path, text: &str) -> anyhow::Result<()> {
    write_with_mode(path, text, 0o600)
}

/// Writes a public file (0644 on Unix), replacing it atomically.
fn write_public(path: &Path, text: &str) -> anyhow::Result<()> {
    write_with_mode(path, text, 0o644)
}

fn write_with_mode(path: &Path, text: &str, mode: u32) -> anyhow::Result<()> {
    use std::io::Write;
    let tmp = path.with_extension("tmp");
    let _ = std::fs::remove_file(&tmp);
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // The mode is set when the file is created, so a key is never readable by others, not
        // even for an instant.
        o.mode(mode);
    }
    #[cfg(not(unix))]
    let _ = mode;
    let mut f = o
        .open(&tmp)
        .with_context(|| format!("create {}", tmp.display()))?;
    f.write_all(text.as_bytes())
        .and_then(|()| f.sync_all())
        .with_context(|| format!("write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("rename to {}", path.display()))
}

/// Reads the register (an empty one when the file does not exist yet).
pub fn read_register(fleet: &FleetDir) -> anyhow::Result<Register> {
    let p = fleet.register();
    match std::fs::read_to_string(&p) {
        Ok(t) => Register::parse(&t).map_err(|e| anyhow::anyhow!("{}: {e}", p.display())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Register::default()),
        Err(e) => Err(e).with_context(|| format!("read {}", p.display())),
    }
}

fn write_register(fleet: &FleetDir, r: &Register) -> anyhow::Result<()> {
    write_public(&fleet.register(), &r.to_text())
}

/// Checks that `dir` holds a fleet PKI (`pki init` ran there).
pub fn require_fleet(dir: &Path) -> anyhow::Result<FleetDir> {
    let fleet = FleetDir::new(dir);
    let s = fleet.station();
    for f in [&s.ca, &s.cert, &s.key] {
        if !f.is_file() {
            bail!(
                "{} is not a fleet PKI folder ({} is missing): create one with \
                 `operator-station pki init --dir {}`",
                dir.display(),
                f.display(),
                dir.display()
            );
        }
    }
    Ok(fleet)
}

/// `pki init`: a new fleet CA and the station's certificate (valid for the loopback names, this
/// machine's host name and `hosts`). Refuses to touch a folder that already has a CA.
pub fn init(dir: &Path, hosts: &[String]) -> anyhow::Result<InitReport> {
    let fleet = FleetDir::new(dir);
    if fleet.ca_key().exists() || fleet.ca_cert().exists() {
        bail!(
            "{} already holds a fleet CA: a second CA would lock out every robot issued by the \
             first. Use another --dir for a new fleet",
            dir.display()
        );
    }
    private_dir(dir)?;
    private_dir(&dir.join("ca"))?;
    private_dir(&dir.join("station"))?;
    let ca_key = KeyPair::generate().context("generate the CA key")?;
    let mut ca = CertificateParams::new(Vec::<String>::new()).context("CA parameters")?;
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationName, "terranav fleet");
    dn.push(DnType::CommonName, "terranav fleet CA");
    ca.distinguished_name = dn;
    // The CA signs station and robot certificates only, never another CA.
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ];
    validity(&mut ca, CA_DAYS);
    let ca_cert = ca.self_signed(&ca_key).context("self-sign the CA")?;
    write_private(&fleet.ca_key(), &ca_key.serialize_pem())?;
    write_public(&fleet.ca_cert(), &ca_cert.pem())?;

    let mut extra = hosts.to_vec();
    extra.extend(host_name());
    let station_names = names(&extra);
    let issuer = Issuer::new(ca, ca_key);
    let key = KeyPair::generate().context("generate the station key")?;
    let cert = leaf_params(security::STATION_CN, station_names.clone(), STATION_DAYS)?
        .signed_by(&key, &issuer)
        .context("sign the station certificate")?;
    let s = fleet.station();
    write_private(&s.key, &key.serialize_pem())?;
    write_public(&s.cert, &cert.pem())?;
    write_register(&fleet, &Register::default())?;
    Ok(InitReport {
        dir: dir.to_path_buf(),
        ca_cert: fleet.ca_cert(),
        station_cert: s.cert,
        station_names,
    })
}

fn load_issuer(fleet: &FleetDir) -> anyhow::Result<Issuer<'static, KeyPair>> {
    let key_pem = std::fs::read_to_string(fleet.ca_key())
        .with_context(|| format!("read {}", fleet.ca_key().display()))?;
    let cert_pem = std::fs::read_to_string(fleet.ca_cert())
        .with_context(|| format!("read {}", fleet.ca_cert().display()))?;
    let key = KeyPair::from_pem(&key_pem).context("the CA key")?;
    Issuer::from_ca_cert_pem(&cert_pem, key).context("the CA certificate")
}

/// A leaf certificate issued and written to its folder.
struct Leaf {
    serial: u32,
    cn: String,
    dir: PathBuf,
    not_after_unix_s: i64,
    superseded_serial: Option<u32>,
}

/// Issues the next certificate of `id` (valid `days`, for the loopback names and `hosts`), writes
/// it with its key and the CA certificate into the id's folder, and records it in the register;
/// the id's previous certificate is superseded.
fn issue_leaf(
    dir: &Path,
    kind: Kind,
    id: &str,
    hosts: &[String],
    days: i64,
) -> anyhow::Result<Leaf> {
    if !(1..=3650).contains(&days) {
        bail!("--days must be 1-3650");
    }
    let fleet = require_fleet(dir)?;
    let issuer = load_issuer(&fleet)?;
    let mut reg = read_register(&fleet)?;
    let superseded_serial = reg
        .newest(kind, id)
        .filter(|i| i.revoked_unix_s.is_none())
        .map(|i| i.serial);
    let serial = reg.next_serial(kind, id);
    let (cn, ldir, files) = leaf_names(&fleet, kind, id, serial)?;
    let params = leaf_params(&cn, names(hosts), days)?;
    let not_after_unix_s = params.not_after.unix_timestamp();
    let noun = kind.noun();
    let key = KeyPair::generate().with_context(|| format!("generate the {noun} key"))?;
    let cert = params
        .signed_by(&key, &issuer)
        .with_context(|| format!("sign the {noun} certificate"))?;
    private_dir(ldir.parent().unwrap_or(dir))?;
    private_dir(&ldir)?;
    let ca_pem = std::fs::read_to_string(fleet.ca_cert())?;
    write_private(&files.key, &key.serialize_pem())?;
    write_public(&files.cert, &cert.pem())?;
    write_public(&files.ca, &ca_pem)?;
    reg.push(
        kind,
        Issued {
            id: id.to_string(),
            serial,
            cn: cn.clone(),
            issued_unix_s: now().unix_timestamp(),
            not_after_unix_s,
            revoked_unix_s: None,
        },
    );
    write_register(&fleet, &reg)?;
    Ok(Leaf {
        serial,
        cn,
        dir: ldir,
        not_after_unix_s,
        superseded_serial,
    })
}

/// The common name, folder and file names of `id`'s certificate number `serial`.
fn leaf_names(
    fleet: &FleetDir,
    kind: Kind,
    id: &str,
    serial: u32,
) -> anyhow::Result<(String, PathBuf, security::CertFiles)> {
    Ok(match kind {
        Kind::Robot => {
            let robot = RobotId::new(id).map_err(|e| anyhow::anyhow!("{e}"))?;
            let d = fleet.robot_dir(&robot);
            let files = security::CertFiles::robot(&d);
            (security::robot_cn(&robot, serial), d, files)
        }
        Kind::Monitor => {
            security::check_monitor_name(id).map_err(|e| anyhow::anyhow!(e))?;
            let d = fleet.monitor_dir(id);
            let files = security::CertFiles::monitor(&d);
            (security::monitor_cn(id, serial), d, files)
        }
    })
}

/// Marks every certificate of `id` revoked (running stations and routers re-read the register and
/// refuse it) and deletes the station's copy of its folder. Returns how many certificates were
/// valid and whether the folder was deleted.
fn revoke_leaf(dir: &Path, kind: Kind, id: &str) -> anyhow::Result<(usize, bool)> {
    let fleet = require_fleet(dir)?;
    let mut reg = read_register(&fleet)?;
    if reg.newest(kind, id).is_none() {
        bail!(
            "no certificate was ever issued to {} {id} in {}",
            kind.noun(),
            dir.display()
        );
    }
    let revoked = reg.revoke(kind, id, now().unix_timestamp());
    write_register(&fleet, &reg)?;
    let (_, ldir, _) = leaf_names(&fleet, kind, id, 0)?;
    let deleted = ldir.is_dir();
    if deleted {
        std::fs::remove_dir_all(&ldir).with_context(|| format!("delete {}", ldir.display()))?;
    }
    Ok((revoked, deleted))
}

/// `pki issue`: a new certificate for `robot` (valid `days`, for the loopback names and `hosts`,
/// so a station may link to the robot's own listener), in `robots/<id>/` with the CA certificate.
/// A previous certificate of the robot is superseded: the station admits the new one only.
pub fn issue(
    dir: &Path,
    robot: &RobotId,
    hosts: &[String],
    days: i64,
) -> anyhow::Result<IssueReport> {
    let leaf = issue_leaf(dir, Kind::Robot, robot.as_str(), hosts, days)?;
    Ok(IssueReport {
        robot: robot.to_string(),
        serial: leaf.serial,
        cn: leaf.cn,
        robot_dir: leaf.dir,
        not_after_unix_s: leaf.not_after_unix_s,
        superseded_serial: leaf.superseded_serial,
    })
}

/// What `pki add-monitor` made.
#[derive(Debug, Serialize)]
pub struct MonitorReport {
    /// Monitor name.
    pub monitor: String,
    /// Issue number.
    pub serial: u32,
    /// Common name.
    pub cn: String,
    /// The folder to copy to the monitor's machine.
    pub monitor_dir: PathBuf,
    /// End of validity, Unix seconds.
    pub not_after_unix_s: i64,
    /// The monitor's previous certificate, now superseded (refused everywhere), if any.
    pub superseded_serial: Option<u32>,
}

/// `pki add-monitor`: a certificate for a read-only station `name` (valid `days`), in
/// `monitors/<name>/` with the CA certificate. Stations and routers that read the register admit
/// it to watch, never to command; robots admit it to nothing. Issuing again supersedes the
/// previous certificate.
pub fn add_monitor(dir: &Path, name: &str, days: i64) -> anyhow::Result<MonitorReport> {
    // A monitor only connects (it is a Zenoh client of a station or router): loopback names are
    // enough for its certificate.
    let leaf = issue_leaf(dir, Kind::Monitor, name, &[], days)?;
    Ok(MonitorReport {
        monitor: name.to_string(),
        serial: leaf.serial,
        cn: leaf.cn,
        monitor_dir: leaf.dir,
        not_after_unix_s: leaf.not_after_unix_s,
        superseded_serial: leaf.superseded_serial,
    })
}

/// What `pki revoke-monitor` did.
#[derive(Debug, Serialize)]
pub struct RevokeMonitorReport {
    /// Monitor name.
    pub monitor: String,
    /// Certificates newly marked revoked.
    pub revoked: usize,
    /// Whether the station's copy of the monitor's files was deleted.
    pub deleted_monitor_dir: bool,
}

/// `pki revoke-monitor`: marks every certificate of monitor `name` revoked (running stations and
/// routers re-read the register and refuse it) and deletes the station's copy of its files.
pub fn revoke_monitor(dir: &Path, name: &str) -> anyhow::Result<RevokeMonitorReport> {
    security::check_monitor_name(name).map_err(|e| anyhow::anyhow!(e))?;
    let (revoked, deleted_monitor_dir) = revoke_leaf(dir, Kind::Monitor, name)?;
    Ok(RevokeMonitorReport {
        monitor: name.to_string(),
        revoked,
        deleted_monitor_dir,
    })
}

/// `pki revoke`: marks every certificate of `robot` revoked in the register (a running station
/// re-reads it and drops the robot) and deletes the station's copy of the robot's files.
pub fn revoke(dir: &Path, robot: &RobotId) -> anyhow::Result<RevokeReport> {
    let (revoked, deleted_robot_dir) = revoke_leaf(dir, Kind::Robot, robot.as_str())?;
    Ok(RevokeReport {
        robot: robot.to_string(),
        revoked,
        deleted_robot_dir,
    })
}

/// Issues certificates for the robots in `robots` that have no valid one yet (what `demo --pki`
/// needs), creating the fleet first when `dir` has none.
pub fn ensure_demo_fleet(dir: &Path, robots: &[RobotId]) -> anyhow::Result<()> {
    if !FleetDir::new(dir).ca_cert().exists() {
        init(dir, &[])?;
    }
    let fleet = require_fleet(dir)?;
    let now_s = now().unix_timestamp();
    let admitted = read_register(&fleet)?.admitted(now_s);
    for r in robots {
        let ok = admitted.iter().any(|a| &a.robot == r)
            && security::CertFiles::robot(&fleet.robot_dir(r))
                .all()
                .iter()
                .all(|f| f.is_file());
        if !ok {
            issue(dir, r, &[], ROBOT_DAYS)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mode(p: &Path) -> u32 {
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::metadata(p).unwrap().permissions().mode() & 0o777
        }
        #[cfg(not(unix))]
        {
            let _ = p;
            0o600
        }
    }

    #[test]
    fn init_issue_revoke_write_what_they_say() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("pki");
        let rep = init(&dir, &["station.example".into()]).unwrap();
        assert!(rep.station_names.iter().any(|n| n == "station.example"));
        assert!(rep.station_names.iter().any(|n| n == "127.0.0.1"));
        let fleet = FleetDir::new(&dir);
        assert_eq!(mode(&fleet.ca_key()), 0o600);
        assert_eq!(mode(&fleet.station().key), 0o600);
        assert_eq!(mode(&dir.join("ca")), 0o700);
        assert!(init(&dir, &[]).is_err(), "never a second CA in one folder");

        let r1 = RobotId::new("r1").unwrap();
        let a = issue(&dir, &r1, &[], 30).unwrap();
        assert_eq!((a.serial, a.superseded_serial), (1, None));
        let files = security::CertFiles::robot(&a.robot_dir);
        assert_eq!(mode(&files.key), 0o600);
        assert_eq!(mode(&a.robot_dir), 0o700);
        assert_eq!(
            std::fs::read(&files.ca).unwrap(),
            std::fs::read(fleet.ca_cert()).unwrap()
        );
        let b = issue(&dir, &r1, &[], 30).unwrap();
        assert_eq!((b.serial, b.superseded_serial), (2, Some(1)));
        assert_eq!(b.cn, "terranav:robot:r1:2");
        let now_s = now().unix_timestamp();
        let reg = read_register(&fleet).unwrap();
        assert_eq!(reg.admitted(now_s).len(), 1);
        assert_eq!(reg.admitted(now_s)[0].cn, b.cn);

        let rev = revoke(&dir, &r1).unwrap();
        assert_eq!(rev.revoked, 2);
        assert!(rev.deleted_robot_dir && !a.robot_dir.exists());
        assert!(read_register(&fleet).unwrap().admitted(now_s).is_empty());
        assert!(revoke(&dir, &RobotId::new("nobody").unwrap()).is_err());
        // No key ever lands in the register.
        let text = std::fs::read_to_string(fleet.register()).unwrap();
        assert!(!text.contains("PRIVATE KEY"));
    }

    #[test]
    fn add_and_revoke_a_monitor() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("pki");
        init(&dir, &[]).unwrap();
        let fleet = FleetDir::new(&dir);
        assert!(add_monitor(&dir, "Bad Name", 30).is_err());
        let a = add_monitor(&dir, "ops", 30).unwrap();
        assert_eq!(
            (a.serial, a.cn.as_str(), a.superseded_serial),
            (1, "terranav:monitor:ops:1", None)
        );
        let files = security::CertFiles::monitor(&a.monitor_dir);
        assert_eq!(mode(&files.key), 0o600);
        assert_eq!(mode(&a.monitor_dir), 0o700);
        assert!(files.all().iter().all(|f| f.is_file()));
        let b = add_monitor(&dir, "ops", 30).unwrap();
        assert_eq!((b.serial, b.superseded_serial), (2, Some(1)));
        let now_s = now().unix_timestamp();
        let reg = read_register(&fleet).unwrap();
        assert_eq!(reg.admitted_monitors(now_s).len(), 1);
        assert_eq!(reg.admitted_monitors(now_s)[0].cn, b.cn);
        assert!(reg.admitted(now_s).is_empty(), "a monitor is no robot");
        let rev = revoke_monitor(&dir, "ops").unwrap();
        assert_eq!(rev.revoked, 2);
        assert!(rev.deleted_monitor_dir && !b.monitor_dir.exists());
        assert!(read_register(&fleet)
            .unwrap()
            .admitted_monitors(now_s)
            .is_empty());
        assert!(revoke_monitor(&dir, "nobody").is_err());
    }
}
