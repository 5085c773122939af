//! Recorded packet files, pcap or ROS 2 bag, behind one iterator of packets.

use super::pcap::{PcapError, PcapReader, PcapStats};
use super::rosbag::{BagError, BagReader, CdrError, StampedPacket};
use super::{LidarScan, ScanAssembler, VelodyneConfig, DATA_PORT};
use std::collections::VecDeque;
use std::io::{BufReader, Read};
use std::path::Path;

/// Why a packet file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SourceError {
    /// The file could not be opened.
    #[error("reading {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Neither a pcap nor an SQLite (rosbag2) file.
    #[error("{0} is neither a pcap capture nor a ROS 2 .db3 bag")]
    UnknownFormat(String),
    /// The capture is unreadable.
    #[error(transparent)]
    Pcap(#[from] PcapError),
    /// The bag is unreadable.
    #[error(transparent)]
    Bag(#[from] BagError),
}

/// One packet with its host time.
#[derive(Clone, Debug, PartialEq)]
pub struct RawPacket {
    /// Host (capture or ROS) time, seconds.
    pub stamp_s: f64,
    /// The UDP payload.
    pub data: Vec<u8>,
}

/// Things in a file that were not packets.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FileStats {
    /// Bag messages read.
    pub bag_messages: u64,
    /// Bag messages skipped because their CDR was corrupt.
    pub bad_cdr_messages: u64,
    /// Capture frames skipped (pcap files).
    pub pcap: PcapStats,
}

enum Inner {
    Pcap(PcapReader<BufReader<std::fs::File>>, u16),
    Bag(BagReader, VecDeque<StampedPacket>),
}

/// Packets of a pcap capture (UDP to one port) or of a ROS 2 bag's VelodyneScan topic.
pub struct PacketFile {
    inner: Inner,
    stats: FileStats,
    last_cdr_error: Option<CdrError>,
}

impl std::fmt::Debug for PacketFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PacketFile")
            .field("stats", &self.stats)
            .finish()
    }
}

impl PacketFile {
    /// Opens a file, telling pcap from bag by its first bytes; `port` filters pcap traffic
    /// (default 2368), `topic` picks the bag topic (default: the first VelodyneScan topic).
    pub fn open(
        path: impl AsRef<Path>,
        port: Option<u16>,
        topic: Option<&str>,
    ) -> Result<Self, SourceError> {
        let path = path.as_ref();
        let io = |source| SourceError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut magic = [0u8; 16];
        let mut f = std::fs::File::open(path).map_err(io)?;
        let n = f.read(&mut magic).map_err(io)?;
        let inner = if n >= 16 && &magic == b"SQLite format 3\0" {
            Inner::Bag(BagReader::open(path, topic)?, VecDeque::new())
        } else if n >= 4
            && matches!(
                u32::from_le_bytes([magic[0], magic[1], magic[2], magic[3]]),
                0xa1b2c3d4 | 0xa1b23c4d | 0xd4c3b2a1 | 0x4d3cb2a1
            )
        {
            Inner::Pcap(PcapReader::open(path)?, port.unwrap_or(DATA_PORT))
        } else {
            return Err(SourceError::UnknownFormat(path.display().to_string()));
        };
        Ok(Self {
            inner,
            stats: FileStats::default(),
            last_cdr_error: None,
        })
    }

    /// The next packet, `None` at the end. Corrupt bag messages are counted and skipped.
    pub fn next_packet(&mut self) -> Result<Option<RawPacket>, SourceError> {
        match &mut self.inner {
            Inner::Pcap(r, port) => {
                let d = r.next_udp(Some(*port))?;
                self.stats.pcap = r.stats.clone();
                Ok(d.map(|d| RawPacket {
                    stamp_s: d.stamp_s,
                    data: d.payload,
                }))
            }
            Inner::Bag(r, queue) => loop {
                if let Some(p) = queue.pop_front() {
                    return Ok(Some(RawPacket {
                        stamp_s: p.stamp_s,
                        data: p.data,
                    }));
                }
                match r.next_message()? {
                    None => return Ok(None),
                    Some((_, Ok(msg))) => {
                        self.stats.bag_messages += 1;
                        queue.extend(msg.packets);
                    }
                    Some((_, Err(e))) => {
                        self.stats.bag_messages += 1;
                        self.stats.bad_cdr_messages += 1;
                        self.last_cdr_error = Some(e);
                    }
                }
            },
        }
    }

    /// What was skipped so far.
    pub fn stats(&self) -> &FileStats {
        &self.stats
    }

    /// The most recent CDR error, if any message was corrupt.
    pub fn last_cdr_error(&self) -> Option<&CdrError> {
        self.last_cdr_error.as_ref()
    }
}

/// Decodes a whole pcap or bag file into scans (see [`PacketFile::open`]).
pub fn decode_file(
    path: impl AsRef<Path>,
    config: VelodyneConfig,
) -> Result<(Vec<LidarScan>, super::DecodeStats, FileStats), SourceError> {
    let mut f = PacketFile::open(path, None, None)?;
    let mut asm = ScanAssembler::new(config);
    let mut scans = Vec::new();
    while let Some(p) = f.next_packet()? {
        scans.extend(asm.push_packet(&p.data, p.stamp_s));
    }
    scans.extend(asm.finish());
    Ok((scans, asm.stats().clone(), f.stats().clone()))
}
