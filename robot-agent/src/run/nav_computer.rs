//! The base of a robot whose own navigation computer follows waypoint lists (`robot-agent run
//! --nav-computer orpheus-udp:HOST:PORT`, methods.md §7): instead of velocities it gets the
//! mission's route as a `$NALST` list, the route's changes (detours) as `$CAREM`/`$CAINS` edits
//! and the speed as `$CASPD`, over the Orpheus UDP gateway; the NC's `$NAWPT` reports are
//! counted. While no mission with a route runs (teleop, teaching, idle) the NC is held at speed
//! 0 and the velocity commands go to the manual base (`cmd_vel`) when the robot has one.

use super::robot::Base;
use crate::bus::orpheus::OrpheusUdp;
use crate::navcomp::sync::RouteSync;
use crate::navcomp::GatewayEvent;
use crate::runtime::route::RouteOrder;
use agent::Cmd;
use std::net::{SocketAddr, ToSocketAddrs};

/// See the module docs.
pub struct NavComputerBase {
    udp: OrpheusUdp,
    peer: SocketAddr,
    sync: RouteSync,
    manual: Box<dyn Base>,
    following: bool,
    last_t_s: f64,
    reached: u64,
    last_reached: Option<u32>,
    hold: Option<&'static str>,
}

impl NavComputerBase {
    /// Talks to the navigation computer at `host:port` from an ephemeral local UDP port (the NC
    /// answers to the sender); `manual` takes the velocity commands of teleop.
    pub fn connect(host: &str, port: u16, manual: Box<dyn Base>) -> anyhow::Result<Self> {
        let peer = (host, port)
            .to_socket_addrs()
            .map_err(|e| anyhow::anyhow!("navigation computer {host}:{port}: {e}"))?
            .next()
            .ok_or_else(|| anyhow::anyhow!("navigation computer {host}:{port}: no address"))?;
        let bind: SocketAddr = if peer.is_ipv4() {
            ([0, 0, 0, 0], 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let udp = OrpheusUdp::bind(bind, Some(peer))
            .map_err(|e| anyhow::anyhow!("binding the navigation computer's socket: {e}"))?;
        tracing::info!(
            "base -> navigation computer {peer} (Orpheus UDP from {})",
            udp.local_addr()
                .map_or_else(|_| "?".into(), |a| a.to_string())
        );
        Ok(Self {
            udp,
            peer,
            sync: RouteSync::new(),
            manual,
            following: false,
            last_t_s: 0.0,
            reached: 0,
            last_reached: None,
            hold: None,
        })
    }

    fn send(&mut self, lines: &[String]) -> anyhow::Result<()> {
        if lines.is_empty() {
            return Ok(());
        }
        self.udp
            .send(lines)
            .map_err(|e| anyhow::anyhow!("navigation computer {}: {e}", self.peer))
    }
}

impl Base for NavComputerBase {
    fn drive(&mut self, cmd: Cmd) -> anyhow::Result<()> {
        if self.following {
            return Ok(());
        }
        self.manual.drive(cmd)
    }

    fn follows_routes(&self) -> bool {
        true
    }

    fn follow(&mut self, t_s: f64, route: Option<&RouteOrder>) -> anyhow::Result<()> {
        for ev in self.udp.poll() {
            match ev {
                Ok(GatewayEvent::Reached(id)) => {
                    self.reached += 1;
                    self.last_reached = Some(id);
                    tracing::debug!("navigation computer reached waypoint {id}");
                }
                // A list the NC announces itself is its route; the sync edits it into ours.
                Ok(GatewayEvent::RouteComplete(n)) => {
                    tracing::info!("navigation computer announced a list of {n} waypoints")
                }
                Ok(GatewayEvent::PointReceived(_)) => {}
                // Counted (and logged) by the gateway.
                Err(_) => {}
            }
        }
        let before = self.sync.mission().map(str::to_owned);
        let lines = self.sync.update(&mut self.udp.gateway, route, t_s);
        if let Some(o) = route {
            if before.as_deref() != Some(o.mission.as_str()) {
                tracing::info!(
                    "navigation computer: {} sent as a list of {} waypoints",
                    o.mission,
                    self.udp.gateway.route().len()
                );
            }
            if o.hold != self.hold {
                match o.hold {
                    Some(why) => tracing::info!("navigation computer held: {why}"),
                    None => tracing::info!("navigation computer released"),
                }
                self.hold = o.hold;
            }
        }
        self.following = route.is_some();
        self.last_t_s = t_s;
        self.send(&lines)
    }

    fn stop(&mut self) -> anyhow::Result<()> {
        let hold = self
            .sync
            .update(&mut self.udp.gateway, None, self.last_t_s + 1e3);
        let nc = self.send(&hold);
        let manual = self.manual.stop();
        nc.and(manual)
    }

    fn report(&self) -> serde_json::Value {
        serde_json::json!({
            "nav_computer": self.peer.to_string(),
            "sent": self.sync.counts,
            "waypoints_reached": self.reached,
            "last_reached": self.last_reached,
            "lines_refused": self.udp.gateway.rejected,
            "manual": self.manual.report(),
        })
    }
}
