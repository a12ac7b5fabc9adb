//! Reading rosbag2 bags: a lone `.mcap` file, a lone `.db3` file, or a rosbag2 directory
//! (`metadata.yaml` + its MCAP or sqlite3 files, optionally zstd-compressed per file or per
//! message). MCAP is read as a stream (the `mcap` crate's sans-io reader: plain, zstd and lz4
//! chunks) so memory stays bounded by one chunk; sqlite3 through `rusqlite`, in timestamp order.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

mod mcap_source;
mod sqlite_source;

use super::schemas::normalise_type;
use super::BagError;
use mcap_source::{mcap_summary_topics, McapSource, MAX_RECORD_BYTES};
use sqlite_source::SqliteSource;

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
    /// The QoS the recorder offered, as rosbag2 records it (`offered_qos_profiles`: YAML
    /// text), when the bag records one; `--copy-inputs` writes it back out unchanged.
    pub qos: Option<String>,
}

/// Log times that go backwards in an MCAP bag's file order ([`BagReader::log_times_back`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepsBack {
    /// Messages logged earlier than the MCAP message read before them.
    pub messages: u64,
    /// The largest step back, nanoseconds.
    pub max_ns: u64,
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
    /// The log time of the last MCAP message read, and the steps back met so far.
    last_mcap_ns: Option<u64>,
    steps_back: StepsBack,
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
            last_mcap_ns: None,
            steps_back: StepsBack::default(),
        };
        if meta.is_dir() && !path.join("metadata.yaml").exists() {
            // A recording that did not finish writes no metadata.yaml: its storage files,
            // which describe themselves, in name order.
            reader.sources = storage_files(path)?;
            if reader.sources.is_empty() {
                return Err(BagError::Format {
                    path: path.to_path_buf(),
                    reason: "a folder without metadata.yaml or .mcap / .db3 files: not a \
                             rosbag2 bag"
                        .into(),
                });
            }
            tracing::warn!(
                "{}: no metadata.yaml (a recording that did not finish?): reading its {} \
                 storage file(s) in name order",
                path.display(),
                reader.sources.len()
            );
        } else if meta.is_dir() {
            let metadata = Metadata::read(path)?;
            let unlisted: Vec<String> = storage_files(path)?
                .into_iter()
                .filter(|f| !metadata.files.contains(f))
                .filter(|f| !metadata.files.iter().any(|m| m.with_extension("") == *f))
                .filter_map(|f| Some(f.file_name()?.to_string_lossy().into_owned()))
                .collect();
            if !unlisted.is_empty() && !metadata.file_zstd {
                tracing::warn!(
                    "{}: metadata.yaml does not list {} of the folder's storage files, which are \
                     not read ({}; `ros2 bag reindex` rewrites metadata.yaml)",
                    path.display(),
                    unlisted.len(),
                    unlisted.join(", ")
                );
            }
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
        // Topics and counts from the storage files' own indexes where metadata lacked them,
        // and the message definitions they carry (metadata.yaml has none: `--copy-inputs`
        // writes them with the copied topics).
        let lacking_schema = reader.topics.iter().any(|t| t.schema.is_none());
        if (reader.topics.is_empty() || lacking_schema) && !reader.file_zstd {
            let from_metadata = !reader.topics.is_empty();
            let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
            for file in &reader.sources {
                let found = match storage_kind(file)? {
                    StorageKind::Mcap => mcap_summary_topics(file)?,
                    StorageKind::Sqlite => SqliteSource::open(file, 0)?.topic_infos(),
                };
                if from_metadata {
                    for t in found {
                        for known in &mut reader.topics {
                            if known.qos.is_none() && known.name == t.name {
                                known.qos.clone_from(&t.qos);
                            }
                        }
                        let Some(schema) = t.schema else { continue };
                        for known in &mut reader.topics {
                            if known.schema.is_none() && known.msg_type == t.msg_type {
                                known.schema = Some(schema.clone());
                            }
                        }
                    }
                    continue;
                }
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
            if !from_metadata {
                reader.topics = topics.into_values().collect();
            }
        }
        Ok(reader)
    }

    /// The topics known before reading (from metadata.yaml, the MCAP summary or the sqlite
    /// topics table). A lone MCAP file without a summary lists its topics only as they appear.
    pub fn topics(&self) -> &[TopicInfo] {
        &self.topics
    }

    /// How often the log times of the MCAP messages read so far went backwards in file order
    /// (a file merged or written out of order; sets are then made in file order, not time
    /// order); `None` when they never did. Across the MCAP files of a folder too.
    pub fn log_times_back(&self) -> Option<StepsBack> {
        (self.steps_back.messages > 0).then_some(self.steps_back)
    }

    /// The recorded `offered_qos_profiles` of `topic`: from [`Self::topics`], else from the
    /// MCAP channel being read (a file without a summary describes its channels as it goes).
    pub fn offered_qos(&self, topic: &str) -> Option<&str> {
        let known = self.topics.iter().find(|t| t.name == topic);
        if let Some(qos) = known.and_then(|t| t.qos.as_deref()) {
            return Some(qos);
        }
        match &self.current {
            Some(Source::Mcap(m)) => m.offered_qos(topic),
            _ => None,
        }
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
                Some(Source::Mcap(m)) => {
                    let next = m.next_message()?;
                    if let Some(msg) = &next {
                        self.note_log_time(msg.log_time_ns);
                    }
                    next
                }
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

impl BagReader {
    /// Counts an MCAP message logged before the one read before it.
    fn note_log_time(&mut self, log_time_ns: u64) {
        if let Some(last) = self.last_mcap_ns.filter(|&last| log_time_ns < last) {
            self.steps_back.messages += 1;
            self.steps_back.max_ns = self.steps_back.max_ns.max(last - log_time_ns);
        }
        self.last_mcap_ns = Some(log_time_ns);
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
    /// at the next intact chunk when the file's summary lists one; an sqlite3 file cut short
    /// yields what it holds, then one error, and the next file follows; any other error ends
    /// it.
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
                // A damaged sqlite3 file's last word: the bag's next file follows.
                let sqlite_ended =
                    matches!(&self.current, Some(Source::Sqlite(s)) if s.damage_reported());
                if !resumable && !sqlite_ended {
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
    // A stream cut short (a recording killed while compressing): what came before the cut is
    // read, and its storage's reader reports where it ends; nothing decompressed: an error.
    // Either way no copy is left behind on an error.
    let fail = |reason: String| {
        let _ = std::fs::remove_file(&tmp);
        BagError::Format {
            path: path.to_path_buf(),
            reason,
        }
    };
    let mut decoder = match zstd::stream::read::Decoder::new(BufReader::new(input)) {
        Ok(d) => d,
        Err(e) => return Err(fail(format!("zstd file compression: {e}"))),
    };
    let mut written = 0u64;
    let mut buf = vec![0u8; 1 << 20];
    loop {
        match decoder.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                output.write_all(&buf[..n]).map_err(|e| {
                    let _ = std::fs::remove_file(&tmp);
                    BagError::io(&tmp, e)
                })?;
                written += n as u64;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) if written > 0 => {
                tracing::warn!(
                    "{}: zstd file compression: {e}; reading the {:.1} MB decompressed before it",
                    path.display(),
                    written as f64 / 1e6
                );
                break;
            }
            Err(e) => return Err(fail(format!("zstd file compression: {e}"))),
        }
    }
    Ok(tmp)
}

/// A file name's natural order: runs of digits compare as numbers (`frame_2` < `frame_10`;
/// also the storage files of a rosbag2 folder without metadata: `rec_2` < `rec_10`).
pub(crate) fn natural_key(path: &Path) -> Vec<(String, u128)> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut digits = c.to_string();
            while let Some(d) = chars.next_if(char::is_ascii_digit) {
                digits.push(d);
            }
            key.push((
                std::mem::take(&mut text),
                digits.parse().unwrap_or(u128::MAX),
            ));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// A folder's MCAP and sqlite3 files (by name: `.mcap`, `.db3`), in natural name order
/// (`rec_2` before `rec_10`).
fn storage_files(dir: &Path) -> Result<Vec<PathBuf>, BagError> {
    let mut files: Vec<PathBuf> = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| BagError::io(dir, e))? {
        let file = entry.map_err(|e| BagError::io(dir, e))?.path();
        let ext = file.extension().and_then(|e| e.to_str()).unwrap_or("");
        if file.is_file() && (ext == "mcap" || ext == "db3") {
            files.push(file);
        }
    }
    files.sort_by_key(|p| natural_key(p));
    Ok(files)
}

/// `offered_qos_profiles` of a `metadata.yaml` topic: YAML text in a string as rosbag2 writes
/// it (a list or map written in place is turned back into its text); none when empty.
fn qos_text(value: &serde_yaml_ng::Value) -> Option<String> {
    let text = match value {
        serde_yaml_ng::Value::String(s) => s.clone(),
        serde_yaml_ng::Value::Null => return None,
        other => serde_yaml_ng::to_string(other).ok()?,
    };
    (!text.trim().is_empty()).then_some(text)
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
                    qos: meta
                        .and_then(|m| m.get("offered_qos_profiles"))
                        .and_then(qos_text),
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
