//! ROS 2 bags (rosbag2 SQLite `.db3`) of `velodyne_msgs/msg/VelodyneScan`, and the CDR decoding of
//! that message.
//!
//! A `.db3` holds tables `topics(id, name, type, serialization_format, ...)` and
//! `messages(id, topic_id, timestamp, data)`. `data` is XCDR1: a 4-byte encapsulation header
//! (`00 01` little-endian or `00 00` big-endian, then two option bytes), then the message with
//! every primitive aligned to its size relative to the end of the header:
//!
//! ```text
//! VelodyneScan   { std_msgs/Header header; VelodynePacket[] packets }
//! Header         { int32 sec; uint32 nanosec; string frame_id }   (string: u32 length incl. NUL)
//! VelodynePacket { int32 sec; uint32 nanosec; uint8[1206] data }  (fixed array: no length)
//! ```

use super::PACKET_SIZE;
use std::path::Path;

/// ROS type name of the decoded message.
pub const VELODYNE_SCAN_TYPE: &str = "velodyne_msgs/msg/VelodyneScan";

/// Why a CDR message could not be decoded.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CdrError {
    /// The message ends before a field.
    #[error("CDR message truncated at byte {at}: {what} needs {need} bytes")]
    Truncated {
        /// Offset where the field starts.
        at: usize,
        /// The field.
        what: &'static str,
        /// Bytes needed.
        need: usize,
    },
    /// The encapsulation header is not plain CDR (little- or big-endian).
    #[error("unsupported CDR encapsulation {0:#06x}")]
    Encapsulation(u16),
    /// A string without its NUL terminator or not UTF-8.
    #[error("bad CDR string at byte {0}")]
    BadString(usize),
}

/// One packet of a scan message.
#[derive(Clone, Debug, PartialEq)]
pub struct StampedPacket {
    /// The packet's stamp, seconds (ROS time).
    pub stamp_s: f64,
    /// The 1206-byte payload.
    pub data: Vec<u8>,
}

/// A decoded `velodyne_msgs/msg/VelodyneScan`.
#[derive(Clone, Debug, PartialEq)]
pub struct VelodyneScanMsg {
    /// Header stamp, seconds.
    pub stamp_s: f64,
    /// Header frame id.
    pub frame_id: String,
    /// The packets.
    pub packets: Vec<StampedPacket>,
}

struct Cdr<'a> {
    buf: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    fn new(msg: &'a [u8]) -> Result<Self, CdrError> {
        if msg.len() < 4 {
            return Err(CdrError::Truncated {
                at: 0,
                what: "encapsulation header",
                need: 4,
            });
        }
        let little = match [msg[0], msg[1]] {
            [0, 1] => true,
            [0, 0] => false,
            [a, b] => return Err(CdrError::Encapsulation(u16::from_be_bytes([a, b]))),
        };
        Ok(Self {
            buf: &msg[4..],
            pos: 0,
            little,
        })
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n).filter(|e| *e <= self.buf.len());
        let end = end.ok_or(CdrError::Truncated {
            at: self.pos + 4,
            what,
            need: n,
        })?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        // Alignment is relative to the end of the encapsulation header. Trailing padding may be
        // missing at the very end of a message, so align only when reading.
        self.pos = (self.pos + 3) & !3;
        let b = self.take(4, what)?;
        let a = [b[0], b[1], b[2], b[3]];
        Ok(if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        })
    }

    fn stamp(&mut self) -> Result<f64, CdrError> {
        let sec = self.u32("stamp.sec")? as i32;
        let nanosec = self.u32("stamp.nanosec")?;
        Ok(sec as f64 + nanosec as f64 * 1e-9)
    }

    fn string(&mut self) -> Result<String, CdrError> {
        let at = self.pos + 4;
        let n = self.u32("string length")? as usize;
        let b = self.take(n, "string")?;
        match b.split_last() {
            Some((0, s)) => String::from_utf8(s.to_vec()).map_err(|_| CdrError::BadString(at)),
            // ROS 2 writes at least the NUL; an empty buffer is tolerated as "".
            None => Ok(String::new()),
            _ => Err(CdrError::BadString(at)),
        }
    }
}

/// Decodes one CDR-serialised `velodyne_msgs/msg/VelodyneScan`.
pub fn decode_velodyne_scan(msg: &[u8]) -> Result<VelodyneScanMsg, CdrError> {
    let mut c = Cdr::new(msg)?;
    let stamp_s = c.stamp()?;
    let frame_id = c.string()?;
    let n = c.u32("packet count")? as usize;
    // Each packet takes at least 8 + 1206 bytes: a count beyond what is left is corruption, and
    // must not drive a huge allocation.
    let room = c.buf.len().saturating_sub(c.pos) / (8 + PACKET_SIZE);
    if n > room {
        return Err(CdrError::Truncated {
            at: c.pos + 4,
            what: "packets",
            need: n * (8 + PACKET_SIZE),
        });
    }
    let mut packets = Vec::with_capacity(n);
    for _ in 0..n {
        let stamp_s = c.stamp()?;
        let data = c.take(PACKET_SIZE, "packet data")?.to_vec();
        packets.push(StampedPacket { stamp_s, data });
    }
    Ok(VelodyneScanMsg {
        stamp_s,
        frame_id,
        packets,
    })
}

/// Encodes a scan message as little-endian CDR (for tests and tools).
pub fn encode_velodyne_scan(m: &VelodyneScanMsg) -> Vec<u8> {
    fn align(b: &mut Vec<u8>) {
        while !(b.len() - 4).is_multiple_of(4) {
            b.push(0);
        }
    }
    fn stamp(b: &mut Vec<u8>, t: f64) {
        align(b);
        let sec = t.floor();
        b.extend_from_slice(&(sec as i32).to_le_bytes());
        b.extend_from_slice(&(((t - sec) * 1e9).round().min(999_999_999.0) as u32).to_le_bytes());
    }
    let mut b = vec![0, 1, 0, 0];
    stamp(&mut b, m.stamp_s);
    b.extend_from_slice(&(m.frame_id.len() as u32 + 1).to_le_bytes());
    b.extend_from_slice(m.frame_id.as_bytes());
    b.push(0);
    align(&mut b);
    b.extend_from_slice(&(m.packets.len() as u32).to_le_bytes());
    for p in &m.packets {
        stamp(&mut b, p.stamp_s);
        b.extend_from_slice(&p.data);
    }
    align(&mut b);
    b
}

/// Why a bag could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BagError {
    /// SQLite failed (not a bag, unreadable file, missing tables).
    #[error("reading bag {path}: {source}")]
    Sqlite {
        /// File path.
        path: String,
        /// Cause.
        source: rusqlite::Error,
    },
    /// No topic of type `velodyne_msgs/msg/VelodyneScan` (or not the requested one).
    #[error("bag {0} has no velodyne_msgs/msg/VelodyneScan topic{1}")]
    NoTopic(String, String),
}

/// A rosbag2 SQLite file opened read-only, iterating one Velodyne topic's messages in time order.
pub struct BagReader {
    conn: rusqlite::Connection,
    path: String,
    /// Topic name being read.
    pub topic: String,
    ids: Vec<(i64, i64)>,
    next: usize,
}

impl std::fmt::Debug for BagReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagReader")
            .field("path", &self.path)
            .field("topic", &self.topic)
            .finish()
    }
}

impl BagReader {
    /// Opens `path` and selects `topic` (or the first topic of type VelodyneScan by id).
    pub fn open(path: impl AsRef<Path>, topic: Option<&str>) -> Result<Self, BagError> {
        let path_s = path.as_ref().display().to_string();
        let sql = |source| BagError::Sqlite {
            path: path_s.clone(),
            source,
        };
        let conn = rusqlite::Connection::open_with_flags(
            path.as_ref(),
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sql)?;
        let topics: Vec<(i64, String)> = {
            let mut st = conn
                .prepare("SELECT id, name FROM topics WHERE type = ?1 ORDER BY id")
                .map_err(sql)?;
            let rows = st
                .query_map([VELODYNE_SCAN_TYPE], |r| Ok((r.get(0)?, r.get(1)?)))
                .map_err(sql)?;
            rows.collect::<Result<_, _>>().map_err(sql)?
        };
        let chosen = topics
            .into_iter()
            .find(|(_, name)| topic.is_none_or(|t| t == name));
        let (topic_id, name) = chosen.ok_or_else(|| {
            BagError::NoTopic(
                path_s.clone(),
                topic.map(|t| format!(" named {t}")).unwrap_or_default(),
            )
        })?;
        let ids: Vec<(i64, i64)> = {
            let mut st = conn
                .prepare(
                    "SELECT id, timestamp FROM messages WHERE topic_id = ?1 ORDER BY timestamp, id",
                )
                .map_err(sql)?;
            let rows = st
                .query_map([topic_id], |r| Ok((r.get(0)?, r.get(1)?)))
                .map_err(sql)?;
            rows.collect::<Result<_, _>>().map_err(sql)?
        };
        Ok(Self {
            conn,
            path: path_s,
            topic: name,
            ids,
            next: 0,
        })
    }

    /// Number of messages on the topic.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// True when the topic has no messages.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The next message: its bag timestamp (ns) and the decoded scan, or `None` at the end.
    /// A message whose CDR is corrupt comes back as `Ok((t, Err(..)))`: skip it and go on.
    #[allow(clippy::type_complexity)]
    pub fn next_message(
        &mut self,
    ) -> Result<Option<(i64, Result<VelodyneScanMsg, CdrError>)>, BagError> {
        Ok(self
            .next_raw()?
            .map(|(t_ns, blob)| (t_ns, decode_velodyne_scan(&blob))))
    }

    /// The next message as recorded: its bag timestamp (ns) and CDR bytes, or `None` at the end
    /// (what a player sends on unchanged).
    pub fn next_raw(&mut self) -> Result<Option<(i64, Vec<u8>)>, BagError> {
        let Some(&(id, t_ns)) = self.ids.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        let blob: Vec<u8> = self
            .conn
            .query_row("SELECT data FROM messages WHERE id = ?1", [id], |r| {
                r.get(0)
            })
            .map_err(|source| BagError::Sqlite {
                path: self.path.clone(),
                source,
            })?;
        Ok(Some((t_ns, blob)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sample() -> VelodyneScanMsg {
        VelodyneScanMsg {
            stamp_s: 1673400471.5,
            frame_id: "velodyne".into(),
            packets: (0..3)
                .map(|i| StampedPacket {
                    stamp_s: 1673400471.5 + i as f64 * 0.001,
                    data: vec![i as u8; PACKET_SIZE],
                })
                .collect(),
        }
    }

    #[test]
    fn round_trip_and_alignment() {
        let m = sample();
        let b = encode_velodyne_scan(&m);
        // Header 4, stamp 8, string 4+9, pad 3, count 4; then 1214 per packet padded to 1216.
        assert_eq!(b.len(), 4 + 28 + 3 * 1216);
        let d = decode_velodyne_scan(&b).unwrap();
        assert_eq!(d.frame_id, "velodyne");
        assert_eq!(d.packets.len(), 3);
        assert_eq!(d.packets[2].data, m.packets[2].data);
        assert!((d.packets[1].stamp_s - m.packets[1].stamp_s).abs() < 1e-6);
        // Without the final padding it still decodes.
        assert_eq!(
            decode_velodyne_scan(&b[..b.len() - 2])
                .unwrap()
                .packets
                .len(),
            3
        );
    }

    #[test]
    fn corrupt_cdr_is_a_typed_error() {
        let b = encode_velodyne_scan(&sample());
        assert!(matches!(
            decode_velodyne_scan(&b[..100]),
            Err(CdrError::Truncated { .. })
        ));
        assert!(matches!(
            decode_velodyne_scan(&b[..2]),
            Err(CdrError::Truncated { .. })
        ));
        let mut e = b.clone();
        e[1] = 3;
        assert_eq!(decode_velodyne_scan(&e), Err(CdrError::Encapsulation(3)));
        let mut huge = b.clone();
        huge[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            decode_velodyne_scan(&huge),
            Err(CdrError::Truncated {
                what: "packets",
                ..
            })
        ));
        let mut nonul = b;
        nonul[4 + 8 + 4 + 8] = b'x';
        assert!(matches!(
            decode_velodyne_scan(&nonul),
            Err(CdrError::BadString(_))
        ));
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4000)) {
            let _ = decode_velodyne_scan(&bytes);
        }

        #[test]
        fn corrupted_messages_never_panic(pos in 0usize..3688, val in any::<u8>(), cut in 0usize..3700) {
            let mut b = encode_velodyne_scan(&sample());
            let n = b.len();
            b[pos % n] = val;
            b.truncate(cut.min(n));
            let _ = decode_velodyne_scan(&b);
        }
    }
}
