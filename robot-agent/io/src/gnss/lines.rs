//! Text lines from a serial port, a TCP stream or UDP datagrams: how NMEA reaches a robot.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader};
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, BufReader as AsyncBufReader};
use tokio::net::{TcpStream, UdpSocket};
use tokio::sync::mpsc;

/// Longest line accepted; NMEA allows 82 characters, proprietary sentences run longer, and
/// anything past this is not NMEA (it is cut and then refused by the parser).
const MAX_LINE: usize = 1024;

/// A stream of lines.
pub enum LineSource {
    /// A TCP stream (an NTRIP caster's or a receiver's NMEA port).
    Tcp(AsyncBufReader<TcpStream>),
    /// UDP datagrams, each holding one or more lines.
    Udp {
        /// The bound socket.
        socket: UdpSocket,
        /// Lines of the last datagram not yet returned.
        pending: VecDeque<String>,
    },
    /// A serial port read on its own thread (serial I/O is blocking).
    Serial(mpsc::Receiver<std::io::Result<String>>),
}

impl LineSource {
    /// Connects to `host:port`.
    pub async fn tcp(host: &str, port: u16) -> std::io::Result<Self> {
        Ok(LineSource::Tcp(AsyncBufReader::new(
            TcpStream::connect((host, port)).await?,
        )))
    }

    /// Listens on UDP `port` (all interfaces; port 0 picks one, see [`LineSource::local_port`]).
    pub async fn udp(port: u16) -> std::io::Result<Self> {
        let socket = UdpSocket::bind(("0.0.0.0", port)).await?;
        Ok(LineSource::Udp {
            socket,
            pending: VecDeque::new(),
        })
    }

    /// Opens `device` at `baud` (8N1, no flow control).
    pub fn serial(device: &str, baud: u32) -> std::io::Result<Self> {
        let port = serialport::new(device, baud)
            .timeout(Duration::from_millis(500))
            .open()
            .map_err(|e| std::io::Error::other(format!("{device}@{baud}: {e}")))?;
        let (tx, rx) = mpsc::channel(256);
        std::thread::Builder::new()
            .name(format!("nmea-serial {device}"))
            .spawn(move || {
                let mut reader = BufReader::new(port);
                let mut buf = Vec::new();
                loop {
                    match reader.read_until(b'\n', &mut buf) {
                        Ok(0) => return,
                        Ok(_) => {
                            buf.truncate(MAX_LINE);
                            let line = String::from_utf8_lossy(&buf).trim_end().to_owned();
                            buf.clear();
                            if tx.blocking_send(Ok(line)).is_err() {
                                return;
                            }
                        }
                        // A quiet port times out; keep waiting (a partial line stays in `buf`
                        // and is completed by the next read).
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                            if tx.is_closed() {
                                return;
                            }
                        }
                        Err(e) => {
                            let _ = tx.blocking_send(Err(e));
                            return;
                        }
                    }
                }
            })?;
        Ok(LineSource::Serial(rx))
    }

    /// The bound UDP port (for a UDP source opened on port 0).
    pub fn local_port(&self) -> Option<u16> {
        match self {
            LineSource::Udp { socket, .. } => socket.local_addr().ok().map(|a| a.port()),
            _ => None,
        }
    }

    /// The next line without its line ending; `None` when the stream ended.
    pub async fn next_line(&mut self) -> std::io::Result<Option<String>> {
        match self {
            LineSource::Tcp(r) => {
                let mut buf = Vec::new();
                if r.read_until(b'\n', &mut buf).await? == 0 {
                    return Ok(None);
                }
                buf.truncate(MAX_LINE);
                Ok(Some(String::from_utf8_lossy(&buf).trim_end().to_owned()))
            }
            LineSource::Udp { socket, pending } => loop {
                if let Some(l) = pending.pop_front() {
                    return Ok(Some(l));
                }
                let mut buf = vec![0u8; 65536];
                let n = socket.recv(&mut buf).await?;
                let text = String::from_utf8_lossy(&buf[..n]);
                pending.extend(
                    text.lines()
                        .map(|l| l.trim().chars().take(MAX_LINE).collect::<String>())
                        .filter(|l| !l.is_empty()),
                );
            },
            LineSource::Serial(rx) => rx.recv().await.transpose(),
        }
    }
}
