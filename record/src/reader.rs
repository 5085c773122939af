//! Reads an MCAP file front to back, record by record, without needing its summary: a recording
//! whose process was killed, or whose disk filled, reads up to its last closed chunk and then
//! says where and why it ends. Messages come with their channel's topic, schema name and
//! encodings; metadata records come in file order among them.

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A channel as the file declares it.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelInfo {
    /// Topic.
    pub topic: String,
    /// Message encoding (`json`, `cdr`, ...).
    pub message_encoding: String,
    /// Schema name (`foxglove.PointCloud`, `sensor_msgs/msg/PointCloud2`; empty: none).
    pub schema_name: String,
    /// Schema encoding (`jsonschema`, `ros2msg`, ...).
    pub schema_encoding: String,
    /// The schema's text.
    pub schema_data: Vec<u8>,
}

/// One message.
#[derive(Clone, Debug)]
pub struct Message {
    /// Its channel.
    pub channel: Arc<ChannelInfo>,
    /// Sequence number (terranav: one counter over all channels, so a gap is a dropped message).
    pub sequence: u32,
    /// Log time, nanoseconds since the Unix epoch.
    pub log_time_ns: u64,
    /// The message bytes.
    pub data: Vec<u8>,
}

/// What the file holds, in order.
#[derive(Clone, Debug)]
pub enum Item {
    /// A metadata record.
    Metadata {
        /// Its name.
        name: String,
        /// Its values.
        values: BTreeMap<String, String>,
    },
    /// A message.
    Message(Message),
}

/// Why reading stopped early.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be opened or read.
    #[error("reading {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The file ends inside a record or chunk: the recording was cut (killed, disk full).
    #[error("{path} ends after {offset} bytes inside an unfinished record or chunk (the recording was cut); everything before it was read")]
    Truncated {
        /// File.
        path: String,
        /// Bytes read.
        offset: u64,
    },
    /// A record is not valid MCAP.
    #[error("{path}: not valid MCAP after {offset} bytes: {source}")]
    Corrupt {
        /// File.
        path: String,
        /// Bytes read.
        offset: u64,
        /// Cause.
        source: mcap::McapError,
    },
    /// A message names a channel the file never declared.
    #[error("{path}: message on undeclared channel {channel}")]
    UnknownChannel {
        /// File.
        path: String,
        /// The channel id.
        channel: u16,
    },
}

/// See the module docs.
pub struct Reader {
    path: PathBuf,
    file: std::fs::File,
    lr: LinearReader,
    offset: u64,
    schemas: HashMap<u16, (String, String, Vec<u8>)>,
    channels: HashMap<u16, Arc<ChannelInfo>>,
    done: bool,
    finished: bool,
}

impl Reader {
    /// Opens `path`.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let file = std::fs::File::open(path).map_err(|source| ReadError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            lr: LinearReader::new_with_options(
                LinearReaderOptions::default()
                    .with_validate_chunk_crcs(true)
                    // Chunks are at most a few MiB; a corrupt length must not allocate more.
                    .with_record_length_limit(1 << 30),
            ),
            offset: 0,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            done: false,
            finished: false,
        })
    }

    /// True once the file was read to its end magic (it was closed properly).
    pub fn finished(&self) -> bool {
        self.finished
    }

    /// The channels declared so far.
    pub fn channels(&self) -> impl Iterator<Item = &Arc<ChannelInfo>> {
        self.channels.values()
    }

    fn shown(&self) -> String {
        self.path.display().to_string()
    }

    fn next_item(&mut self) -> Option<Result<Item, ReadError>> {
        loop {
            let event = match self.lr.next_event() {
                None => {
                    self.finished = true;
                    return None;
                }
                // A killed writer leaves its open chunk with the placeholder lengths it patches
                // when the chunk closes (all ones), which the mcap reader reports as a chunk
                // ending early: the same cut as a file ending inside a record.
                Some(Err(mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc)) => {
                    return Some(Err(ReadError::Truncated {
                        path: self.shown(),
                        offset: self.offset,
                    }))
                }
                Some(Err(source)) => {
                    return Some(Err(ReadError::Corrupt {
                        path: self.shown(),
                        offset: self.offset,
                        source,
                    }))
                }
                Some(Ok(e)) => e,
            };
            match event {
                LinearReadEvent::ReadRequest(n) => {
                    let buf = self.lr.insert(n);
                    match self.file.read(buf) {
                        Ok(k) => {
                            self.offset += k as u64;
                            self.lr.notify_read(k);
                        }
                        Err(source) => {
                            return Some(Err(ReadError::Io {
                                path: self.path.display().to_string(),
                                source,
                            }))
                        }
                    }
                }
                LinearReadEvent::Record { opcode, data } => {
                    let rec = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(source) => {
                            return Some(Err(ReadError::Corrupt {
                                path: self.path.display().to_string(),
                                offset: self.offset,
                                source,
                            }))
                        }
                    };
                    match rec {
                        Record::Schema { header, data } => {
                            self.schemas.insert(
                                header.id,
                                (header.name, header.encoding, data.into_owned()),
                            );
                        }
                        Record::Channel(c) => {
                            let (schema_name, schema_encoding, schema_data) =
                                self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                            self.channels.insert(
                                c.id,
                                Arc::new(ChannelInfo {
                                    topic: c.topic,
                                    message_encoding: c.message_encoding,
                                    schema_name,
                                    schema_encoding,
                                    schema_data,
                                }),
                            );
                        }
                        Record::Message { header, data } => {
                            let Some(channel) = self.channels.get(&header.channel_id).cloned()
                            else {
                                return Some(Err(ReadError::UnknownChannel {
                                    path: self.path.display().to_string(),
                                    channel: header.channel_id,
                                }));
                            };
                            return Some(Ok(Item::Message(Message {
                                channel,
                                sequence: header.sequence,
                                log_time_ns: header.log_time,
                                data: data.into_owned(),
                            })));
                        }
                        Record::Metadata(m) => {
                            return Some(Ok(Item::Metadata {
                                name: m.name,
                                values: m.metadata,
                            }))
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

impl Iterator for Reader {
    type Item = Result<Item, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let r = self.next_item();
        if !matches!(r, Some(Ok(_))) {
            // Nothing is read past an error or the end.
            self.done = true;
        }
        r
    }
}
