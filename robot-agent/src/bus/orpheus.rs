//! The Orpheus navigation-computer gateway on a UDP socket (methods.md §7): sentences in, route
//! edits out. The protocol logic is [`crate::navcomp::OrpheusGateway`]; this is only
//! the socket.

use crate::navcomp::{GatewayError, GatewayEvent, OrpheusGateway};
use std::net::{SocketAddr, UdpSocket};

/// The gateway's UDP endpoint.
#[derive(Debug)]
pub struct OrpheusUdp {
    socket: UdpSocket,
    peer: Option<SocketAddr>,
    /// The protocol state.
    pub gateway: OrpheusGateway,
    buf: Vec<u8>,
}

impl OrpheusUdp {
    /// Binds `bind` (e.g. `127.0.0.1:10110`); the navigation computer is `peer`, or the sender
    /// of the first datagram when None.
    pub fn bind(bind: SocketAddr, peer: Option<SocketAddr>) -> std::io::Result<Self> {
        let socket = UdpSocket::bind(bind)?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            peer,
            gateway: OrpheusGateway::new(),
            buf: vec![0; 64 * 1024],
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Reads every datagram waiting (one or more CR LF separated sentences each) and returns
    /// what each line did; rejected lines are logged with their reason and counted.
    pub fn poll(&mut self) -> Vec<Result<GatewayEvent, GatewayError>> {
        let mut out = Vec::new();
        loop {
            match self.socket.recv_from(&mut self.buf) {
                Ok((n, from)) => {
                    if self.peer.is_none() {
                        self.peer = Some(from);
                    }
                    let text = String::from_utf8_lossy(&self.buf[..n]).into_owned();
                    for line in text.split(['\r', '\n']).filter(|l| !l.trim().is_empty()) {
                        let r = self.gateway.on_line(line);
                        if let Err(e) = &r {
                            tracing::warn!(%from, line, "orpheus: rejected: {e}");
                        }
                        out.push(r);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                // The ICMP answer to a datagram sent before the NC listened: it is not up yet.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => break,
                Err(e) => {
                    tracing::warn!("orpheus: receive failed: {e}");
                    break;
                }
            }
        }
        out
    }

    /// Sends sentences to the navigation computer, one datagram each.
    pub fn send(&self, lines: &[String]) -> std::io::Result<()> {
        let peer = self.peer.ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::NotConnected,
                "navigation computer not heard from yet",
            )
        })?;
        for l in lines {
            self.socket.send_to(l.as_bytes(), peer)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::navcomp::ReferenceNavComputer;
    use common::geo::orpheus::RoutePoint;
    use std::time::{Duration, Instant};

    fn poll_until(gw: &mut OrpheusUdp, want: usize) -> Vec<Result<GatewayEvent, GatewayError>> {
        let mut got = Vec::new();
        let t0 = Instant::now();
        while got.len() < want && t0.elapsed() < Duration::from_secs(5) {
            got.extend(gw.poll());
            std::thread::sleep(Duration::from_millis(2));
        }
        got
    }

    /// A simulated navigation computer on its own real UDP socket on loopback.
    #[test]
    fn drives_a_navigation_computer_over_udp() {
        let mut gw = OrpheusUdp::bind("127.0.0.1:0".parse().unwrap(), None).unwrap();
        let nc_sock = UdpSocket::bind("127.0.0.1:0").unwrap();
        nc_sock
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let gw_addr = gw.local_addr().unwrap();
        let mut nc = ReferenceNavComputer {
            route: (0..8)
                .map(|i| RoutePoint {
                    id: i,
                    lat_deg: 50.0 + f64::from(i) * 1e-5,
                    lon_deg: -14.4,
                    lat_err_m: 0.02,
                    lon_err_m: 0.03,
                })
                .collect(),
            speed_pct: 100,
        };
        // The list, a bad checksum, an unknown id, and a reached waypoint; two sentences in one datagram too.
        let mut lines = nc.announce();
        lines.push("$NAWPT,2*00\r\n".into());
        lines.push(common::geo::nmea::frame("NAWPT,99"));
        for l in &lines {
            nc_sock.send_to(l.as_bytes(), gw_addr).unwrap();
        }
        let two = format!(
            "{}{}",
            common::geo::nmea::frame("NAWPT,1"),
            common::geo::nmea::frame("NAWPT,2")
        );
        nc_sock.send_to(two.as_bytes(), gw_addr).unwrap();
        let events = poll_until(&mut gw, lines.len() + 2);
        assert_eq!(events.len(), lines.len() + 2);
        assert!(events.contains(&Ok(GatewayEvent::RouteComplete(8))));
        assert!(
            matches!(events[9], Err(GatewayError::Malformed(_))),
            "bad checksum: {:?}",
            events[9]
        );
        assert!(matches!(events[10], Err(GatewayError::UnknownId(99, 8))));
        assert_eq!(gw.gateway.reached(), Some(2));
        assert_eq!(gw.gateway.rejected, 2);

        // A detour replacing waypoints 3..5 by four points; the NC applies what arrives.
        let detour: Vec<(f64, f64)> = (0..4)
            .map(|k| (50.00003 + f64::from(k) * 5e-6, -14.39998))
            .collect();
        let edits = gw.gateway.splice(3, 5, &detour, 0.05).unwrap();
        gw.send(&edits).unwrap();
        gw.send(&[OrpheusGateway::speed_limit(40)]).unwrap();
        let mut buf = [0u8; 512];
        for _ in 0..edits.len() + 1 {
            let (n, _) = nc_sock.recv_from(&mut buf).unwrap();
            nc.apply(std::str::from_utf8(&buf[..n]).unwrap()).unwrap();
        }
        assert_eq!(nc.route.len(), 10);
        assert_eq!(nc.speed_pct, 40);
        for (a, b) in nc.route.iter().zip(gw.gateway.route()) {
            assert_eq!(a.id, b.id);
            assert!((a.lat_deg - b.lat_deg).abs() < 1e-8);
        }
        assert!((nc.route[3].lat_deg - 50.00003).abs() < 1e-8);
        assert!(
            (nc.route[7].lat_deg - 50.00005).abs() < 1e-8,
            "old waypoint 5 follows the detour"
        );
    }
}
