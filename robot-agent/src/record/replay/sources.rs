//! Where a replay's events come from: a terranav recording (its session metadata, commands and
//! control periods included) or a ROS 2 bag (inputs only), read in order.

use super::Event;
use crate::record::channels::{InputKind, CMD_VEL, COMMANDS};
use crate::record::digest::Digest;
use crate::record::rosbag::{Db3, Decoder};
use crate::record::SessionMeta;
use crate::runtime::AgentCommand;
use agent::Cmd;
use record::{Item, Reader};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};

/// A recording's events.
pub(super) struct RecordingSource {
    files: VecDeque<PathBuf>,
    reader: Option<Reader>,
    pub(super) meta: Option<SessionMeta>,
    pub(super) digest: Option<Digest>,
    last_seq: Option<u32>,
    pub(super) gaps: u64,
    pub(super) truncated: Option<String>,
    /// The first message, read while looking for the session's metadata.
    first: Option<record::Message>,
}

impl RecordingSource {
    pub(super) fn open(files: Vec<PathBuf>) -> anyhow::Result<Self> {
        let mut s = Self {
            files: files.into(),
            reader: None,
            meta: None,
            digest: None,
            last_seq: None,
            gaps: 0,
            truncated: None,
            first: None,
        };
        // The session's metadata (and its configuration) come before its first message; reading
        // up to that message processes them.
        match s.next_raw() {
            None => {}
            Some(Err(e)) => return Err(e),
            Some(Ok(m)) => s.first = Some(m),
        }
        anyhow::ensure!(
            s.meta.is_some(),
            "the recording has no terranav.session metadata before its first message"
        );
        Ok(s)
    }

    /// The next item of the files, handling metadata; `None` at the end.
    fn next_raw(&mut self) -> Option<anyhow::Result<record::Message>> {
        loop {
            if self.reader.is_none() {
                let f = self.files.pop_front()?;
                match Reader::open(&f) {
                    Ok(r) => self.reader = Some(r),
                    Err(e) => return Some(Err(e.into())),
                }
            }
            let r = self.reader.as_mut()?;
            match r.next() {
                None => self.reader = None,
                Some(Err(e @ record::ReadError::Truncated { .. })) => {
                    self.truncated = Some(e.to_string());
                    self.reader = None;
                }
                Some(Err(e)) => {
                    self.truncated = Some(e.to_string());
                    self.reader = None;
                }
                Some(Ok(Item::Metadata { name, values })) => {
                    if name == record::SESSION_METADATA && self.meta.is_none() {
                        match SessionMeta::from_metadata(&values) {
                            Ok(m) => self.meta = Some(m),
                            Err(e) => return Some(Err(e)),
                        }
                    } else if name == crate::record::CONFIG_METADATA {
                        if let Some(m) = self.meta.as_mut() {
                            if m.config_files.is_empty() {
                                m.config_files = values;
                            }
                        }
                    } else if name == crate::record::DIGEST_METADATA {
                        self.digest = digest_of(&values);
                    }
                }
                Some(Ok(Item::Message(m))) => {
                    if let Some(l) = self.last_seq {
                        self.gaps += u64::from(m.sequence.wrapping_sub(l).saturating_sub(1));
                    }
                    self.last_seq = Some(m.sequence);
                    return Some(Ok(m));
                }
            }
        }
    }

    fn next_event(&mut self) -> Option<anyhow::Result<Event>> {
        loop {
            let next = match self.first.take() {
                Some(m) => Ok(m),
                None => self.next_raw()?,
            };
            let m = match next {
                Ok(m) => m,
                Err(e) => return Some(Err(e)),
            };
            let topic = m.channel.topic.as_str();
            if let Some(kind) = InputKind::of_topic(topic) {
                return Some(Ok(match crate::record::inputs::from_json(kind, &m.data) {
                    Ok(i) => Event::Input(i),
                    Err(e) => Event::Undecodable(kind.stream(), format!("{topic}: {e}")),
                }));
            }
            if topic == COMMANDS {
                return Some(command_of(&m.data).map(Event::Command));
            }
            if topic == CMD_VEL {
                return Some(control_of(&m.data));
            }
        }
    }
}

fn digest_of(values: &std::collections::BTreeMap<String, String>) -> Option<Digest> {
    let s = |k: &str| values.get(k).cloned();
    Some(Digest {
        poses: s("poses")?,
        plans: s("plans")?,
        tiles: s("tiles")?,
        commands: s("commands")?,
        controls: s("controls")?.parse().ok()?,
        plan_changes: s("plan_changes")?.parse().ok()?,
    })
}

fn command_of(data: &[u8]) -> anyhow::Result<AgentCommand> {
    let v: serde_json::Value = serde_json::from_slice(data)?;
    let t_s = v["t_s"]
        .as_f64()
        .ok_or_else(|| anyhow::anyhow!("/commands: no t_s"))?;
    if let Some(c) = v.get("command") {
        let kind = serde_json::from_value(c.clone())?;
        Ok(AgentCommand::Do(agent::Command::at(t_s, kind)))
    } else if let Some(r) = v.get("refusal") {
        Ok(AgentCommand::Refused {
            t_s,
            refusal: serde_json::from_value(r.clone())?,
        })
    } else {
        anyhow::bail!("/commands: neither command nor refusal")
    }
}

fn control_of(data: &[u8]) -> anyhow::Result<Event> {
    let v: serde_json::Value = serde_json::from_slice(data)?;
    let n = |k: &str| {
        v[k].as_f64()
            .ok_or_else(|| anyhow::anyhow!("/cmd_vel: no {k}"))
    };
    Ok(Event::Control {
        t_s: n("t_s")?,
        cmd: Cmd {
            v_mps: n("v_mps")?,
            omega_rps: n("omega_rps")?,
        },
    })
}

/// A bag's events.
pub(super) enum BagReader {
    // Boxed: the MCAP reader's buffers are large beside the SQLite handle.
    Mcap(Box<Reader>),
    Db3(Db3),
}

pub(super) struct BagSource {
    pub(super) reader: BagReader,
    pub(super) decoder: Decoder,
    pub(super) pending: VecDeque<Event>,
    pub(super) truncated: Option<String>,
    pub(super) ended: bool,
}

impl BagSource {
    fn next_event(&mut self) -> Option<anyhow::Result<Event>> {
        loop {
            if let Some(e) = self.pending.pop_front() {
                return Some(Ok(e));
            }
            if self.ended {
                return None;
            }
            let msg = match &mut self.reader {
                BagReader::Mcap(r) => match r.next() {
                    None => None,
                    Some(Ok(Item::Message(m))) => Some(Ok((
                        m.channel.topic.clone(),
                        m.channel.schema_name.clone(),
                        m.data,
                    ))),
                    Some(Ok(Item::Metadata { .. })) => continue,
                    Some(Err(e)) => {
                        self.truncated = Some(e.to_string());
                        None
                    }
                },
                BagReader::Db3(d) => d.next_message(),
            };
            match msg {
                None => {
                    self.ended = true;
                    self.decoder.finish();
                }
                Some(Err(e)) => return Some(Err(e)),
                Some(Ok((topic, ty, data))) => {
                    self.decoder.decode(&topic, &ty, &data, &mut self.pending)
                }
            }
        }
    }
}

// Both boxed: each holds a reader with large buffers, and only one exists per replay.
pub(super) enum Source {
    Recording(Box<RecordingSource>),
    Bag(Box<BagSource>),
}

impl Source {
    pub(super) fn next_event(&mut self) -> Option<anyhow::Result<Event>> {
        match self {
            Source::Recording(r) => r.next_event(),
            Source::Bag(b) => b.next_event(),
        }
    }
}

/// Whether an MCAP file is a terranav recording (its session metadata comes first) or a bag.
pub(super) fn is_terranav(path: &Path) -> anyhow::Result<bool> {
    for item in Reader::open(path)? {
        match item {
            Ok(Item::Metadata { name, .. }) if name == record::SESSION_METADATA => return Ok(true),
            Ok(Item::Message(_)) => return Ok(false),
            Ok(_) => {}
            Err(e) => return Err(e.into()),
        }
    }
    Ok(false)
}

/// The topics (name, type) of an MCAP bag (a first pass over it).
pub(super) fn mcap_topics(path: &Path) -> anyhow::Result<Vec<(String, String)>> {
    let mut r = Reader::open(path)?;
    for item in r.by_ref() {
        if item.is_err() {
            break;
        }
    }
    let mut v: Vec<(String, String)> = r
        .channels()
        .filter(|c| c.message_encoding == "cdr")
        .map(|c| (c.topic.clone(), c.schema_name.clone()))
        .collect();
    v.sort();
    v.dedup();
    Ok(v)
}
