//! Fleets across networks: `router` (a Zenoh router the fleet can use without zenohd) and
//! `robot-tiles` (what a robot serves from its tile queryable, to check a station against it).
//!
//! The router is a Zenoh session in router mode and nothing else: robots and stations on other
//! networks connect to it (robots as clients, stations as peers), routers of two sites connect to
//! each other. With `--pki` it holds the station's certificate (a robot's access rules admit
//! only that identity) and enforces the station's access rules on its own links, so a robot
//! behind it still publishes only under its own prefix; it re-reads the fleet register every
//! second and re-opens its session when a robot is issued or revoked.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use common::grid::decode_tile;
use common::keys::{self, RobotId};
use zenoh::query::ConsolidationMode;

use super::{until_stopped, zenoh_config, Role, ZenohArgs};
use crate::security::RegisterWatch;

/// `router` options.
#[derive(Debug, Clone, clap::Args)]
pub struct RouterArgs {
    /// Zenoh options: `--zenoh-listen` where robots and stations reach it (default loopback),
    /// `--connect` another site's router, `--pki` the fleet's certificates (station identity).
    #[command(flatten)]
    pub z: ZenohArgs,
}

/// `robot-tiles` options.
#[derive(Debug, Clone, clap::Args)]
pub struct RobotTilesArgs {
    /// Zenoh options (connects to the station's endpoint or a router by default).
    #[command(flatten)]
    pub z: ZenohArgs,
    /// Robot id.
    #[arg(long)]
    pub robot: String,
    /// Folder to write each tile into, encoded as on the wire (`TX_TY.tile`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// How long to wait for the robot's replies, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub timeout_s: f64,
}

/// The router's Zenoh config: the station's (TLS and access rules with `--pki`, plain endpoints
/// off loopback refused) in router mode.
fn router_config(z: &ZenohArgs) -> anyhow::Result<zenoh::Config> {
    let mut c = zenoh_config(z, Role::Station)?;
    c.insert_json5("mode", "\"router\"")
        .map_err(|e| anyhow::anyhow!("zenoh config mode: {e}"))?;
    Ok(c)
}

async fn open(z: &ZenohArgs) -> anyhow::Result<zenoh::Session> {
    let c = router_config(z)?;
    zenoh::open(c)
        .await
        .map_err(|e| anyhow::anyhow!("zenoh router: {e}"))
}

/// Runs a Zenoh router until Ctrl-C (or SIGTERM / SIGHUP).
pub async fn router(a: RouterArgs) -> anyhow::Result<()> {
    let mut session = open(&a.z).await?;
    println!(
        "{}",
        serde_json::json!({"router": session.zid().to_string(), "listen": a.z.zenoh_listen,
                           "connect": a.z.connect, "secure": a.z.pki.is_some()})
    );
    let mut watch = a.z.pki.as_deref().map(RegisterWatch::new);
    let reopen = async || {
        let _ = session.close().await;
        session = open(&a.z).await?;
        Ok(())
    };
    until_stopped(
        Duration::from_secs(1),
        "the router",
        &mut watch,
        || false,
        reopen,
    )
    .await;
    let _ = session.close().await;
    Ok(())
}

/// Asks a robot for every tile it serves and writes them to `--out`; prints one JSON line with
/// the tiles and their versions.
pub async fn robot_tiles(a: RobotTilesArgs) -> anyhow::Result<()> {
    let rid = RobotId::new(a.robot.clone())?;
    let s = super::client_session(&a.z).await?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("create {}", a.out.display()))?;
    let mut tiles = Vec::new();
    // The link may take a moment (TLS across a slow link): retry an empty answer until the
    // timeout, as a robot with a session always serves at least one tile once it has mapped.
    let t0 = std::time::Instant::now();
    let limit = Duration::from_secs_f64(a.timeout_s.max(0.5));
    while tiles.is_empty() && t0.elapsed() < limit {
        let replies = s
            .get(keys::robot_tiles(&rid))
            .consolidation(ConsolidationMode::None)
            .timeout(
                limit
                    .saturating_sub(t0.elapsed())
                    .max(Duration::from_millis(500)),
            )
            .await
            .map_err(|e| anyhow::anyhow!("tile query: {e}"))?;
        while let Ok(r) = replies.recv_async().await {
            let Ok(sample) = r.result() else { continue };
            let bytes = sample.payload().to_bytes();
            match decode_tile(&bytes) {
                Ok(t) => {
                    let (tx, ty) = (t.index.tx, t.index.ty);
                    std::fs::write(a.out.join(format!("{tx}_{ty}.tile")), &bytes)?;
                    tiles.push(serde_json::json!({"tx": tx, "ty": ty, "version": t.version}));
                }
                Err(e) => tracing::warn!("undecodable tile from {rid}: {e}"),
            }
        }
        if tiles.is_empty() {
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
    }
    let _ = s.close().await;
    println!(
        "{}",
        serde_json::json!({"robot": rid.as_str(), "tiles": tiles})
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(zenoh: Option<&str>, listen: Option<&str>) -> ZenohArgs {
        ZenohArgs {
            zenoh: zenoh.map(|f| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(f)),
            zenoh_listen: listen.map(String::from),
            connect: None,
            pki: None,
        }
    }

    #[test]
    fn the_router_is_a_router_and_refuses_plain_links_off_loopback() {
        let c = router_config(&args(None, None)).unwrap();
        assert_eq!(c.get_json("mode").unwrap(), "\"router\"");
        // The shipped site router listens on every interface: TLS, so only with --pki.
        let e = router_config(&args(Some("../config/zenoh/router.json5"), None)).unwrap_err();
        assert!(e.to_string().contains("pki"), "{e}");
        assert!(router_config(&args(None, Some("tcp/0.0.0.0:7447"))).is_err());
    }
}
