//! The MCAP writer: a bounded queue in front of a thread that owns the file, so that a slow or
//! full disk never holds up the loop that records. A message that finds the queue full (by count
//! or by bytes) is dropped and counted, never waited for; every message takes a sequence number
//! when it is offered, so a reader sees each drop as a gap.
//!
//! Chunks are closed, and handed to the operating system, after `chunk_bytes` of messages or
//! `chunk_interval` of wall time, whichever comes first: a process killed at any moment leaves
//! every closed chunk readable (at most the last second is lost). A write error (a full disk) stops
//! the writing for good; what was written before stays readable and later messages are counted as
//! dropped. With a [`Split`] the recording is a folder of files (`0000.mcap`, `0001.mcap`, ...),
//! each complete in itself (schemas, channels and metadata repeated, its own summary and index).

use crate::schemas::Schema;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How a recording is cut into files.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Split {
    /// Start a new file once this one holds this many bytes.
    pub max_bytes: Option<u64>,
    /// Start a new file once this one spans this much log time, seconds.
    pub max_duration_s: Option<f64>,
}

impl Split {
    /// True when the recording is to be cut at all.
    pub fn is_set(&self) -> bool {
        self.max_bytes.is_some() || self.max_duration_s.is_some()
    }
}

/// What and how to record.
#[derive(Clone, Debug)]
pub struct Options {
    /// The file, or with a [`Split`] the folder of files.
    pub path: PathBuf,
    /// Rotation.
    pub split: Split,
    /// Close a chunk after this many bytes of messages (uncompressed).
    pub chunk_bytes: u64,
    /// ... or after this much wall time.
    pub chunk_interval: Duration,
    /// Messages the queue holds at most.
    pub queue_messages: usize,
    /// Bytes (as estimated by the caller) the queue holds at most.
    pub queue_bytes: usize,
    /// The MCAP header's profile.
    pub profile: String,
    /// For tests: every write fails as on a full disk once the file holds this many bytes.
    pub fail_after_bytes: Option<u64>,
}

impl Options {
    /// Defaults for recording to `path`.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            split: Split::default(),
            chunk_bytes: 4 << 20,
            chunk_interval: Duration::from_secs(1),
            queue_messages: 4096,
            queue_bytes: 256 << 20,
            profile: String::new(),
            fail_after_bytes: None,
        }
    }
}

/// A channel of the recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ChannelId(u16);

/// Counters of a recording (live, while it runs).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Stats {
    /// Messages written.
    pub written: u64,
    /// Messages dropped because the queue was full.
    pub dropped_queue: u64,
    /// Messages dropped because writing had failed.
    pub dropped_error: u64,
    /// Bytes in the files so far.
    pub bytes: u64,
    /// Files begun.
    pub files: u32,
    /// The write error that stopped the recording, if one did.
    pub error: Option<String>,
}

impl Stats {
    /// Every message not written, for whatever reason.
    pub fn dropped(&self) -> u64 {
        self.dropped_queue + self.dropped_error
    }
}

/// What a finished recording holds.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Finished {
    /// The counters at the end.
    pub stats: Stats,
    /// The files, in order.
    pub files: Vec<PathBuf>,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
}

#[derive(Default)]
struct Shared {
    written: AtomicU64,
    dropped_queue: AtomicU64,
    dropped_error: AtomicU64,
    bytes: AtomicU64,
    files: AtomicU32,
    in_flight: AtomicUsize,
    error: Mutex<Option<String>>,
}

/// Serialises one message on the writer thread.
type Encode = Box<dyn FnOnce() -> Vec<u8> + Send>;

enum Job {
    Channel {
        id: u16,
        topic: String,
        schema: Schema,
        encoding: String,
    },
    Metadata(String, BTreeMap<String, String>),
    Message {
        channel: u16,
        sequence: u32,
        log_time_ns: u64,
        size: usize,
        encode: Encode,
    },
    Flush(SyncSender<()>),
}

/// The recording's handle: cheap calls that never wait for the disk. Dropping it finishes the
/// recording (as [`Recorder::finish`] does).
pub struct Recorder {
    tx: Option<SyncSender<Job>>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Finished>>,
    next_channel: u16,
    sequence: u32,
    queue_bytes: usize,
}

/// Why a recording could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The file or folder could not be created.
    #[error("creating {path}: {source}")]
    Create {
        /// The path.
        path: String,
        /// Cause.
        source: io::Error,
    },
    /// The MCAP writer refused to start.
    #[error("starting MCAP {path}: {source}")]
    Mcap {
        /// The path.
        path: String,
        /// Cause.
        source: mcap::McapError,
    },
}

impl Recorder {
    /// Opens the first file and starts the writer thread.
    pub fn start(opts: Options) -> Result<Self, StartError> {
        let shared = Arc::new(Shared::default());
        let first = FileWriter::open(&opts, 0, &shared)?;
        let (tx, rx) = std::sync::mpsc::sync_channel(opts.queue_messages.max(1));
        let queue_bytes = opts.queue_bytes;
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || run(opts, first, rx, sh))
            .map_err(|source| StartError::Create {
                path: "writer thread".into(),
                source,
            })?;
        Ok(Self {
            tx: Some(tx),
            shared,
            thread: Some(thread),
            next_channel: 1,
            sequence: 0,
            queue_bytes,
        })
    }

    /// Adds a channel (JSON messages of `schema`). Call before the recording gets busy: unlike
    /// messages, a channel waits for room in the queue.
    pub fn channel(&mut self, topic: &str, schema: &Schema) -> ChannelId {
        self.channel_with_encoding(topic, schema, "json")
    }

    /// Adds a channel with another message encoding (`cdr` for ROS 2 messages).
    pub fn channel_with_encoding(
        &mut self,
        topic: &str,
        schema: &Schema,
        encoding: &str,
    ) -> ChannelId {
        let id = self.next_channel;
        self.next_channel += 1;
        if let Some(tx) = &self.tx {
            let _ = tx.send(Job::Channel {
                id,
                topic: topic.to_string(),
                schema: schema.clone(),
                encoding: encoding.to_string(),
            });
        }
        ChannelId(id)
    }

    /// Adds a metadata record (repeated at the start of every later file of a split recording).
    pub fn metadata(&mut self, name: &str, values: BTreeMap<String, String>) {
        if let Some(tx) = &self.tx {
            let _ = tx.send(Job::Metadata(name.to_string(), values));
        }
    }

    /// Offers one message: `encode` runs on the writer thread and returns the message bytes;
    /// `size` is the caller's estimate of what the job holds (for the queue's byte bound).
    /// Returns false when the message was dropped (queue full, or writing has failed).
    pub fn write(
        &mut self,
        channel: ChannelId,
        log_time_ns: u64,
        size: usize,
        encode: impl FnOnce() -> Vec<u8> + Send + 'static,
    ) -> bool {
        let sequence = self.sequence;
        self.sequence = self.sequence.wrapping_add(1);
        let Some(tx) = &self.tx else {
            return false;
        };
        if self.shared.in_flight.load(Ordering::Relaxed) + size > self.queue_bytes {
            self.shared.dropped_queue.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        self.shared.in_flight.fetch_add(size, Ordering::Relaxed);
        match tx.try_send(Job::Message {
            channel: channel.0,
            sequence,
            log_time_ns,
            size,
            encode: Box::new(encode),
        }) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.shared.in_flight.fetch_sub(size, Ordering::Relaxed);
                self.shared.dropped_queue.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Waits until everything offered so far is written and its chunk is closed (tests, and
    /// before reading a file that is still being recorded).
    pub fn flush(&self) {
        if let Some(tx) = &self.tx {
            let (done, wait) = std::sync::mpsc::sync_channel(1);
            if tx.send(Job::Flush(done)).is_ok() {
                let _ = wait.recv();
            }
        }
    }

    /// The counters now.
    pub fn stats(&self) -> Stats {
        stats(&self.shared)
    }

    /// Writes what is queued, closes the file(s) with their summaries, and says what they hold.
    pub fn finish(mut self) -> Finished {
        self.close()
    }

    fn close(&mut self) -> Finished {
        drop(self.tx.take());
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(f)) => f,
            Some(Err(_)) => Finished {
                stats: Stats {
                    error: Some("the writer thread panicked".into()),
                    ..stats(&self.shared)
                },
                ..Finished::default()
            },
            None => Finished {
                stats: stats(&self.shared),
                ..Finished::default()
            },
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.close();
        }
    }
}

fn stats(s: &Shared) -> Stats {
    Stats {
        written: s.written.load(Ordering::Relaxed),
        dropped_queue: s.dropped_queue.load(Ordering::Relaxed),
        dropped_error: s.dropped_error.load(Ordering::Relaxed),
        bytes: s.bytes.load(Ordering::Relaxed),
        files: s.files.load(Ordering::Relaxed),
        error: s.error.lock().map(|e| e.clone()).unwrap_or_default(),
    }
}

/// A file that counts its bytes and, for tests, fails like a full disk.
struct Counted {
    inner: BufWriter<File>,
    pos: u64,
    end: u64,
    fail_after: Option<u64>,
    shared: Arc<Shared>,
}

impl Write for Counted {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self
            .fail_after
            .is_some_and(|cap| self.pos + buf.len() as u64 > cap)
        {
            return Err(io::Error::new(
                io::ErrorKind::StorageFull,
                "no space left on device (simulated)",
            ));
        }
        let n = self.inner.write(buf)?;
        self.pos += n as u64;
        if self.pos > self.end {
            self.shared
                .bytes
                .fetch_add(self.pos - self.end, Ordering::Relaxed);
            self.end = self.pos;
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

impl Seek for Counted {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        self.pos = self.inner.seek(to)?;
        Ok(self.pos)
    }
}

struct FileWriter {
    mcap: mcap::Writer<Counted>,
    path: PathBuf,
    first_log_ns: Option<u64>,
    /// The file's channel id of each of ours.
    ids: std::collections::HashMap<u16, u16>,
}

impl FileWriter {
    fn path_of(opts: &Options, index: u32) -> PathBuf {
        if opts.split.is_set() {
            opts.path.join(format!("{index:04}.mcap"))
        } else {
            opts.path.clone()
        }
    }

    fn open(opts: &Options, index: u32, shared: &Arc<Shared>) -> Result<Self, StartError> {
        let path = Self::path_of(opts, index);
        let create = |source| StartError::Create {
            path: path.display().to_string(),
            source,
        };
        if opts.split.is_set() {
            std::fs::create_dir_all(&opts.path).map_err(create)?;
        } else if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(create)?;
        }
        let file = File::create(&path).map_err(create)?;
        let out = Counted {
            inner: BufWriter::with_capacity(1 << 20, file),
            pos: 0,
            end: 0,
            fail_after: opts.fail_after_bytes,
            shared: shared.clone(),
        };
        let mcap = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .profile(opts.profile.clone())
            // The writer closes chunks itself (size or time), so that a closed chunk is also on disk.
            .chunk_size(None)
            // This thread is the compressor; zstd's own workers would compete with the robot.
            .compression_threads(0)
            .create(out)
            .map_err(|source| StartError::Mcap {
                path: path.display().to_string(),
                source,
            })?;
        shared.files.fetch_add(1, Ordering::Relaxed);
        Ok(Self {
            mcap,
            path,
            first_log_ns: None,
            ids: Default::default(),
        })
    }
}

struct ChannelDef {
    id: u16,
    topic: String,
    schema: Schema,
    encoding: String,
}

/// The writer thread's state.
struct Thread {
    opts: Options,
    shared: Arc<Shared>,
    file: Option<FileWriter>,
    index: u32,
    files: Vec<PathBuf>,
    channels: Vec<ChannelDef>,
    metadata: Vec<(String, BTreeMap<String, String>)>,
    chunk_fill: u64,
    chunk_started: Instant,
    messages: BTreeMap<u16, u64>,
    failed: bool,
}

impl Thread {
    fn fail(&mut self, what: &str, e: impl std::error::Error) {
        if !self.failed {
            // The MCAP errors wrap the I/O error that says why (a full disk); name it.
            let mut msg = format!("{what}: {e}");
            let mut cause = e.source();
            while let Some(c) = cause {
                msg.push_str(&format!(": {c}"));
                cause = c.source();
            }
            tracing::error!("recording stopped: {msg}");
            if let Ok(mut slot) = self.shared.error.lock() {
                *slot = Some(msg);
            }
        }
        self.failed = true;
        // Nothing more can be added to this file; what it holds stays readable. Forget it
        // without finishing (finishing would write more after the failure).
        if let Some(f) = self.file.take() {
            std::mem::forget(f);
        }
    }

    fn register(file: &mut FileWriter, c: &ChannelDef) -> mcap::McapResult<()> {
        let schema_id =
            file.mcap
                .add_schema(&c.schema.name, &c.schema.encoding, c.schema.data.as_bytes())?;
        let id = file
            .mcap
            .add_channel(schema_id, &c.topic, &c.encoding, &BTreeMap::new())?;
        file.ids.insert(c.id, id);
        Ok(())
    }

    fn close_chunk(&mut self) {
        self.chunk_fill = 0;
        self.chunk_started = Instant::now();
        if let Some(f) = self.file.as_mut() {
            // Closes the chunk and hands it to the OS: a kill after this loses nothing before it.
            if let Err(e) = f.mcap.flush() {
                self.fail("closing a chunk", e);
            }
        }
    }

    fn finish_file(&mut self) {
        if let Some(mut f) = self.file.take() {
            match f.mcap.finish() {
                Ok(_) => {
                    let mut out = f.mcap.into_inner();
                    if let Err(e) = out.flush() {
                        self.fail("finishing the file", e);
                    }
                }
                Err(e) => self.fail("finishing the file", e),
            }
        }
    }

    fn rotate(&mut self) {
        self.finish_file();
        if self.failed {
            return;
        }
        self.index += 1;
        match FileWriter::open(&self.opts, self.index, &self.shared) {
            Ok(mut f) => {
                for c in &self.channels {
                    if let Err(e) = Self::register(&mut f, c) {
                        self.fail("adding a channel", e);
                        return;
                    }
                }
                for (name, values) in &self.metadata {
                    let m = mcap::records::Metadata {
                        name: name.clone(),
                        metadata: values.clone(),
                    };
                    if let Err(e) = f.mcap.write_metadata(&m) {
                        self.fail("writing metadata", e);
                        return;
                    }
                }
                self.files.push(f.path.clone());
                self.file = Some(f);
            }
            Err(e) => self.fail("starting the next file", e),
        }
    }

    fn due_for_rotation(&self, log_ns: u64) -> bool {
        let Some(f) = &self.file else {
            return false;
        };
        let split = self.opts.split;
        // The file's length on disk lags the writer by its buffer (1 MiB) and the open chunk:
        // close enough for a rotation threshold.
        split
            .max_bytes
            .is_some_and(|b| std::fs::metadata(&f.path).map(|m| m.len()).unwrap_or(0) >= b)
            || split.max_duration_s.is_some_and(|d| {
                f.first_log_ns
                    .is_some_and(|t0| log_ns.saturating_sub(t0) as f64 * 1e-9 >= d)
            })
    }

    fn job(&mut self, job: Job) {
        match job {
            Job::Channel {
                id,
                topic,
                schema,
                encoding,
            } => {
                let c = ChannelDef {
                    id,
                    topic,
                    schema,
                    encoding,
                };
                if let Some(f) = self.file.as_mut() {
                    if let Err(e) = Self::register(f, &c) {
                        self.fail("adding a channel", e);
                    }
                }
                self.channels.push(c);
            }
            Job::Metadata(name, values) => {
                if let Some(f) = self.file.as_mut() {
                    let m = mcap::records::Metadata {
                        name: name.clone(),
                        metadata: values.clone(),
                    };
                    if let Err(e) = f.mcap.write_metadata(&m) {
                        self.fail("writing metadata", e);
                    }
                }
                self.metadata.push((name, values));
            }
            Job::Message {
                channel,
                sequence,
                log_time_ns,
                size,
                encode,
            } => {
                self.shared.in_flight.fetch_sub(size, Ordering::Relaxed);
                if self.failed {
                    self.shared.dropped_error.fetch_add(1, Ordering::Relaxed);
                    return;
                }
                if self.due_for_rotation(log_time_ns) {
                    self.rotate();
                    if self.failed {
                        self.shared.dropped_error.fetch_add(1, Ordering::Relaxed);
                        return;
                    }
                }
                let data = encode();
                let Some(f) = self.file.as_mut() else {
                    self.shared.dropped_error.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                f.first_log_ns.get_or_insert(log_time_ns);
                let Some(&channel_id) = f.ids.get(&channel) else {
                    self.shared.dropped_error.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                let header = mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: log_time_ns,
                    publish_time: log_time_ns,
                };
                match f.mcap.write_to_known_channel(&header, &data) {
                    Ok(()) => {
                        self.shared.written.fetch_add(1, Ordering::Relaxed);
                        *self.messages.entry(channel).or_default() += 1;
                        self.chunk_fill += data.len() as u64;
                        if self.chunk_fill >= self.opts.chunk_bytes {
                            self.close_chunk();
                        }
                    }
                    Err(e) => {
                        self.shared.dropped_error.fetch_add(1, Ordering::Relaxed);
                        self.fail("writing a message", e);
                    }
                }
            }
            Job::Flush(done) => {
                self.close_chunk();
                let _ = done.send(());
            }
        }
    }
}

fn run(opts: Options, first: FileWriter, rx: Receiver<Job>, shared: Arc<Shared>) -> Finished {
    let interval = opts.chunk_interval;
    let mut t = Thread {
        files: vec![first.path.clone()],
        file: Some(first),
        opts,
        shared,
        index: 0,
        channels: Vec::new(),
        metadata: Vec::new(),
        chunk_fill: 0,
        chunk_started: Instant::now(),
        messages: BTreeMap::new(),
        failed: false,
    };
    loop {
        let wait = interval.saturating_sub(t.chunk_started.elapsed());
        match rx.recv_timeout(wait.max(Duration::from_millis(1))) {
            Ok(job) => t.job(job),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if t.chunk_started.elapsed() >= interval {
            if t.chunk_fill > 0 {
                t.close_chunk();
            } else {
                t.chunk_started = Instant::now();
            }
        }
    }
    t.finish_file();
    let topics: BTreeMap<u16, &str> = t
        .channels
        .iter()
        .map(|c| (c.id, c.topic.as_str()))
        .collect();
    let mut messages = BTreeMap::new();
    for (id, n) in &t.messages {
        if let Some(topic) = topics.get(id) {
            *messages.entry(topic.to_string()).or_default() += n;
        }
    }
    Finished {
        stats: stats(&t.shared),
        files: t.files,
        messages,
    }
}

/// Every `.mcap` file of a recording: the file itself, or a split recording's folder in order.
pub fn recording_files(path: &Path) -> io::Result<Vec<PathBuf>> {
    if path.is_dir() {
        let mut files: Vec<PathBuf> = std::fs::read_dir(path)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
            .collect();
        files.sort();
        Ok(files)
    } else {
        Ok(vec![path.to_path_buf()])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reader::{Item, ReadError, Reader};

    fn schema() -> Schema {
        crate::schemas::terranav::heading()
    }

    fn payload(i: u64, len: usize) -> Vec<u8> {
        // Incompressible enough that chunks fill as the sizes say.
        let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect()
    }

    /// (topic, sequence, log time, data) of each message.
    type Msgs = Vec<(String, u32, u64, Vec<u8>)>;

    fn read_all(path: &Path) -> (Msgs, Vec<String>, Option<ReadError>, bool) {
        let mut r = Reader::open(path).unwrap();
        let (mut msgs, mut meta, mut err) = (Vec::new(), Vec::new(), None);
        for item in r.by_ref() {
            match item {
                Ok(Item::Message(m)) => {
                    msgs.push((m.channel.topic.clone(), m.sequence, m.log_time_ns, m.data))
                }
                Ok(Item::Metadata { name, .. }) => meta.push(name),
                Err(e) => err = Some(e),
            }
        }
        let finished = r.finished();
        (msgs, meta, err, finished)
    }

    #[test]
    fn messages_metadata_and_summary_round_trip() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("a.mcap");
        let mut rec = Recorder::start(Options::new(&path)).unwrap();
        let a = rec.channel("/a", &schema());
        let b = rec.channel("/b", &schema());
        rec.metadata("m", BTreeMap::from([("k".into(), "v".into())]));
        for i in 0..100u64 {
            let ch = if i % 3 == 0 { b } else { a };
            assert!(rec.write(ch, 1_000 + i, 10, move || payload(i, 10)));
        }
        let f = rec.finish();
        assert_eq!(f.stats.written, 100);
        assert_eq!(f.stats.dropped(), 0);
        assert_eq!(f.messages["/b"], 34);
        let (msgs, meta, err, finished) = read_all(&path);
        assert!(err.is_none() && finished, "{err:?}");
        assert_eq!(meta, ["m"]);
        assert_eq!(msgs.len(), 100);
        assert!(msgs
            .iter()
            .enumerate()
            .all(|(i, m)| m.1 == i as u32 && m.3 == payload(i as u64, 10)));
        let bytes = std::fs::read(&path).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert_eq!(summary.stats.unwrap().message_count, 100);
        assert_eq!(summary.channels.len(), 2);
    }

    #[test]
    fn a_cut_file_reads_to_its_last_closed_chunk() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("cut.mcap");
        let mut opts = Options::new(&path);
        opts.chunk_bytes = 20_000;
        let mut rec = Recorder::start(opts).unwrap();
        let a = rec.channel("/a", &schema());
        for i in 0..50u64 {
            rec.write(a, i, 1000, move || payload(i, 1000));
        }
        rec.flush();
        // What a SIGKILL now would leave on disk.
        let cut = d.path().join("copy.mcap");
        std::fs::copy(&path, &cut).unwrap();
        for i in 50..60u64 {
            rec.write(a, i, 1000, move || payload(i, 1000));
        }
        drop(rec);
        let (msgs, _, err, finished) = read_all(&cut);
        assert!(!finished);
        assert!(matches!(err, Some(ReadError::Truncated { .. })), "{err:?}");
        assert_eq!(msgs.len(), 50);
        // A kill while a chunk is open leaves the header the mcap writer starts every chunk
        // with: lengths all ones until the chunk is closed, then compressed bytes.
        let mut open = std::fs::read(&cut).unwrap();
        open.push(0x06);
        open.extend((!0u64).to_le_bytes());
        open.extend([0u8; 16]); // start and end time
        open.extend((!0u64).to_le_bytes()); // uncompressed size
        open.extend((!0u32).to_le_bytes()); // uncompressed CRC
        open.extend(4u32.to_le_bytes());
        open.extend(b"zstd");
        open.extend((!0u64).to_le_bytes()); // compressed size
        open.extend(payload(99, 3000));
        let open_path = d.path().join("open-chunk.mcap");
        std::fs::write(&open_path, &open).unwrap();
        let (msgs, _, err, finished) = read_all(&open_path);
        assert!(!finished);
        assert!(matches!(err, Some(ReadError::Truncated { .. })), "{err:?}");
        assert_eq!(msgs.len(), 50);
        // And a cut in the middle of a chunk: the chunks before it still read.
        let bytes = std::fs::read(&cut).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let (msgs, _, err, _) = read_all(&cut);
        assert!(err.is_some());
        assert!(msgs.len() >= 20 && msgs.len() < 50, "{}", msgs.len());
        assert!(msgs
            .iter()
            .enumerate()
            .all(|(i, m)| m.3 == payload(i as u64, 1000)));
    }

    #[test]
    fn a_full_disk_stops_the_recording_and_keeps_what_was_written() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("full.mcap");
        let mut opts = Options::new(&path);
        opts.chunk_bytes = 10_000;
        opts.fail_after_bytes = Some(60_000);
        let mut rec = Recorder::start(opts).unwrap();
        let a = rec.channel("/a", &schema());
        for i in 0..200u64 {
            rec.write(a, i, 1000, move || payload(i, 1000));
        }
        let f = rec.finish();
        assert!(
            f.stats
                .error
                .as_deref()
                .is_some_and(|e| e.contains("no space")),
            "{:?}",
            f.stats
        );
        assert!(f.stats.dropped_error > 0);
        assert_eq!(f.stats.written + f.stats.dropped_error, 200);
        let (msgs, _, err, _) = read_all(&path);
        assert!(err.is_some());
        assert!(msgs.len() >= 40, "{}", msgs.len());
        assert!(msgs
            .iter()
            .enumerate()
            .all(|(i, m)| m.3 == payload(i as u64, 1000)));
    }

    #[test]
    fn a_split_recording_is_a_folder_of_complete_files() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("rec");
        let mut opts = Options::new(&dir);
        opts.split.max_duration_s = Some(1.0);
        let mut rec = Recorder::start(opts).unwrap();
        let a = rec.channel("/a", &schema());
        rec.metadata("m", BTreeMap::new());
        for i in 0..35u64 {
            rec.write(a, i * 100_000_000, 10, move || payload(i, 10));
        }
        let f = rec.finish();
        assert_eq!(f.files.len(), 4, "{:?}", f.files);
        assert_eq!(recording_files(&dir).unwrap(), f.files);
        let mut all = Vec::new();
        for file in &f.files {
            let (msgs, meta, err, finished) = read_all(file);
            assert!(err.is_none() && finished);
            assert_eq!(meta, ["m"]);
            all.extend(msgs.into_iter().map(|m| m.1));
        }
        assert_eq!(all, (0..35).collect::<Vec<u32>>());
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_waiting() {
        let d = tempfile::tempdir().unwrap();
        let mut opts = Options::new(d.path().join("q.mcap"));
        opts.queue_messages = 2;
        let mut rec = Recorder::start(opts).unwrap();
        let a = rec.channel("/a", &schema());
        let t = Instant::now();
        let mut accepted = 0;
        for i in 0..50u64 {
            accepted += u64::from(rec.write(a, i, 10, move || {
                std::thread::sleep(Duration::from_millis(20));
                payload(i, 10)
            }));
        }
        assert!(
            t.elapsed() < Duration::from_millis(200),
            "{:?}",
            t.elapsed()
        );
        let f = rec.finish();
        assert_eq!(f.stats.written, accepted);
        assert_eq!(f.stats.dropped_queue, 50 - accepted);
        assert!(f.stats.dropped_queue > 30);
    }
}
