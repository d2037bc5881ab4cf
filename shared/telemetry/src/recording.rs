//! MCAP recordings of per-cycle data, JSON messages with JSON-schema schemas, so Foxglove
//! can open and plot them directly.
//!
//! The file holds nothing that depends on the wall clock or the machine: the same calls
//! with the same data give the same bytes (the determinism tests compare recordings byte
//! for byte). Timestamps are whatever the caller passes: the simulated clock in simulations,
//! Unix time in the processes (so [`merge`] can put both processes' files on one timeline).
//!
//! ```no_run
//! use h4_telemetry::recording::Recorder;
//! # fn main() -> Result<(), h4_telemetry::recording::RecordingError> {
//! let mut rec = Recorder::create("run.mcap")?;
//! let ch = rec.add_channel(
//!     "/slave/force",
//!     "h4.Force",
//!     r#"{"type":"object","properties":{"fz_n":{"type":"number"}}}"#,
//! )?;
//! #[derive(serde::Serialize)]
//! struct Force { fz_n: f64 }
//! rec.write(ch, 1_000_000, &Force { fz_n: 20.0 })?;
//! rec.finish()?;
//! # Ok(()) }
//! ```

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Cursor, Seek, Write};
use std::path::Path;

use serde::Serialize;

/// Identifies a channel of a [`Recorder`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ChannelId(u16);

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be created or written.
    #[error("recording {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The MCAP writer refused a record.
    #[error("recording: MCAP: {0}")]
    Mcap(String),
    /// A message could not be serialised to JSON.
    #[error("recording: JSON message on channel {channel}: {message}")]
    Json {
        /// The channel's topic.
        channel: String,
        /// The serialiser's message.
        message: String,
    },
    /// The schema text is not valid JSON.
    #[error("recording: schema {schema}: not valid JSON: {message}")]
    BadSchema {
        /// The schema name.
        schema: String,
        /// The parser's message.
        message: String,
    },
    /// The channel id does not belong to this recorder.
    #[error("recording: unknown channel {0}")]
    UnknownChannel(u16),
    /// `finish` was already called.
    #[error("recording: already finished")]
    Finished,
}

fn mcap_err(e: mcap::McapError) -> RecordingError {
    RecordingError::Mcap(e.to_string())
}

/// Where a recording goes: a file, memory (for tests), or a crash-safe file.
enum Sink {
    File(BufWriter<File>),
    Memory(Cursor<Vec<u8>>),
    CrashSafe(CrashSafeFile),
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Sink::File(f) => f.write(buf),
            Sink::Memory(m) => m.write(buf),
            Sink::CrashSafe(c) => {
                c.pending.extend_from_slice(buf);
                Ok(buf.len())
            }
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Sink::File(f) => f.flush(),
            Sink::Memory(m) => m.flush(),
            Sink::CrashSafe(c) => c.write_out(),
        }
    }
}

impl Seek for Sink {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        match self {
            Sink::File(f) => f.seek(pos),
            Sink::Memory(m) => m.seek(pos),
            // Written with seeking disabled: only the position is ever asked for.
            Sink::CrashSafe(c) => match pos {
                std::io::SeekFrom::Current(0) => Ok(c.end + c.pending.len() as u64),
                _ => Err(std::io::Error::new(
                    std::io::ErrorKind::Unsupported,
                    "crash-safe recording: seeking is disabled",
                )),
            },
        }
    }
}

/// The end of a valid MCAP file with no summary section: a DataEnd record (data CRC 0: not
/// computed), a Footer record (summary start 0: no summary; CRC 0) and the closing magic.
const TRAILER: [u8; 50] = {
    let mut t = [0u8; 50];
    // DataEnd: opcode 0x0F, record length 4 (u64 LE), data_section_crc 0.
    t[0] = 0x0F;
    t[1] = 4;
    // Footer at 13: opcode 0x02, record length 20, summary_start 0, summary_offset_start 0,
    // summary_crc 0.
    t[13] = 0x02;
    t[14] = 20;
    // Magic at 42.
    let magic = *b"\x89MCAP0\r\n";
    let mut i = 0;
    while i < 8 {
        t[42 + i] = magic[i];
        i += 1;
    }
    t
};

/// A recording file that is a valid MCAP file after every checkpoint: the MCAP writer's bytes
/// collect in memory (chunks are built whole, seeking disabled), and each checkpoint appends
/// them to the file followed by [`TRAILER`] in one write, then steps back over the trailer so
/// the next checkpoint overwrites it. A process killed between checkpoints leaves a file that
/// every MCAP reader opens (no summary section: readers scan it), missing only what came after
/// the last checkpoint.
struct CrashSafeFile {
    file: File,
    /// Bytes of MCAP data in the file (the trailer, if any, lies after them).
    end: u64,
    pending: Vec<u8>,
    /// The next flush is a checkpoint (append the trailer); otherwise the final write. Set by
    /// [`Recorder::checkpoint`], which cannot reach the sink inside the MCAP writer.
    checkpoint: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl CrashSafeFile {
    fn write_out(&mut self) -> std::io::Result<()> {
        let data = self.pending.len() as u64;
        let checkpoint = self.checkpoint.load(std::sync::atomic::Ordering::Relaxed);
        if checkpoint {
            self.pending.extend_from_slice(&TRAILER);
        }
        self.file.seek(std::io::SeekFrom::Start(self.end))?;
        self.file.write_all(&self.pending)?;
        self.end += data;
        self.pending.clear();
        if !checkpoint {
            // The final summary and footer replaced the trailer; nothing may follow them.
            self.file.set_len(self.end)?;
        }
        Ok(())
    }
}

/// An MCAP writer of JSON messages.
pub struct Recorder {
    writer: Option<mcap::Writer<Sink>>,
    topics: Vec<(u16, String, u32)>,
    buffer: Vec<u8>,
    path: String,
    /// Set for a crash-safe recording ([`Recorder::create_crash_safe`]).
    checkpoint_flag: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .field("channels", &self.topics.len())
            .finish()
    }
}

/// The library string stored in the MCAP header: fixed, so the bytes do not depend on
/// the mcap crate's version.
const LIBRARY: &str = "h4-teleop";

/// Uncompressed size of one chunk, bytes: about a quarter of a second of a process's 1 kHz
/// records, so a killed process loses at most that much.
const CHUNK_BYTES: u64 = 256 * 1024;

impl Recorder {
    /// Creates (or truncates) the file at `path`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let file = File::create(path).map_err(|source| RecordingError::Io {
            path: name.clone(),
            source,
        })?;
        Self::to_sink(Sink::File(BufWriter::new(file)), name)
    }

    /// A recorder writing into memory; [`Recorder::finish_into_bytes`] returns the file.
    pub fn in_memory() -> Result<Self, RecordingError> {
        Self::to_sink(
            Sink::Memory(Cursor::new(Vec::new())),
            "<memory>".to_string(),
        )
    }

    /// Creates (or truncates) a crash-safe recording at `path`: nothing reaches the file
    /// between [`Recorder::checkpoint`]s, and after each the file is a complete MCAP file
    /// (without a summary section until [`Recorder::finish`]). A process killed at any moment
    /// leaves a file every MCAP reader opens, missing what was written after the last
    /// checkpoint. Used by the processes' recordings ([`BackgroundRecorder`]).
    pub fn create_crash_safe(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let file = File::create(path).map_err(|source| RecordingError::Io {
            path: name.clone(),
            source,
        })?;
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let sink = Sink::CrashSafe(CrashSafeFile {
            file,
            end: 0,
            pending: Vec::with_capacity(2 * CHUNK_BYTES as usize),
            checkpoint: std::sync::Arc::clone(&flag),
        });
        let mut rec = Self::to_sink(sink, name)?;
        rec.checkpoint_flag = Some(flag);
        rec.checkpoint()?;
        Ok(rec)
    }

    /// Ends the current chunk and, for a crash-safe recording, writes everything so far to
    /// the file as a complete MCAP file (one write). For other recordings: ends the chunk
    /// and flushes.
    pub fn checkpoint(&mut self) -> Result<(), RecordingError> {
        use std::sync::atomic::Ordering;
        let path = self.path.clone();
        let writer = self.writer.as_mut().ok_or(RecordingError::Finished)?;
        if let Some(f) = &self.checkpoint_flag {
            f.store(true, Ordering::Relaxed);
        }
        let result = writer.flush();
        if let Some(f) = &self.checkpoint_flag {
            f.store(false, Ordering::Relaxed);
        }
        result.map_err(|e| match e {
            mcap::McapError::Io(source) => RecordingError::Io { path, source },
            e => mcap_err(e),
        })
    }

    fn to_sink(sink: Sink, path: String) -> Result<Self, RecordingError> {
        // zstd chunks of at most CHUNK_BYTES of messages, compressed in the writer's own thread
        // (no compression workers beside the 1 kHz loops); docs/processes.md, "Faults and
        // safe states", "Recordings: size and write cost".
        // A crash-safe file builds each chunk in memory (no seeking back into the file).
        let crash_safe = matches!(sink, Sink::CrashSafe(_));
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            .chunk_size(Some(CHUNK_BYTES))
            .disable_seeking(crash_safe)
            .profile("")
            .library(LIBRARY);
        let writer = options.create(sink).map_err(mcap_err)?;
        Ok(Recorder {
            writer: Some(writer),
            topics: Vec::new(),
            buffer: Vec::with_capacity(1024),
            path,
            checkpoint_flag: None,
        })
    }

    /// Adds a channel on `topic` whose messages are JSON objects described by
    /// `json_schema` (a JSON Schema document, as text) under the name `schema_name`.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        json_schema: &str,
    ) -> Result<ChannelId, RecordingError> {
        serde_json::from_str::<serde_json::Value>(json_schema).map_err(|e| {
            RecordingError::BadSchema {
                schema: schema_name.to_string(),
                message: e.to_string(),
            }
        })?;
        let writer = self.writer.as_mut().ok_or(RecordingError::Finished)?;
        let schema_id = writer
            .add_schema(schema_name, "jsonschema", json_schema.as_bytes())
            .map_err(mcap_err)?;
        let id = writer
            .add_channel(schema_id, topic, "json", &BTreeMap::new())
            .map_err(mcap_err)?;
        self.topics.push((id, topic.to_string(), 0));
        Ok(ChannelId(id))
    }

    /// Adds a channel on `topic` whose messages are `T` serialised as JSON, with the JSON
    /// Schema generated from `T` itself (so the schema always declares the fields, their types
    /// and which are required) under the name `schema_name`. Distinct shapes get distinct names.
    pub fn add_channel_for<T: schemars::JsonSchema>(
        &mut self,
        topic: &str,
        schema_name: &str,
    ) -> Result<ChannelId, RecordingError> {
        let schema = json_schema_for::<T>(schema_name)?;
        self.add_channel(topic, schema_name, &schema)
    }

    /// Writes one message, timestamped `log_time_ns` (log and publish time).
    pub fn write<T: Serialize>(
        &mut self,
        channel: ChannelId,
        log_time_ns: u64,
        message: &T,
    ) -> Result<(), RecordingError> {
        let writer = self.writer.as_mut().ok_or(RecordingError::Finished)?;
        let entry = self
            .topics
            .iter_mut()
            .find(|(id, _, _)| *id == channel.0)
            .ok_or(RecordingError::UnknownChannel(channel.0))?;
        self.buffer.clear();
        serde_json::to_writer(&mut self.buffer, message).map_err(|e| RecordingError::Json {
            channel: entry.1.clone(),
            message: e.to_string(),
        })?;
        let header = mcap::records::MessageHeader {
            channel_id: channel.0,
            sequence: entry.2,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        entry.2 = entry.2.wrapping_add(1);
        writer
            .write_to_known_channel(&header, &self.buffer)
            .map_err(mcap_err)
    }

    /// Adds a channel of messages encoded elsewhere ([`EncodedChannel`]: e.g. ROS 2 CDR
    /// with a `ros2msg` schema); its messages are written with [`Recorder::write_encoded`].
    pub fn add_encoded_channel(&mut self, c: &EncodedChannel) -> Result<ChannelId, RecordingError> {
        let writer = self.writer.as_mut().ok_or(RecordingError::Finished)?;
        let schema_id = writer
            .add_schema(&c.schema_name, &c.schema_encoding, c.schema_data.as_bytes())
            .map_err(mcap_err)?;
        let id = writer
            .add_channel(schema_id, &c.topic, &c.message_encoding, &BTreeMap::new())
            .map_err(mcap_err)?;
        self.topics.push((id, c.topic.clone(), 0));
        Ok(ChannelId(id))
    }

    /// Writes one already encoded message, timestamped `log_time_ns` (log and publish time).
    pub fn write_encoded(
        &mut self,
        channel: ChannelId,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        let writer = self.writer.as_mut().ok_or(RecordingError::Finished)?;
        let entry = self
            .topics
            .iter_mut()
            .find(|(id, _, _)| *id == channel.0)
            .ok_or(RecordingError::UnknownChannel(channel.0))?;
        let header = mcap::records::MessageHeader {
            channel_id: channel.0,
            sequence: entry.2,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        entry.2 = entry.2.wrapping_add(1);
        writer
            .write_to_known_channel(&header, data)
            .map_err(mcap_err)
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<(), RecordingError> {
        let mut writer = self.writer.take().ok_or(RecordingError::Finished)?;
        writer.finish().map_err(mcap_err)?;
        let mut sink = writer.into_inner();
        sink.flush().map_err(|source| RecordingError::Io {
            path: self.path.clone(),
            source,
        })
    }

    /// For [`Recorder::in_memory`]: finishes and returns the file's bytes (empty for a
    /// file recorder, whose bytes are on disk).
    pub fn finish_into_bytes(mut self) -> Result<Vec<u8>, RecordingError> {
        let mut writer = self.writer.take().ok_or(RecordingError::Finished)?;
        writer.finish().map_err(mcap_err)?;
        match writer.into_inner() {
            Sink::Memory(m) => Ok(m.into_inner()),
            mut sink => {
                sink.flush().map_err(|source| RecordingError::Io {
                    path: self.path.clone(),
                    source,
                })?;
                Ok(Vec::new())
            }
        }
    }
}

/// What [`merge`] wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MergeStats {
    /// Messages written, per topic, in topic order.
    pub messages_by_topic: BTreeMap<String, u64>,
    /// Per input: messages taken from it.
    pub messages_by_input: Vec<u64>,
    /// Per input: the last message's log time, ns (0: none).
    pub last_log_time_ns: Vec<u64>,
    /// Per input: it ended properly (a summary section: the writer finished it); false for
    /// the file of a process that was killed (crash-safe files end at their last checkpoint).
    pub complete: Vec<bool>,
    /// Per input: its tail could not be read (a torn last write); what came before is merged.
    pub unreadable_tail: Vec<bool>,
}

/// Merges MCAP files into one at `out`: every channel of every input (with its schema), and
/// every message in log-time order (ties keep the inputs' order). The inputs must share a time
/// base, e.g. the Unix-time stamps of the process recordings
/// ([`h4_shared::clock::MonotonicClock::unix_ns`]).
pub fn merge(inputs: &[&Path], out: &Path) -> Result<MergeStats, RecordingError> {
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| RecordingError::Io { path, source }
    };
    let mut files = Vec::with_capacity(inputs.len());
    for path in inputs {
        files.push(std::fs::read(path).map_err(io(path))?);
    }
    let mut streams = Vec::with_capacity(files.len());
    for bytes in &files {
        streams.push(
            mcap::MessageStream::new(bytes)
                .map_err(mcap_err)?
                .peekable(),
        );
    }
    let mut rec = Recorder::create(out)?;
    let writer = rec.writer.as_mut().ok_or(RecordingError::Finished)?;
    let mut channels: BTreeMap<(usize, u16), (u16, String)> = BTreeMap::new();
    let mut sequence: BTreeMap<u16, u32> = BTreeMap::new();
    let n = files.len();
    let mut stats = MergeStats {
        messages_by_input: vec![0; n],
        last_log_time_ns: vec![0; n],
        complete: files
            .iter()
            .map(|b| matches!(mcap::Summary::read(b), Ok(Some(_))))
            .collect(),
        unreadable_tail: vec![false; n],
        ..MergeStats::default()
    };
    let mut ended = vec![false; n];
    loop {
        // The input whose next message is the earliest; an input whose next record cannot be
        // read (a torn tail) ends there.
        let mut earliest: Option<(usize, u64)> = None;
        for (i, s) in streams.iter_mut().enumerate() {
            if ended.get(i).copied().unwrap_or(true) {
                continue;
            }
            match s.peek() {
                Some(Ok(m)) if earliest.is_none_or(|(_, t)| m.log_time < t) => {
                    earliest = Some((i, m.log_time));
                }
                Some(Err(_)) => {
                    ended[i] = true;
                    stats.unreadable_tail[i] = true;
                }
                _ => {}
            }
        }
        let Some((i, _)) = earliest else { break };
        let Some(Ok(m)) = streams.get_mut(i).and_then(Iterator::next) else {
            break;
        };
        let key = (i, m.channel.id);
        let id = match channels.get(&key) {
            Some((id, _)) => *id,
            None => {
                let schema_id = match &m.channel.schema {
                    Some(s) => writer
                        .add_schema(&s.name, &s.encoding, &s.data)
                        .map_err(mcap_err)?,
                    None => 0,
                };
                let id = writer
                    .add_channel(
                        schema_id,
                        &m.channel.topic,
                        &m.channel.message_encoding,
                        &m.channel.metadata,
                    )
                    .map_err(mcap_err)?;
                channels.insert(key, (id, m.channel.topic.clone()));
                id
            }
        };
        let seq = sequence.entry(id).or_insert(0);
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: *seq,
            log_time: m.log_time,
            publish_time: m.publish_time,
        };
        *seq = seq.wrapping_add(1);
        writer
            .write_to_known_channel(&header, &m.data)
            .map_err(mcap_err)?;
        if let Some((_, topic)) = channels.get(&key) {
            *stats.messages_by_topic.entry(topic.clone()).or_insert(0) += 1;
        }
        stats.messages_by_input[i] += 1;
        stats.last_log_time_ns[i] = m.log_time;
    }
    rec.finish()?;
    Ok(stats)
}

/// The JSON Schema of `T` as text, generated from the type (fields, their types, which are
/// required, their doc comments as descriptions); `schema_name` names it in errors. The same
/// type gives the same text.
pub fn json_schema_for<T: schemars::JsonSchema>(
    schema_name: &str,
) -> Result<String, RecordingError> {
    let schema = schemars::schema_for!(T);
    serde_json::to_string(&schema).map_err(|e| RecordingError::BadSchema {
        schema: schema_name.to_string(),
        message: e.to_string(),
    })
}

/// How often a [`BackgroundRecorder`] makes its file complete on disk
/// ([`Recorder::checkpoint`]): a process killed at any moment loses at most this much of its
/// recording (plus the records still queued).
pub const CHECKPOINT_INTERVAL: std::time::Duration = std::time::Duration::from_millis(500);

/// A recording written by its own thread: a control loop hands it one `Copy` record per cycle
/// through a bounded queue (no allocation, no blocking; a full queue drops the record and
/// counts it), and the thread does the JSON encoding and the file writes. The file is
/// crash-safe ([`Recorder::create_crash_safe`]), checkpointed every [`CHECKPOINT_INTERVAL`].
/// A second channel of another record type `U` is optional
/// ([`BackgroundRecorder::start_two_for`], [`BackgroundRecorder::push_second`]).
pub struct BackgroundRecorder<T: Send + 'static, U: Send + 'static = ()> {
    tx: Option<std::sync::mpsc::SyncSender<(u64, Either<T, U>)>>,
    handle: Option<std::thread::JoinHandle<Result<(), String>>>,
    dropped: u64,
}

/// A channel whose messages arrive already encoded, with its schema as text: e.g. a ROS 2
/// topic (`message_encoding` `cdr`, `schema_encoding` `ros2msg`, `schema_name`
/// `geometry_msgs/msg/PoseStamped`, `schema_data` the complete `.msg` definition).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EncodedChannel {
    /// The topic, e.g. `/h4/measured_cp`.
    pub topic: String,
    /// The schema's name.
    pub schema_name: String,
    /// The schema's encoding, e.g. `ros2msg`.
    pub schema_encoding: String,
    /// The schema itself.
    pub schema_data: String,
    /// The messages' encoding, e.g. `cdr`.
    pub message_encoding: String,
}

/// Writes `(channel index, log time ns, message)`; the index is into
/// [`PolledChannels::channels`].
pub type PolledWrite<'a> = dyn FnMut(usize, u64, &[u8]) + 'a;

/// Channels a [`BackgroundRecorder`]'s own thread fills by polling, every `period`, a source
/// another thread keeps up to date (the ROS 2 CRTK topics, sampled from the cell the 1 kHz
/// loop writes: the loop does nothing more for them). `poll` is called on the recording
/// thread and hands each new message to the writer it is given.
pub struct PolledChannels {
    /// The channels.
    pub channels: Vec<EncodedChannel>,
    /// How often `poll` is called.
    pub period: std::time::Duration,
    /// Takes what is new since the last call.
    pub poll: Box<dyn FnMut(&mut PolledWrite<'_>) + Send>,
}

impl std::fmt::Debug for PolledChannels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PolledChannels")
            .field("channels", &self.channels)
            .field("period", &self.period)
            .finish()
    }
}

/// A queued record of either channel.
enum Either<T, U> {
    First(T),
    Second(U),
}

/// A channel's topic, schema name and JSON schema.
struct ChannelSpec<'a> {
    topic: &'a str,
    schema_name: &'a str,
    json_schema: String,
}

/// One poll of `p` on the recording thread: writes what it hands out on the channels `ids`
/// (the first error ends the recording, as for the queued records).
fn poll_into(rec: &mut Recorder, p: &mut PolledChannels, ids: &[ChannelId]) -> Result<(), String> {
    let mut result = Ok(());
    (p.poll)(&mut |i, time_ns, data| {
        if result.is_ok() {
            result = match ids.get(i) {
                Some(&ch) => rec.write_encoded(ch, time_ns, data),
                None => Err(RecordingError::UnknownChannel(
                    u16::try_from(i).unwrap_or(u16::MAX),
                )),
            };
        }
    });
    result.map_err(|e| e.to_string())
}

impl<T: Serialize + Send + 'static, U: Serialize + Send + 'static> BackgroundRecorder<T, U> {
    fn start_channels(
        path: Option<&Path>,
        first: ChannelSpec,
        second: Option<ChannelSpec>,
        polled: Option<PolledChannels>,
    ) -> Result<Self, RecordingError> {
        let Some(path) = path else {
            return Ok(BackgroundRecorder {
                tx: None,
                handle: None,
                dropped: 0,
            });
        };
        let mut rec = Recorder::create_crash_safe(path)?;
        let first = rec.add_channel(first.topic, first.schema_name, &first.json_schema)?;
        let second = match second {
            Some(c) => Some(rec.add_channel(c.topic, c.schema_name, &c.json_schema)?),
            None => None,
        };
        let mut polled = match polled {
            Some(p) => {
                let mut ids = Vec::with_capacity(p.channels.len());
                for c in &p.channels {
                    ids.push(rec.add_encoded_channel(c)?);
                }
                Some((p, ids, std::time::Instant::now()))
            }
            None => None,
        };
        let (tx, rx) = std::sync::mpsc::sync_channel::<(u64, Either<T, U>)>(8192);
        let handle = std::thread::spawn(move || -> Result<(), String> {
            use std::sync::mpsc::RecvTimeoutError;
            let mut next = std::time::Instant::now() + CHECKPOINT_INTERVAL;
            loop {
                let until = match &polled {
                    Some((_, _, poll_at)) => next.min(*poll_at),
                    None => next,
                };
                let wait = until.saturating_duration_since(std::time::Instant::now());
                let received = rx.recv_timeout(wait);
                if let Some((p, ids, poll_at)) = &mut polled
                    && (std::time::Instant::now() >= *poll_at
                        || matches!(received, Err(RecvTimeoutError::Disconnected)))
                {
                    poll_into(&mut rec, p, ids)?;
                    *poll_at = (*poll_at + p.period).max(std::time::Instant::now());
                }
                match received {
                    Ok((time_ns, Either::First(item))) => rec
                        .write(first, time_ns, &item)
                        .map_err(|e| e.to_string())?,
                    Ok((time_ns, Either::Second(item))) => {
                        if let Some(ch) = second {
                            rec.write(ch, time_ns, &item).map_err(|e| e.to_string())?;
                        }
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
                if std::time::Instant::now() >= next {
                    rec.checkpoint().map_err(|e| e.to_string())?;
                    next = std::time::Instant::now() + CHECKPOINT_INTERVAL;
                }
            }
            rec.finish().map_err(|e| e.to_string())
        });
        Ok(BackgroundRecorder {
            tx: Some(tx),
            handle: Some(handle),
            dropped: 0,
        })
    }

    /// Starts a recorder writing one channel to `path`; with `None`, records are discarded.
    pub fn start(
        path: Option<&Path>,
        topic: &str,
        schema_name: &str,
        json_schema: &str,
    ) -> Result<Self, RecordingError> {
        let first = ChannelSpec {
            topic,
            schema_name,
            json_schema: json_schema.to_string(),
        };
        Self::start_channels(path, first, None, None)
    }

    /// [`BackgroundRecorder::start`] with the schema generated from `T`
    /// ([`json_schema_for`]).
    pub fn start_for(
        path: Option<&Path>,
        topic: &str,
        schema_name: &str,
    ) -> Result<Self, RecordingError>
    where
        T: schemars::JsonSchema,
    {
        let schema = json_schema_for::<T>(schema_name)?;
        Self::start(path, topic, schema_name, &schema)
    }

    /// A recorder of two channels, `T`'s on `topic` and, when `second` names one
    /// (`(topic, schema name)`), `U`'s, the schemas generated from the types; with `path`
    /// `None`, records are discarded.
    pub fn start_two_for(
        path: Option<&Path>,
        topic: &str,
        schema_name: &str,
        second: Option<(&str, &str)>,
    ) -> Result<Self, RecordingError>
    where
        T: schemars::JsonSchema,
        U: schemars::JsonSchema,
    {
        Self::start_two_for_polled(path, topic, schema_name, second, None)
    }

    /// [`BackgroundRecorder::start_two_for`] with `polled`'s channels too (written by the
    /// recording thread itself, [`PolledChannels`]).
    pub fn start_two_for_polled(
        path: Option<&Path>,
        topic: &str,
        schema_name: &str,
        second: Option<(&str, &str)>,
        polled: Option<PolledChannels>,
    ) -> Result<Self, RecordingError>
    where
        T: schemars::JsonSchema,
        U: schemars::JsonSchema,
    {
        let first = ChannelSpec {
            topic,
            schema_name,
            json_schema: json_schema_for::<T>(schema_name)?,
        };
        let second = match second {
            Some((topic, schema_name)) => Some(ChannelSpec {
                topic,
                schema_name,
                json_schema: json_schema_for::<U>(schema_name)?,
            }),
            None => None,
        };
        Self::start_channels(path, first, second, polled)
    }

    /// Queues one record stamped `time_ns`; never blocks.
    pub fn push(&mut self, time_ns: u64, item: T) {
        self.send(time_ns, Either::First(item));
    }

    /// Queues one record of the second channel stamped `time_ns` (discarded by the writer
    /// when the recorder has no second channel); never blocks.
    pub fn push_second(&mut self, time_ns: u64, item: U) {
        self.send(time_ns, Either::Second(item));
    }

    fn send(&mut self, time_ns: u64, item: Either<T, U>) {
        if let Some(tx) = &self.tx
            && tx.try_send((time_ns, item)).is_err()
        {
            self.dropped += 1;
        }
    }

    /// Records dropped because the writer fell behind.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Closes the queue, waits for the writer and closes the file.
    pub fn finish(mut self) -> Result<(), String> {
        self.tx = None;
        match self.handle.take() {
            Some(h) => h
                .join()
                .map_err(|_| "recording thread panicked".to_string())?,
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Sample {
        t: f64,
    }

    #[derive(Serialize, schemars::JsonSchema)]
    struct Typed {
        /// Force, N.
        force_n: f64,
        count: u64,
    }

    #[test]
    fn typed_channel_schema_declares_the_fields_as_required() {
        let mut rec = Recorder::in_memory().unwrap();
        let ch = rec.add_channel_for::<Typed>("/t", "h4.Typed").unwrap();
        rec.write(
            ch,
            1,
            &Typed {
                force_n: 1.5,
                count: 2,
            },
        )
        .unwrap();
        let bytes = rec.finish_into_bytes().unwrap();
        let msg = mcap::MessageStream::new(&bytes)
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        let schema = msg.channel.schema.as_ref().unwrap();
        assert_eq!(schema.name, "h4.Typed");
        let v: serde_json::Value = serde_json::from_slice(&schema.data).unwrap();
        assert_eq!(v["properties"]["force_n"]["type"], "number");
        let required: Vec<&str> = v["required"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_str().unwrap())
            .collect();
        assert_eq!(required, ["force_n", "count"]);
    }

    /// Topics and counts of the messages in an MCAP file.
    fn topic_counts(path: &Path) -> std::collections::BTreeMap<String, usize> {
        let bytes = std::fs::read(path).unwrap();
        let mut counts = std::collections::BTreeMap::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            *counts.entry(m.unwrap().channel.topic.clone()).or_insert(0) += 1;
        }
        counts
    }

    /// A background recorder's second channel gets its records, in the same file; without
    /// a second channel they are discarded.
    #[test]
    fn background_recorder_writes_a_second_channel_or_discards_it() {
        let dir = std::env::temp_dir().join(format!("h4-two-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, second) in [("two.mcap", Some(("/b", "h4.B"))), ("one.mcap", None)] {
            let path = dir.join(name);
            let mut rec = BackgroundRecorder::<Typed, Typed>::start_two_for(
                Some(&path),
                "/a",
                "h4.A",
                second,
            )
            .unwrap();
            for i in 0..30u64 {
                let t = Typed {
                    force_n: i as f64,
                    count: i,
                };
                rec.push(i, t);
                if i % 3 == 0 {
                    rec.push_second(
                        i,
                        Typed {
                            force_n: 0.0,
                            count: i,
                        },
                    );
                }
            }
            assert_eq!(rec.dropped(), 0);
            rec.finish().unwrap();
            let counts = topic_counts(&path);
            let want: std::collections::BTreeMap<String, usize> = match second {
                Some(_) => [("/a".to_string(), 30), ("/b".to_string(), 10)].into(),
                None => [("/a".to_string(), 30)].into(),
            };
            assert_eq!(counts, want, "{name}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn record() -> Vec<u8> {
        let mut rec = Recorder::in_memory().unwrap();
        let ch = rec
            .add_channel(
                "/a",
                "A",
                r#"{"type":"object","properties":{"t":{"type":"number"}}}"#,
            )
            .unwrap();
        for i in 0..100u64 {
            rec.write(ch, i * 1_000_000, &Sample { t: i as f64 })
                .unwrap();
        }
        rec.finish_into_bytes().unwrap()
    }

    #[test]
    fn same_input_same_bytes_and_valid_mcap() {
        let a = record();
        let b = record();
        assert_eq!(a, b);
        assert!(a.starts_with(b"\x89MCAP0\r\n"));
        let messages: Vec<_> = mcap::MessageStream::new(&a).unwrap().collect();
        assert_eq!(messages.len(), 100);
        let m = messages[7].as_ref().unwrap();
        assert_eq!(m.log_time, 7_000_000);
        assert_eq!(&m.data[..], br#"{"t":7.0}"#);
        assert_eq!(m.channel.topic, "/a");
    }

    #[test]
    fn merge_interleaves_channels_in_log_time_order() {
        let dir = std::env::temp_dir().join(format!("h4-merge-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, topic: &str, times: &[u64]| {
            let path = dir.join(name);
            let mut rec = Recorder::create(&path).unwrap();
            let ch = rec
                .add_channel(topic, topic, r#"{"type":"object"}"#)
                .unwrap();
            for &t in times {
                rec.write(ch, t, &Sample { t: t as f64 }).unwrap();
            }
            rec.finish().unwrap();
            path
        };
        let a = write("a.mcap", "/a", &[1, 3, 5, 7]);
        let b = write("b.mcap", "/b", &[2, 3, 4, 8, 9]);
        let out = dir.join("out.mcap");
        let stats = merge(&[&a, &b], &out).unwrap();
        assert_eq!(stats.messages_by_topic.get("/a"), Some(&4));
        assert_eq!(stats.messages_by_topic.get("/b"), Some(&5));
        let bytes = std::fs::read(&out).unwrap();
        let got: Vec<(String, u64)> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| {
                let m = m.unwrap();
                (m.channel.topic.clone(), m.log_time)
            })
            .collect();
        let times: Vec<u64> = got.iter().map(|g| g.1).collect();
        assert_eq!(times, vec![1, 2, 3, 3, 4, 5, 7, 8, 9]);
        // The tie at t = 3 keeps the inputs' order; each message keeps its channel.
        assert_eq!(got[2], ("/a".to_string(), 3));
        assert_eq!(got[3], ("/b".to_string(), 3));
        assert!(got.iter().all(|(topic, t)| {
            let from_a = [1, 3, 5, 7].contains(t) && topic == "/a";
            let from_b = [2, 3, 4, 8, 9].contains(t) && topic == "/b";
            from_a || from_b
        }));
        // A missing input is an error naming it, and nothing panics.
        let missing = dir.join("missing.mcap");
        let err = merge(&[&a, &missing], &dir.join("x.mcap")).unwrap_err();
        assert!(err.to_string().contains("missing.mcap"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_crash_safe_recording_killed_between_checkpoints_is_valid_up_to_the_last_one() {
        let dir = std::env::temp_dir().join(format!("h4-crashsafe-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("killed.mcap");
        let mut rec = Recorder::create_crash_safe(&path).unwrap();
        let ch = rec.add_channel("/a", "A", r#"{"type":"object"}"#).unwrap();
        // Valid from the start: an empty recording.
        let empty = std::fs::read(&path).unwrap();
        assert_eq!(mcap::MessageStream::new(&empty).unwrap().count(), 0);
        for i in 0..300u64 {
            rec.write(ch, i, &Sample { t: i as f64 }).unwrap();
            if i == 99 || i == 199 {
                rec.checkpoint().unwrap();
            }
        }
        // "Killed": never finished, nothing after the second checkpoint reaches the file.
        std::mem::forget(rec);
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.ends_with(b"\x89MCAP0\r\n"));
        let times: Vec<u64> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap().log_time)
            .collect();
        assert_eq!(times, (0..200).collect::<Vec<u64>>());
        // Finished normally, the same kind of file is an ordinary MCAP file with a summary.
        let done = dir.join("done.mcap");
        let mut rec = Recorder::create_crash_safe(&done).unwrap();
        let ch = rec.add_channel("/a", "A", r#"{"type":"object"}"#).unwrap();
        for i in 0..50u64 {
            rec.write(ch, i, &Sample { t: i as f64 }).unwrap();
            if i % 20 == 0 {
                rec.checkpoint().unwrap();
            }
        }
        rec.finish().unwrap();
        let bytes = std::fs::read(&done).unwrap();
        assert_eq!(mcap::MessageStream::new(&bytes).unwrap().count(), 50);
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert_eq!(summary.stats.unwrap().message_count, 50);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_schema_and_unknown_channel_are_errors() {
        let mut rec = Recorder::in_memory().unwrap();
        assert!(matches!(
            rec.add_channel("/a", "A", "{not json"),
            Err(RecordingError::BadSchema { .. })
        ));
        assert!(matches!(
            rec.write(ChannelId(42), 0, &Sample { t: 0.0 }),
            Err(RecordingError::UnknownChannel(42))
        ));
    }

    /// A polled channel: written by the recording thread with its schema's and messages'
    /// encodings as given, each message once per poll that has one, beside the queued JSON
    /// records. Control: a recording without it has only the JSON channel.
    #[test]
    fn polled_channels_are_written_by_the_recording_thread() {
        let dir = std::env::temp_dir().join(format!("h4-polled-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("polled.mcap");
        let mut left = 3u64;
        let polled = PolledChannels {
            channels: vec![EncodedChannel {
                topic: "/h4/measured_cp".into(),
                schema_name: "geometry_msgs/msg/PoseStamped".into(),
                schema_encoding: "ros2msg".into(),
                schema_data: "std_msgs/Header header\n".into(),
                message_encoding: "cdr".into(),
            }],
            period: std::time::Duration::from_millis(1),
            poll: Box::new(move |write| {
                if left > 0 {
                    write(0, 100 - left, &[0, 1, 0, 0, left as u8]);
                    left -= 1;
                }
            }),
        };
        let mut rec = BackgroundRecorder::<Typed>::start_two_for_polled(
            Some(&path),
            "/a",
            "A",
            None,
            Some(polled),
        )
        .unwrap();
        rec.push(
            5,
            Typed {
                force_n: 1.0,
                count: 1,
            },
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
        rec.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(Result::unwrap)
            .collect();
        let ros: Vec<_> = msgs
            .iter()
            .filter(|m| m.channel.topic == "/h4/measured_cp")
            .collect();
        assert_eq!(ros.len(), 3);
        assert_eq!(ros[0].channel.message_encoding, "cdr");
        let schema = ros[0].channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "ros2msg");
        assert_eq!(schema.name, "geometry_msgs/msg/PoseStamped");
        assert_eq!(&schema.data[..], b"std_msgs/Header header\n");
        assert_eq!(
            ros.iter().map(|m| m.log_time).collect::<Vec<_>>(),
            [97, 98, 99]
        );
        assert_eq!(&ros[2].data[..], &[0, 1, 0, 0, 1]);
        assert_eq!(msgs.iter().filter(|m| m.channel.topic == "/a").count(), 1);
        // Control: without the polled channels, only the JSON one.
        let plain = dir.join("plain.mcap");
        let mut rec = BackgroundRecorder::<Typed>::start_for(Some(&plain), "/a", "A").unwrap();
        rec.push(
            5,
            Typed {
                force_n: 1.0,
                count: 1,
            },
        );
        rec.finish().unwrap();
        let bytes = std::fs::read(&plain).unwrap();
        let topics: Vec<String> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap().channel.topic.clone())
            .collect();
        assert_eq!(topics, ["/a"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
