//! Live VLP-16 packets from a UDP socket.

use super::{DecodeStats, LidarScan, ScanAssembler, VelodyneConfig};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A bound socket that turns received packets into scans.
#[derive(Debug)]
pub struct UdpScanSource {
    socket: UdpSocket,
    assembler: ScanAssembler,
    buf: Vec<u8>,
    ready: std::collections::VecDeque<LidarScan>,
    /// Datagrams received (also the malformed ones).
    pub datagrams: u64,
}

impl UdpScanSource {
    /// Binds `addr` (e.g. `0.0.0.0:2368`; port 0 picks a free one).
    pub fn bind(addr: SocketAddr, config: VelodyneConfig) -> std::io::Result<Self> {
        let socket = UdpSocket::bind(addr)?;
        Ok(Self {
            socket,
            assembler: ScanAssembler::new(config),
            // Larger than any packet so oversized datagrams are seen (and counted) as such.
            buf: vec![0u8; 65_536],
            ready: Default::default(),
            datagrams: 0,
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Packet counts so far.
    pub fn stats(&self) -> &DecodeStats {
        self.assembler.stats()
    }

    /// Waits up to `timeout` for the next complete scan; `Ok(None)` when none completed in time.
    /// Packets are stamped with the host clock when received.
    pub fn next_scan(&mut self, timeout: Duration) -> std::io::Result<Option<LidarScan>> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(s) = self.ready.pop_front() {
                return Ok(Some(s));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            // A zero read timeout means "block forever" to the OS: keep it at least 1 ms.
            self.socket
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))?;
            match self.socket.recv_from(&mut self.buf) {
                Ok((n, _from)) => {
                    self.datagrams += 1;
                    let now_s = SystemTime::now()
                        .duration_since(UNIX_EPOCH)
                        .map(|d| d.as_secs_f64())
                        .unwrap_or(0.0);
                    let scans = self.assembler.push_packet(&self.buf[..n], now_s);
                    self.ready.extend(scans);
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None)
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Closes the scan under construction (e.g. when the sender stopped), if it has returns.
    pub fn flush(&mut self) -> Option<LidarScan> {
        self.ready.pop_front().or_else(|| self.assembler.finish())
    }
}
