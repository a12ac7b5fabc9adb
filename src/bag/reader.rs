//! Reading rosbag2 bags: a lone `.mcap` file, a lone `.db3` file, or a rosbag2 directory
//! (`metadata.yaml` + its MCAP or sqlite3 files, optionally zstd-compressed per file or per
//! message). MCAP is read as a stream (the `mcap` crate's sans-io reader: plain, zstd and lz4
//! chunks) so memory stays bounded by one chunk; sqlite3 through `rusqlite`, in timestamp order.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::schemas::normalise_type;
use super::BagError;

/// One serialised message of a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct BagMessage {
    pub topic: String,
    /// `pkg/msg/Name`.
    pub msg_type: String,
    /// Receive time at the recorder, nanoseconds since the epoch.
    pub log_time_ns: u64,
    pub publish_time_ns: u64,
    /// CDR bytes (with the 4-byte encapsulation header), as recorded.
    pub data: Vec<u8>,
}

/// A topic of a bag, as its index or metadata describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    pub name: String,
    pub msg_type: String,
    /// Serialisation (`cdr` for ROS 2).
    pub encoding: String,
    /// Message count when the bag's summary or metadata says it.
    pub count: Option<u64>,
    /// The schema (definition text) when the bag carries one.
    pub schema: Option<Vec<u8>>,
}

/// Reads the messages of one bag in order (file order for MCAP, which rosbag2 writes in
/// receive order; timestamp order for sqlite3).
pub struct BagReader {
    path: PathBuf,
    sources: Vec<PathBuf>,
    next_source: usize,
    current: Option<Source>,
    topics: Vec<TopicInfo>,
    message_zstd: bool,
    /// Decompressed copies of FILE-compressed storage files, removed on drop.
    temp_files: Vec<PathBuf>,
    file_zstd: bool,
    failed: bool,
}

enum Source {
    Mcap(Box<McapSource>),
    Sqlite(Box<SqliteSource>),
}

impl BagReader {
    /// Opens `path`: a `.mcap` or `.db3` file, or a rosbag2 directory.
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let meta = std::fs::metadata(path).map_err(|e| BagError::io(path, e))?;
        let mut reader = Self {
            path: path.to_path_buf(),
            sources: Vec::new(),
            next_source: 0,
            current: None,
            topics: Vec::new(),
            message_zstd: false,
            temp_files: Vec::new(),
            file_zstd: false,
            failed: false,
        };
        if meta.is_dir() {
            let metadata = Metadata::read(path)?;
            reader.topics = metadata.topics;
            reader.message_zstd = metadata.message_zstd;
            reader.file_zstd = metadata.file_zstd;
            reader.sources = metadata.files;
            if reader.sources.is_empty() {
                return Err(BagError::Format {
                    path: path.join("metadata.yaml"),
                    reason: "relative_file_paths lists no storage files".into(),
                });
            }
        } else {
            reader.sources = vec![path.to_path_buf()];
        }
        // Topics and counts from the storage files' own indexes where metadata lacked them.
        if reader.topics.is_empty() && !reader.file_zstd {
            let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
            for file in &reader.sources {
                let found = match storage_kind(file)? {
                    StorageKind::Mcap => mcap_summary_topics(file)?,
                    StorageKind::Sqlite => SqliteSource::open(file, 0)?.topic_infos(),
                };
                for t in found {
                    topics
                        .entry(t.name.clone())
                        .and_modify(|e| {
                            e.count = match (e.count, t.count) {
                                (Some(a), Some(b)) => Some(a.saturating_add(b)),
                                _ => None,
                            }
                        })
                        .or_insert(t);
                }
            }
            reader.topics = topics.into_values().collect();
        }
        Ok(reader)
    }

    /// The topics known before reading (from metadata.yaml, the MCAP summary or the sqlite
    /// topics table). A lone MCAP file without a summary lists its topics only as they appear.
    pub fn topics(&self) -> &[TopicInfo] {
        &self.topics
    }

    fn open_next(&mut self) -> Result<bool, BagError> {
        let Some(file) = self.sources.get(self.next_source).cloned() else {
            return Ok(false);
        };
        self.next_source += 1;
        let file = if self.file_zstd {
            let tmp = decompress_to_temp(&file)?;
            self.temp_files.push(tmp.clone());
            tmp
        } else {
            file
        };
        self.current = Some(match storage_kind(&file)? {
            StorageKind::Mcap => Source::Mcap(Box::new(McapSource::open(&file)?)),
            StorageKind::Sqlite => Source::Sqlite(Box::new(SqliteSource::open(&file, 256)?)),
        });
        Ok(true)
    }

    fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        loop {
            if self.current.is_none() && !self.open_next()? {
                return Ok(None);
            }
            let next = match &mut self.current {
                Some(Source::Mcap(m)) => m.next_message()?,
                Some(Source::Sqlite(s)) => s.next_message()?,
                None => None,
            };
            match next {
                Some(mut msg) => {
                    if self.message_zstd {
                        msg.data = decompress_message(&msg.data).map_err(|e| BagError::Format {
                            path: self.path.clone(),
                            reason: format!(
                                "message on {} at log time {} ns: zstd: {e}",
                                msg.topic, msg.log_time_ns
                            ),
                        })?;
                    }
                    return Ok(Some(msg));
                }
                None => self.current = None,
            }
        }
    }
}

/// A zstd-compressed message (rosbag2's per-message compression), at most
/// [`MAX_RECORD_BYTES`] once decompressed (a zstd bomb is an error, not an allocation).
fn decompress_message(data: &[u8]) -> std::io::Result<Vec<u8>> {
    let decoder = zstd::stream::Decoder::new(data)?;
    let mut out = Vec::new();
    decoder
        .take(MAX_RECORD_BYTES as u64 + 1)
        .read_to_end(&mut out)?;
    if out.len() > MAX_RECORD_BYTES {
        return Err(std::io::Error::other(format!(
            "decompresses to more than {MAX_RECORD_BYTES} bytes"
        )));
    }
    Ok(out)
}

impl Iterator for BagReader {
    type Item = Result<BagMessage, BagError>;

    /// Messages in order. A damaged part of an MCAP file yields one error and reading goes on
    /// at the next intact chunk when the file's summary lists one; any other error ends it.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match self.next_message() {
            Ok(Some(m)) => Some(Ok(m)),
            Ok(None) => None,
            Err(e) => {
                let resumable = matches!(&self.current, Some(Source::Mcap(m)) if !m.ended)
                    && matches!(e, BagError::Corrupt { .. });
                if !resumable {
                    self.failed = true;
                }
                Some(Err(e))
            }
        }
    }
}

impl Drop for BagReader {
    fn drop(&mut self) {
        for f in &self.temp_files {
            let _ = std::fs::remove_file(f);
        }
    }
}

enum StorageKind {
    Mcap,
    Sqlite,
}

/// By magic bytes, not by name.
fn storage_kind(path: &Path) -> Result<StorageKind, BagError> {
    let mut magic = [0u8; 16];
    let mut file = File::open(path).map_err(|e| BagError::io(path, e))?;
    let n = read_up_to(&mut file, &mut magic).map_err(|e| BagError::io(path, e))?;
    if n >= 8 && &magic[..8] == mcap::MAGIC {
        Ok(StorageKind::Mcap)
    } else if n >= 16 && &magic[..16] == b"SQLite format 3\0" {
        Ok(StorageKind::Sqlite)
    } else {
        Err(BagError::Format {
            path: path.to_path_buf(),
            reason: format!(
                "neither an MCAP file nor an sqlite3 database (the file starts with {:02x?})",
                &magic[..n.min(8)]
            ),
        })
    }
}

fn read_up_to(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        let k = file.read(&mut buf[n..])?;
        if k == 0 {
            break;
        }
        n += k;
    }
    Ok(n)
}

fn decompress_to_temp(path: &Path) -> Result<PathBuf, BagError> {
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("bag")
        .trim_end_matches(".zstd")
        .to_string();
    let tmp = std::env::temp_dir().join(format!("sweepdepth-{}-{name}", std::process::id()));
    let input = File::open(path).map_err(|e| BagError::io(path, e))?;
    let mut output = File::create(&tmp).map_err(|e| BagError::io(&tmp, e))?;
    zstd::stream::copy_decode(BufReader::new(input), &mut output).map_err(|e| {
        BagError::Format {
            path: path.to_path_buf(),
            reason: format!("zstd file compression: {e}"),
        }
    })?;
    Ok(tmp)
}

/// The parts of a rosbag2 `metadata.yaml` we use.
struct Metadata {
    files: Vec<PathBuf>,
    topics: Vec<TopicInfo>,
    file_zstd: bool,
    message_zstd: bool,
}

impl Metadata {
    fn read(dir: &Path) -> Result<Self, BagError> {
        let path = dir.join("metadata.yaml");
        let text = std::fs::read_to_string(&path).map_err(|e| BagError::io(&path, e))?;
        let format = |reason: String| BagError::Format {
            path: path.clone(),
            reason,
        };
        let root: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(&text).map_err(|e| format(e.to_string()))?;
        let info = root
            .get("rosbag2_bagfile_information")
            .ok_or_else(|| format("no rosbag2_bagfile_information".into()))?;
        let storage = info
            .get("storage_identifier")
            .and_then(|v| v.as_str())
            .unwrap_or("");
        if !matches!(storage, "mcap" | "sqlite3") {
            return Err(format(format!(
                "storage_identifier '{storage}' is not supported (mcap or sqlite3)"
            )));
        }
        let compression_format = info
            .get("compression_format")
            .and_then(|v| v.as_str())
            .unwrap_or("");
        let compression_mode = info
            .get("compression_mode")
            .and_then(|v| v.as_str())
            .unwrap_or("")
            .to_ascii_uppercase();
        let compressed = !compression_format.is_empty() && compression_mode != "NONE";
        if compressed && compression_format != "zstd" {
            return Err(format(format!(
                "compression_format '{compression_format}' is not supported (zstd)"
            )));
        }
        let files = info
            .get("relative_file_paths")
            .and_then(|v| v.as_sequence())
            .ok_or_else(|| format("no relative_file_paths".into()))?
            .iter()
            .filter_map(|v| v.as_str())
            .map(|p| dir.join(p))
            .collect();
        let mut topics = Vec::new();
        if let Some(list) = info
            .get("topics_with_message_count")
            .and_then(|v| v.as_sequence())
        {
            for entry in list {
                let meta = entry.get("topic_metadata");
                let field = |k: &str| {
                    meta.and_then(|m| m.get(k))
                        .and_then(|v| v.as_str())
                        .unwrap_or("")
                        .to_string()
                };
                topics.push(TopicInfo {
                    name: field("name"),
                    msg_type: normalise_type(&field("type")),
                    encoding: field("serialization_format"),
                    count: entry.get("message_count").and_then(|v| v.as_u64()),
                    schema: None,
                });
            }
        }
        Ok(Self {
            files,
            topics,
            file_zstd: compressed && compression_mode == "FILE",
            message_zstd: compressed && compression_mode == "MESSAGE",
        })
    }
}

/// `mcap::parse_record`, with a panic of the parser (mcap 0.26 slices out of range on some
/// short records) turned into an error.
fn parse_record(opcode: u8, body: &[u8]) -> mcap::McapResult<mcap::records::Record<'_>> {
    std::panic::catch_unwind(move || mcap::parse_record(opcode, body))
        .unwrap_or(Err(mcap::McapError::UnexpectedEoc))
}

/// What an MCAP file's summary section says (read from the end of the file): schemas,
/// channels, per-channel message counts and where the chunks start. Empty when the file has no
/// summary (truncated, or written without one).
#[derive(Default)]
struct McapSummary {
    schemas: HashMap<u16, (String, Vec<u8>)>,
    channels: BTreeMap<u16, (String, u16, String)>,
    counts: Option<BTreeMap<u16, u64>>,
    chunk_starts: Vec<u64>,
}

fn mcap_summary_topics(path: &Path) -> Result<Vec<TopicInfo>, BagError> {
    let summary = read_mcap_summary(path)?;
    let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
    for (id, (topic, schema_id, encoding)) in &summary.channels {
        let (name, schema) = summary
            .schemas
            .get(schema_id)
            .map(|(n, d)| (normalise_type(n), Some(d.clone())))
            .unwrap_or_default();
        let count = summary
            .counts
            .as_ref()
            .map(|c| c.get(id).copied().unwrap_or(0));
        topics
            .entry(topic.clone())
            .and_modify(|t| {
                t.count = match (t.count, count) {
                    (Some(a), Some(b)) => Some(a.saturating_add(b)),
                    _ => None,
                }
            })
            .or_insert(TopicInfo {
                name: topic.clone(),
                msg_type: name,
                encoding: encoding.clone(),
                count,
                schema,
            });
    }
    Ok(topics.into_values().collect())
}

fn read_mcap_summary(path: &Path) -> Result<McapSummary, BagError> {
    let mut file = File::open(path).map_err(|e| BagError::io(path, e))?;
    let len = file
        .seek(SeekFrom::End(0))
        .map_err(|e| BagError::io(path, e))?;
    // Footer record (opcode, length, summary_start, summary_offset_start, crc) + magic.
    const TAIL: u64 = 1 + 8 + 8 + 8 + 4 + 8;
    if len < TAIL + 8 {
        return Ok(McapSummary::default());
    }
    let mut tail = [0u8; TAIL as usize];
    file.seek(SeekFrom::Start(len - TAIL))
        .map_err(|e| BagError::io(path, e))?;
    file.read_exact(&mut tail)
        .map_err(|e| BagError::io(path, e))?;
    if tail[0] != mcap::records::op::FOOTER || &tail[29..] != mcap::MAGIC {
        // No footer: truncated or still being written; the stream reader says more.
        return Ok(McapSummary::default());
    }
    let u64_at = |i: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&tail[i..i + 8]);
        u64::from_le_bytes(b)
    };
    let summary_start = u64_at(9);
    if summary_start == 0 || summary_start >= len - TAIL {
        return Ok(McapSummary::default());
    }
    let mut summary = vec![0u8; (len - TAIL - summary_start) as usize];
    file.seek(SeekFrom::Start(summary_start))
        .map_err(|e| BagError::io(path, e))?;
    file.read_exact(&mut summary)
        .map_err(|e| BagError::io(path, e))?;
    let mut out = McapSummary::default();
    let mut at = 0usize;
    while at + 9 <= summary.len() {
        let op = summary[at];
        let mut b = [0u8; 8];
        b.copy_from_slice(&summary[at + 1..at + 9]);
        let body_len = usize::try_from(u64::from_le_bytes(b)).unwrap_or(usize::MAX);
        let Some(end) = (at + 9)
            .checked_add(body_len)
            .filter(|e| *e <= summary.len())
        else {
            break;
        };
        match parse_record(op, &summary[at + 9..end]) {
            Ok(mcap::records::Record::Schema { header, data }) => {
                out.schemas
                    .insert(header.id, (header.name, data.into_owned()));
            }
            Ok(mcap::records::Record::Channel(c)) => {
                out.channels
                    .insert(c.id, (c.topic, c.schema_id, c.message_encoding));
            }
            Ok(mcap::records::Record::Statistics(s)) => {
                out.counts = Some(s.channel_message_counts);
            }
            Ok(mcap::records::Record::ChunkIndex(c)) => {
                out.chunk_starts.push(c.chunk_start_offset);
            }
            _ => {}
        }
        at = end;
    }
    out.chunk_starts.sort_unstable();
    Ok(out)
}

struct McapChannel {
    topic: String,
    msg_type: String,
    encoding: String,
}

/// The largest MCAP record (or decompressed chunk) accepted: 1 GiB, a 16384 x 16384 rgba8 image.
/// A corrupt length above it is an error instead of an allocation of that size (or an
/// arithmetic overflow inside the reader).
const MAX_RECORD_BYTES: usize = 1 << 30;

/// The most bytes read from an MCAP file per read request of the sans-io reader.
const MAX_READ_REQUEST: usize = 1 << 20;

/// Chunk CRCs are checked before any record of the chunk is used (a flipped bit in a chunk is
/// found, and none of its messages is served); records above [`MAX_RECORD_BYTES`] are refused.
fn reader_options(skip_start_magic: bool) -> LinearReaderOptions {
    LinearReaderOptions::default()
        .with_skip_start_magic(skip_start_magic)
        .with_validate_chunk_crcs(true)
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(MAX_RECORD_BYTES)
}

/// Streams the messages of one MCAP file. After a damaged chunk (bad CRC, undecodable
/// compression, a malformed record) reading resumes at the next chunk the summary lists, so the
/// rest of the file is still read; without a summary (a truncated file) the first damage ends it.
struct McapSource {
    path: PathBuf,
    file: BufReader<File>,
    reader: LinearReader,
    /// File offset of the next byte fed to the reader (the position in error messages).
    offset: u64,
    schemas: HashMap<u16, (String, Vec<u8>)>,
    channels: HashMap<u16, McapChannel>,
    chunk_starts: Vec<u64>,
    /// Where reading last resumed after damage (resume points only move forward).
    resumed_at: Option<u64>,
    file_len: u64,
    /// Set after an error: no resume point is left.
    ended: bool,
}

impl McapSource {
    fn open(path: &Path) -> Result<Self, BagError> {
        let file = File::open(path).map_err(|e| BagError::io(path, e))?;
        // Channels and schemas from the summary too, in case a damaged chunk held their records.
        let summary = read_mcap_summary(path)?;
        let mut channels = HashMap::new();
        for (id, (topic, schema_id, encoding)) in &summary.channels {
            channels.insert(
                *id,
                McapChannel {
                    topic: topic.clone(),
                    msg_type: summary
                        .schemas
                        .get(schema_id)
                        .map(|(n, _)| normalise_type(n))
                        .unwrap_or_default(),
                    encoding: encoding.clone(),
                },
            );
        }
        Ok(Self {
            path: path.to_path_buf(),
            file: BufReader::with_capacity(1 << 20, file),
            reader: LinearReader::new_with_options(reader_options(false)),
            offset: 0,
            schemas: summary.schemas,
            channels,
            chunk_starts: summary.chunk_starts,
            resumed_at: None,
            file_len: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
            ended: false,
        })
    }

    /// After damage at `self.offset`: continue at the first chunk after the damaged one.
    fn resume(&mut self) -> Option<u64> {
        // The damaged chunk is the last one starting before the bytes read so far.
        let damaged = self
            .chunk_starts
            .iter()
            .rev()
            .find(|&&s| s < self.offset)
            .copied()?;
        // Strictly after the damaged chunk and after the last resume point (so a damaged
        // resume point cannot be chosen again), and inside the file.
        let floor = self.resumed_at.map_or(damaged, |r| r.max(damaged));
        let next = self
            .chunk_starts
            .iter()
            .find(|&&s| s > floor && s < self.file_len)
            .copied()?;
        self.resumed_at = Some(next);
        self.file.seek(SeekFrom::Start(next)).ok()?;
        self.reader = LinearReader::new_with_options(reader_options(true));
        self.offset = next;
        Some(next)
    }

    /// Turns a read error into [`BagError::Corrupt`], setting up the resume point if any.
    fn damaged(&mut self, reason: String) -> BagError {
        let offset = self.offset;
        let resumed = self.resume();
        if resumed.is_none() {
            self.ended = true;
        }
        BagError::Corrupt {
            path: self.path.clone(),
            offset,
            reason: match resumed {
                Some(next) => format!("{reason}; skipping to the next chunk at byte {next}"),
                None => reason,
            },
        }
    }

    fn error(&self, reason: impl std::fmt::Display) -> BagError {
        BagError::Corrupt {
            path: self.path.clone(),
            offset: self.offset,
            reason: reason.to_string(),
        }
    }

    /// The next message. The mcap crate (0.26) still panics on some corrupt records (an
    /// arithmetic overflow when a record is longer than its uncompressed chunk, a slice out of
    /// range in a short attachment record). A bag must never panic the program: such a panic
    /// becomes a corrupt-file error at the current offset (reading resumes at the next chunk
    /// when the summary lists one, else it ends).
    fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        if self.ended {
            return Ok(None);
        }
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.next_message_inner())) {
            Ok(result) => result,
            // The reader's state is unknown after a panic: resume at the next chunk, or end.
            Err(_) => Err(self.damaged("the MCAP parser failed on a corrupt record".into())),
        }
    }

    fn next_message_inner(&mut self) -> Result<Option<BagMessage>, BagError> {
        loop {
            let event = match self.reader.next_event() {
                None => return Ok(None),
                Some(Err(e)) => {
                    let reason = match e {
                        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => {
                            "the file ends in the middle of a record (truncated?)".to_string()
                        }
                        other => other.to_string(),
                    };
                    return Err(self.damaged(reason));
                }
                Some(Ok(event)) => event,
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    // `need` comes from a record length in the file: a corrupt one asks for
                    // exabytes. Read at most 1 MiB per request (the reader asks again), so the
                    // buffer never outgrows what the file really holds.
                    let buf = self.reader.insert(need.min(MAX_READ_REQUEST));
                    let n = self
                        .file
                        .read(buf)
                        .map_err(|e| BagError::io(&self.path, e))?;
                    self.reader.notify_read(n);
                    self.offset += n as u64;
                }
                LinearReadEvent::Record { opcode, data } => {
                    let record = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => {
                            let reason = format!("record with opcode {opcode:#04x}: {e}");
                            return Err(self.damaged(reason));
                        }
                    };
                    match record {
                        mcap::records::Record::Schema { header, data } => {
                            self.schemas
                                .insert(header.id, (header.name, data.into_owned()));
                        }
                        mcap::records::Record::Channel(c) => {
                            let msg_type = self
                                .schemas
                                .get(&c.schema_id)
                                .map(|(n, _)| normalise_type(n))
                                .unwrap_or_default();
                            self.channels.insert(
                                c.id,
                                McapChannel {
                                    topic: c.topic,
                                    msg_type,
                                    encoding: c.message_encoding,
                                },
                            );
                        }
                        mcap::records::Record::Message { header, data } => {
                            let Some(channel) = self.channels.get(&header.channel_id) else {
                                let reason =
                                    format!("message on unknown channel {}", header.channel_id);
                                return Err(self.error(reason));
                            };
                            if channel.encoding != "cdr" {
                                let reason = format!(
                                    "topic {} has message encoding '{}', not ROS 2 'cdr'",
                                    channel.topic, channel.encoding
                                );
                                return Err(self.error(reason));
                            }
                            return Ok(Some(BagMessage {
                                topic: channel.topic.clone(),
                                msg_type: channel.msg_type.clone(),
                                log_time_ns: header.log_time,
                                publish_time_ns: header.publish_time,
                                data: data.into_owned(),
                            }));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}

/// Pages through the messages table of a rosbag2 sqlite3 database in timestamp order.
struct SqliteSource {
    path: PathBuf,
    conn: rusqlite::Connection,
    topics: HashMap<i64, (String, String, String)>,
    counts: HashMap<i64, u64>,
    page: std::collections::VecDeque<BagMessage>,
    page_size: usize,
    after: Option<(i64, i64)>,
    done: bool,
}

impl SqliteSource {
    fn open(path: &Path, page_size: usize) -> Result<Self, BagError> {
        let sql = |e: rusqlite::Error| BagError::Format {
            path: path.to_path_buf(),
            reason: format!("sqlite3: {e}"),
        };
        let conn = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sql)?;
        let mut topics = HashMap::new();
        {
            let mut stmt = conn
                .prepare("SELECT id, name, type, serialization_format FROM topics")
                .map_err(sql)?;
            let rows = stmt
                .query_map([], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, String>(3)?,
                    ))
                })
                .map_err(sql)?;
            for row in rows {
                let (id, name, ty, fmt) = row.map_err(sql)?;
                topics.insert(id, (name, normalise_type(&ty), fmt));
            }
        }
        let mut counts = HashMap::new();
        {
            let mut stmt = conn
                .prepare("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id")
                .map_err(sql)?;
            let rows = stmt
                .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?)))
                .map_err(sql)?;
            for row in rows {
                let (id, n) = row.map_err(sql)?;
                counts.insert(id, u64::try_from(n).unwrap_or(0));
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            conn,
            topics,
            counts,
            page: Default::default(),
            page_size,
            after: None,
            done: false,
        })
    }

    fn topic_infos(&self) -> Vec<TopicInfo> {
        let mut v: Vec<TopicInfo> = self
            .topics
            .iter()
            .map(|(id, (name, ty, fmt))| TopicInfo {
                name: name.clone(),
                msg_type: ty.clone(),
                encoding: fmt.clone(),
                count: Some(self.counts.get(id).copied().unwrap_or(0)),
                schema: None,
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }

    fn fill_page(&mut self) -> Result<(), BagError> {
        let sql = |e: rusqlite::Error| BagError::Format {
            path: self.path.clone(),
            reason: format!("sqlite3: {e}"),
        };
        let (t, id) = self.after.unwrap_or((i64::MIN, i64::MIN));
        let mut stmt = self
            .conn
            .prepare_cached(
                "SELECT id, topic_id, timestamp, data FROM messages \
                 WHERE timestamp > ?1 OR (timestamp = ?1 AND id > ?2) \
                 ORDER BY timestamp, id LIMIT ?3",
            )
            .map_err(sql)?;
        let limit = i64::try_from(self.page_size).unwrap_or(256);
        let rows = stmt
            .query_map(rusqlite::params![t, id, limit], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, Vec<u8>>(3)?,
                ))
            })
            .map_err(sql)?;
        let mut n = 0;
        for row in rows {
            let (id, topic_id, timestamp, data) = row.map_err(sql)?;
            n += 1;
            self.after = Some((timestamp, id));
            let Some((topic, msg_type, fmt)) = self.topics.get(&topic_id) else {
                return Err(BagError::Format {
                    path: self.path.clone(),
                    reason: format!("message {id} refers to unknown topic id {topic_id}"),
                });
            };
            if fmt != "cdr" {
                return Err(BagError::Format {
                    path: self.path.clone(),
                    reason: format!("topic {topic} has serialization_format '{fmt}', not 'cdr'"),
                });
            }
            let t = u64::try_from(timestamp).unwrap_or(0);
            self.page.push_back(BagMessage {
                topic: topic.clone(),
                msg_type: msg_type.clone(),
                log_time_ns: t,
                publish_time_ns: t,
                data,
            });
        }
        if n == 0 {
            self.done = true;
        }
        Ok(())
    }

    fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        if self.page.is_empty() && !self.done {
            self.fill_page()?;
        }
        Ok(self.page.pop_front())
    }
}
