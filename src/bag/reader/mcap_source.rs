//! The MCAP source of [`super::BagReader`]: a stream through the `mcap` crate's sans-io
//! reader (memory bounded by one chunk), resuming at the next intact chunk after damage, and
//! the summary's topics.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::super::schemas::normalise_type;
use super::super::BagError;
use super::{BagMessage, TopicInfo};

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
    channels: BTreeMap<u16, SummaryChannel>,
    counts: Option<BTreeMap<u16, u64>>,
    chunk_starts: Vec<u64>,
}

/// A channel of the summary: topic, schema id, message encoding, and the recorded QoS
/// (`offered_qos_profiles` of its metadata, when not empty).
struct SummaryChannel {
    topic: String,
    schema_id: u16,
    encoding: String,
    qos: Option<String>,
}

/// A channel's `offered_qos_profiles` (rosbag2's metadata key), when not empty.
fn channel_qos(metadata: &BTreeMap<String, String>) -> Option<String> {
    metadata
        .get("offered_qos_profiles")
        .filter(|q| !q.trim().is_empty())
        .cloned()
}

pub(super) fn mcap_summary_topics(path: &Path) -> Result<Vec<TopicInfo>, BagError> {
    let summary = read_mcap_summary(path)?;
    let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
    for (id, channel) in &summary.channels {
        let topic = &channel.topic;
        let (name, schema) = summary
            .schemas
            .get(&channel.schema_id)
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
                encoding: channel.encoding.clone(),
                count,
                schema,
                qos: channel.qos.clone(),
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
                let qos = channel_qos(&c.metadata);
                out.channels.insert(
                    c.id,
                    SummaryChannel {
                        topic: c.topic,
                        schema_id: c.schema_id,
                        encoding: c.message_encoding,
                        qos,
                    },
                );
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
    /// `offered_qos_profiles` of its metadata, when not empty.
    qos: Option<String>,
    /// A channel of another encoding than ROS 2's `cdr` (a Foxglove `json` topic, a ROS 1
    /// recording) is not read: said once, when its first message is met.
    skipped: bool,
}

/// The largest MCAP record (or decompressed chunk) accepted: 1 GiB, a 16384 x 16384 rgba8 image.
/// A corrupt length above it is an error instead of an allocation of that size (or an
/// arithmetic overflow inside the reader).
pub(super) const MAX_RECORD_BYTES: usize = 1 << 30;

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
pub(super) struct McapSource {
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
    pub ended: bool,
}

impl McapSource {
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let file = File::open(path).map_err(|e| BagError::io(path, e))?;
        // Channels and schemas from the summary too, in case a damaged chunk held their records.
        let summary = read_mcap_summary(path)?;
        let mut channels = HashMap::new();
        for (id, channel) in &summary.channels {
            channels.insert(
                *id,
                McapChannel {
                    topic: channel.topic.clone(),
                    msg_type: summary
                        .schemas
                        .get(&channel.schema_id)
                        .map(|(n, _)| normalise_type(n))
                        .unwrap_or_default(),
                    encoding: channel.encoding.clone(),
                    qos: channel.qos.clone(),
                    skipped: false,
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

    /// The recorded QoS of `topic`'s channel, once its channel record has been read.
    pub fn offered_qos(&self, topic: &str) -> Option<&str> {
        self.channels
            .values()
            .find(|c| c.topic == topic)
            .and_then(|c| c.qos.as_deref())
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
    pub fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
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
                            let qos = channel_qos(&c.metadata);
                            self.channels.insert(
                                c.id,
                                McapChannel {
                                    topic: c.topic,
                                    msg_type,
                                    encoding: c.message_encoding,
                                    qos,
                                    skipped: false,
                                },
                            );
                        }
                        mcap::records::Record::Message { header, data } => {
                            let Some(channel) = self.channels.get_mut(&header.channel_id) else {
                                let reason =
                                    format!("message on unknown channel {}", header.channel_id);
                                return Err(self.error(reason));
                            };
                            if channel.encoding != "cdr" {
                                if !channel.skipped {
                                    channel.skipped = true;
                                    tracing::info!(
                                        "{}: topic {} has message encoding '{}', not ROS 2's 'cdr': its messages are not read",
                                        self.path.display(),
                                        channel.topic,
                                        channel.encoding
                                    );
                                }
                                continue;
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
