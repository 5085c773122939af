//! `operator-station pki init | issue | revoke | add-monitor | revoke-monitor`: the fleet's certificates ([`crate::pki`]).

use std::path::PathBuf;

use clap::Subcommand;
use common::keys::RobotId;

use crate::pki;

/// `pki` options.
#[derive(Debug, Clone, clap::Args)]
pub struct PkiArgs {
    /// What to do.
    #[command(subcommand)]
    pub what: PkiCmd,
}

/// `pki` subcommands.
#[derive(Debug, Clone, Subcommand)]
pub enum PkiCmd {
    /// Create the fleet CA and the station's certificate in DIR (once per fleet).
    Init {
        /// The PKI folder (created 0700).
        #[arg(long)]
        dir: PathBuf,
        /// Another name or address the station is reached by (robots, browsers); repeatable.
        /// Loopback and this machine's host name are always in.
        #[arg(long = "host")]
        hosts: Vec<String>,
    },
    /// Issue a robot's key and certificate into DIR/robots/ID/ (copy that folder to the robot).
    /// Issuing again supersedes the robot's previous certificate.
    Issue {
        /// Robot id.
        #[arg(long)]
        robot: String,
        /// The PKI folder.
        #[arg(long)]
        dir: PathBuf,
        /// Another name or address the robot's own listener is reached by; repeatable.
        #[arg(long = "host")]
        hosts: Vec<String>,
        /// Validity, days.
        #[arg(long, default_value_t = pki::ROBOT_DAYS)]
        days: i64,
    },
    /// Issue a monitor's key and certificate into DIR/monitors/NAME/ (a read-only station: it may
    /// watch the fleet through a station or router, never command; copy that folder to its
    /// machine and run `serve --pki <folder> --monitor NAME --connect quic/STATION:7447`).
    AddMonitor {
        /// Monitor name (a-z, 0-9, -).
        #[arg(long)]
        name: String,
        /// The PKI folder.
        #[arg(long)]
        dir: PathBuf,
        /// Validity, days.
        #[arg(long, default_value_t = pki::ROBOT_DAYS)]
        days: i64,
    },
    /// Revoke every certificate of a monitor: running stations and routers refuse it at once.
    RevokeMonitor {
        /// Monitor name.
        #[arg(long)]
        name: String,
        /// The PKI folder.
        #[arg(long)]
        dir: PathBuf,
    },
    /// Revoke every certificate of a robot (a stolen or retired robot): a running station drops
    /// it at once and refuses it from then on.
    Revoke {
        /// Robot id.
        #[arg(long)]
        robot: String,
        /// The PKI folder.
        #[arg(long)]
        dir: PathBuf,
    },
}

/// Runs a `pki` subcommand; prints one JSON line.
pub fn run(a: PkiArgs) -> anyhow::Result<()> {
    let out = match a.what {
        PkiCmd::Init { dir, hosts } => serde_json::to_value(pki::init(&dir, &hosts)?)?,
        PkiCmd::Issue {
            robot,
            dir,
            hosts,
            days,
        } => {
            let id = RobotId::new(robot)?;
            let r = pki::issue(&dir, &id, &hosts, days)?;
            eprintln!(
                "copy {} to the robot and run it with --pki <that folder>; keep no other copy",
                r.robot_dir.display()
            );
            serde_json::to_value(r)?
        }
        PkiCmd::AddMonitor { name, dir, days } => {
            let r = pki::add_monitor(&dir, &name, days)?;
            eprintln!(
                "copy {} to the monitor's machine and run `operator-station serve --pki <that \
                 folder> --monitor {name} --connect {}/STATION:7447`; keep no other copy",
                r.monitor_dir.display(),
                common::security::SECURE_SCHEME
            );
            serde_json::to_value(r)?
        }
        PkiCmd::RevokeMonitor { name, dir } => {
            serde_json::to_value(pki::revoke_monitor(&dir, &name)?)?
        }
        PkiCmd::Revoke { robot, dir } => {
            let id = RobotId::new(robot)?;
            serde_json::to_value(pki::revoke(&dir, &id)?)?
        }
    };
    println!("{out}");
    Ok(())
}
