//! Writing bags: a lone `.mcap` file, or a rosbag2 directory (`metadata.yaml` + one MCAP
//! file) that `ros2 bag info` / `ros2 bag play` accept. MCAP with zstd chunks, profile `ros2`,
//! schemas in `ros2msg` encoding (the full definitions of `msg/schemas/`), messages in `cdr`.
//! A bag is written beside its output as `<out>.partial` and moved into place when finished:
//! a run that fails leaves no half-written output (and the one it replaces untouched).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::schemas;
use super::BagError;

/// Where a file goes and whether it may replace what is there.
pub fn check_output(out: &Path, force: bool) -> Result<(), BagError> {
    if out.exists() && !force {
        return Err(BagError::OutputExists(out.to_path_buf()));
    }
    Ok(())
}

/// Where a bag goes: never one of `inputs` or a folder that holds one; where something is
/// there already, replaced only with `force` and only when it is a bag itself (a lone MCAP or
/// sqlite3 file, or a folder of bag files alone), so that `--force` never deletes a dataset, a
/// folder of other files or the input being read.
pub fn check_bag_output(out: &Path, force: bool, inputs: &[&Path]) -> Result<(), BagError> {
    // sqlite3 is read, not written: a `.db3` OUT would silently be a directory of MCAP.
    let extension = out.extension().and_then(|e| e.to_str()).unwrap_or("");
    if extension.eq_ignore_ascii_case("db3") {
        return Err(BagError::Format {
            path: out.to_path_buf(),
            reason: "bags are written as MCAP, not sqlite3: name OUT `.mcap` (one file) or give \
                     a folder name (a rosbag2 directory)"
                .into(),
        });
    }
    if !out.exists() {
        return Ok(());
    }
    let out_real = out.canonicalize().map_err(|e| BagError::io(out, e))?;
    for input in inputs {
        if let Ok(input_real) = input.canonicalize() {
            if input_real.starts_with(&out_real) {
                return Err(BagError::OutputIsInput {
                    out: out.to_path_buf(),
                    input: input.to_path_buf(),
                });
            }
        }
    }
    check_output(out, force)?;
    match not_a_bag(out) {
        Some(what) => Err(BagError::OutputNotABag {
            out: out.to_path_buf(),
            what,
        }),
        None => Ok(()),
    }
}

/// What makes the existing `path` something other than a bag, if anything: a file that is
/// neither MCAP nor sqlite3 (by its first bytes), a folder with other entries than bag files.
fn not_a_bag(path: &Path) -> Option<String> {
    use std::io::Read;
    const MAGICS: [&[u8]; 2] = [b"\x89MCAP0\r\n", b"SQLite format 3\0"];
    if path.is_dir() {
        let entries = match std::fs::read_dir(path) {
            Ok(entries) => entries,
            Err(e) => return Some(format!("a folder that cannot be listed: {e}")),
        };
        let mut others: Vec<String> = entries
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|name| {
                let bag_file = name == "metadata.yaml"
                    || [".mcap", ".db3", ".db3-shm", ".db3-wal", ".zstd"]
                        .iter()
                        .any(|ext| name.ends_with(ext));
                !bag_file
            })
            .collect();
        if others.is_empty() {
            return None;
        }
        others.sort();
        let more = others.len().saturating_sub(3);
        others.truncate(3);
        let mut what = format!("a folder holding {}", others.join(", "));
        if more > 0 {
            what += &format!(" and {more} more");
        }
        return Some(what);
    }
    let mut head = [0u8; 16];
    let read = File::open(path)
        .and_then(|mut f| f.read(&mut head))
        .unwrap_or(0);
    let head = &head[..read];
    if read == 0 || MAGICS.iter().any(|m| head.starts_with(m)) {
        None
    } else {
        Some("a file that is neither MCAP nor sqlite3".into())
    }
}

/// `<out>.partial`: where the bag is written until it is finished.
fn partial_path(out: &Path) -> Result<PathBuf, BagError> {
    let name = out.file_name().ok_or_else(|| BagError::Format {
        path: out.to_path_buf(),
        reason: "not a file or folder name to write a bag to".into(),
    })?;
    let mut partial = name.to_os_string();
    partial.push(".partial");
    Ok(out.with_file_name(partial))
}

/// Removes a file or a folder, if there.
fn remove(path: &Path) -> Result<(), BagError> {
    let r = if path.is_dir() {
        std::fs::remove_dir_all(path)
    } else if path.exists() {
        std::fs::remove_file(path)
    } else {
        Ok(())
    };
    r.map_err(|e| BagError::io(path, e))
}

struct Topic {
    channel_id: u16,
    msg_type: String,
    count: u64,
    /// `offered_qos_profiles`: a copied input's as recorded, else empty.
    qos: String,
}

/// What [`BagWriter::finish`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteSummary {
    pub path: PathBuf,
    pub messages: u64,
    /// (topic, type, count), by topic name.
    pub topics: Vec<(String, String, u64)>,
}

/// Writes one bag.
pub struct BagWriter {
    /// The path the user gave (a `.mcap` file or a directory).
    out: PathBuf,
    /// Where the bag is written until it is finished (`<out>.partial`).
    partial: PathBuf,
    /// The MCAP file inside.
    mcap_path: PathBuf,
    directory: bool,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    topics: HashMap<String, Topic>,
    sequence: u32,
    first_ns: Option<u64>,
    last_ns: u64,
    messages: u64,
}

impl BagWriter {
    /// Creates `out`: a lone MCAP file when it ends in `.mcap`, else a rosbag2 directory,
    /// written as `<out>.partial` until [`BagWriter::finish`]. An existing `out` is an error
    /// unless `force` and it is a bag ([`check_bag_output`]; then it is replaced when the new
    /// one is finished).
    pub fn create(out: &Path, force: bool) -> Result<Self, BagError> {
        check_bag_output(out, force, &[])?;
        let directory = !out
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
        let partial = partial_path(out)?;
        // A `.partial` of a run that was killed: only ever a bag of ours.
        if partial.exists() {
            if let Some(what) = not_a_bag(&partial) {
                return Err(BagError::OutputNotABag { out: partial, what });
            }
            remove(&partial)?;
        }
        if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|e| BagError::io(parent, e))?;
        }
        let mcap_path = if directory {
            std::fs::create_dir_all(&partial).map_err(|e| BagError::io(&partial, e))?;
            let stem = out
                .file_name()
                .and_then(|n| n.to_str())
                .filter(|n| !n.is_empty())
                .unwrap_or("bag");
            partial.join(format!("{stem}_0.mcap"))
        } else {
            partial.clone()
        };
        let file = File::create(&mcap_path).map_err(|e| BagError::io(&mcap_path, e))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("sweepdepth ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(4 << 20))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| BagError::write(&mcap_path, e))?;
        Ok(Self {
            out: out.to_path_buf(),
            partial,
            mcap_path,
            directory,
            writer: Some(writer),
            topics: HashMap::new(),
            sequence: 0,
            first_ns: None,
            last_ns: 0,
            messages: 0,
        })
    }

    /// Declares a topic; `schema` is the definition text, our own for known types when `None`.
    pub fn add_topic(
        &mut self,
        topic: &str,
        msg_type: &str,
        schema: Option<&[u8]>,
    ) -> Result<(), BagError> {
        self.add_topic_with_qos(topic, msg_type, schema, None)
    }

    /// [`Self::add_topic`] with the QoS the topic was recorded with (`offered_qos_profiles`,
    /// rosbag2's YAML text, as the input bag has it): written unchanged into the MCAP channel
    /// and `metadata.yaml`, so that `ros2 bag play` offers it again (`/tf_static` transient
    /// local for late subscribers).
    pub fn add_topic_with_qos(
        &mut self,
        topic: &str,
        msg_type: &str,
        schema: Option<&[u8]>,
        qos: Option<&str>,
    ) -> Result<(), BagError> {
        if self.topics.contains_key(topic) {
            return Ok(());
        }
        let writer = self.writer.as_mut().ok_or(BagError::Finished)?;
        let schema_data = schema
            .filter(|s| !s.is_empty())
            .map(<[u8]>::to_vec)
            .or_else(|| schemas::definition(msg_type).map(|s| s.as_bytes().to_vec()))
            .unwrap_or_default();
        let schema_id = writer
            .add_schema(msg_type, "ros2msg", &schema_data)
            .map_err(|e| BagError::write(&self.mcap_path, e))?;
        let qos = qos.unwrap_or_default().to_string();
        let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), qos.clone())]);
        let channel_id = writer
            .add_channel(schema_id, topic, "cdr", &metadata)
            .map_err(|e| BagError::write(&self.mcap_path, e))?;
        self.topics.insert(
            topic.to_string(),
            Topic {
                channel_id,
                msg_type: msg_type.to_string(),
                count: 0,
                qos,
            },
        );
        Ok(())
    }

    /// Writes one CDR message on a declared topic.
    pub fn write(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        publish_time_ns: u64,
        data: &[u8],
    ) -> Result<(), BagError> {
        let writer = self.writer.as_mut().ok_or(BagError::Finished)?;
        let entry = self
            .topics
            .get_mut(topic)
            .ok_or_else(|| BagError::UnknownTopic(topic.to_string()))?;
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: entry.channel_id,
                    sequence: self.sequence,
                    log_time: log_time_ns,
                    publish_time: publish_time_ns,
                },
                data,
            )
            .map_err(|e| BagError::write(&self.mcap_path, e))?;
        entry.count += 1;
        self.sequence = self.sequence.wrapping_add(1);
        self.messages += 1;
        self.first_ns = Some(self.first_ns.map_or(log_time_ns, |f| f.min(log_time_ns)));
        self.last_ns = self.last_ns.max(log_time_ns);
        Ok(())
    }

    /// Serialises `msg` to CDR and writes it.
    pub fn write_msg<T: serde::Serialize>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        msg: &T,
    ) -> Result<(), BagError> {
        let data = crate::msgs::to_cdr(msg).map_err(|e| BagError::Format {
            path: self.out.clone(),
            reason: format!("cannot serialise a message for {topic}: {e}"),
        })?;
        self.write(topic, log_time_ns, log_time_ns, &data)
    }

    /// Writes the MCAP summary and, for a directory, `metadata.yaml`, and moves the bag into
    /// place (replacing what `out` held, checked to be a bag when the writer was made).
    pub fn finish(mut self) -> Result<WriteSummary, BagError> {
        let mut writer = self.writer.take().ok_or(BagError::Finished)?;
        let ended = writer
            .finish()
            .map_err(|e| BagError::write(&self.mcap_path, e));
        // The file closed before it moves.
        drop(writer);
        let summary = ended.and_then(|_| self.move_into_place());
        if summary.is_err() {
            // Not finished: nothing left behind (as `drop` does).
            let _ = remove(&self.partial);
        }
        summary
    }

    /// The finished MCAP file's `metadata.yaml` (a directory), then the bag into place.
    fn move_into_place(&self) -> Result<WriteSummary, BagError> {
        let mut topics: Vec<(String, String, u64)> = self
            .topics
            .iter()
            .map(|(name, t)| (name.clone(), t.msg_type.clone(), t.count))
            .collect();
        topics.sort();
        if self.directory {
            let path = self.partial.join("metadata.yaml");
            std::fs::write(&path, self.metadata_yaml(&topics))
                .map_err(|e| BagError::io(&path, e))?;
        }
        remove(&self.out)?;
        std::fs::rename(&self.partial, &self.out).map_err(|e| BagError::io(&self.out, e))?;
        Ok(WriteSummary {
            path: self.out.clone(),
            messages: self.messages,
            topics,
        })
    }

    /// rosbag2 metadata, version 5 (read by Humble and every later distribution).
    fn metadata_yaml(&self, topics: &[(String, String, u64)]) -> String {
        let start = self.first_ns.unwrap_or(0);
        let duration = self.last_ns.saturating_sub(start);
        let file = self
            .mcap_path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("bag_0.mcap");
        let mut y = String::from("rosbag2_bagfile_information:\n  version: 5\n");
        y += "  storage_identifier: mcap\n";
        y += &format!("  duration:\n    nanoseconds: {duration}\n");
        y += &format!("  starting_time:\n    nanoseconds_since_epoch: {start}\n");
        y += &format!("  message_count: {}\n", self.messages);
        y += "  topics_with_message_count:\n";
        for (name, ty, count) in topics {
            let qos = self.topics.get(name).map_or("", |t| t.qos.as_str());
            y += &format!(
                "    - topic_metadata:\n        name: {}\n        type: {ty}\n        serialization_format: cdr\n        offered_qos_profiles: {}\n      message_count: {count}\n",
                yaml_str(name),
                yaml_quoted(qos)
            );
        }
        y += "  compression_format: \"\"\n  compression_mode: \"\"\n";
        y += &format!("  relative_file_paths:\n    - {}\n", yaml_str(file));
        y += &format!(
            "  files:\n    - path: {}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      duration:\n        nanoseconds: {duration}\n      message_count: {}\n",
            yaml_str(file),
            self.messages
        );
        y
    }
}

impl Drop for BagWriter {
    /// A bag not finished (the run failed) leaves nothing behind.
    fn drop(&mut self) {
        if self.writer.take().is_some() {
            if let Err(e) = remove(&self.partial) {
                tracing::warn!("cannot remove the unfinished bag: {e}");
            }
        }
    }
}

/// A YAML double-quoted scalar of any text (rosbag2's `offered_qos_profiles` is YAML inside a
/// string: its newlines and quotes escaped).
fn yaml_quoted(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                out.push_str(&format!("\\x{:02x}", c as u32));
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A YAML scalar, quoted when it needs to be.
fn yaml_str(s: &str) -> String {
    if s.chars()
        .all(|c| c.is_ascii_alphanumeric() || "/_.-".contains(c))
        && !s.is_empty()
    {
        s.to_string()
    } else {
        format!("{s:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bag::reader::BagReader;

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("sweepdepth-writer-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    fn round_trip(out: &Path) {
        let mut w = BagWriter::create(out, true).unwrap();
        w.add_topic("/a", schemas::IMAGE, None).unwrap();
        w.add_topic("/b", "foo_msgs/msg/Bar", Some(b"int32 x"))
            .unwrap();
        w.write("/a", 10, 10, &[0, 1, 0, 0, 7]).unwrap();
        w.write("/b", 20, 20, &[0, 1, 0, 0, 8]).unwrap();
        w.write("/a", 30, 30, &[0, 1, 0, 0, 9]).unwrap();
        assert!(matches!(
            w.write("/c", 40, 40, &[]),
            Err(BagError::UnknownTopic(_))
        ));
        let summary = w.finish().unwrap();
        assert_eq!(summary.messages, 3);
        let reader = BagReader::open(out).unwrap();
        let topics = reader.topics().to_vec();
        assert_eq!(topics.len(), 2);
        assert_eq!(topics[0].name, "/a");
        assert_eq!(topics[0].msg_type, schemas::IMAGE);
        assert_eq!(topics[0].count, Some(2));
        let msgs: Vec<_> = reader.map(|m| m.unwrap()).collect();
        assert_eq!(msgs.len(), 3);
        assert_eq!(msgs[1].topic, "/b");
        assert_eq!(msgs[1].msg_type, "foo_msgs/msg/Bar");
        assert_eq!(msgs[2].data, vec![0, 1, 0, 0, 9]);
        assert_eq!(msgs[2].log_time_ns, 30);
    }

    #[test]
    fn lone_mcap_round_trip() {
        round_trip(&tmp("lone.mcap"));
    }

    #[test]
    fn directory_round_trip_and_metadata() {
        let out = tmp("dirbag");
        round_trip(&out);
        let meta = std::fs::read_to_string(out.join("metadata.yaml")).unwrap();
        assert!(meta.contains("storage_identifier: mcap"));
        assert!(meta.contains("- dirbag_0.mcap"));
        assert!(meta.contains("message_count: 3"));
    }

    /// A bag is written as `<out>.partial` and moved into place when finished: a writer
    /// dropped unfinished (a failed run) leaves neither, and the bag it would have replaced
    /// stays as it was.
    #[test]
    fn an_unfinished_bag_leaves_nothing_and_replaces_nothing() {
        let out = tmp("unfinished.mcap");
        let partial = tmp("unfinished.mcap.partial");
        let _ = std::fs::remove_file(&out);
        let mut w = BagWriter::create(&out, false).unwrap();
        w.add_topic("/a", schemas::IMAGE, None).unwrap();
        w.write("/a", 10, 10, &[0, 1, 0, 0, 7]).unwrap();
        assert!(partial.is_file() && !out.exists());
        drop(w);
        assert!(!partial.exists() && !out.exists());

        round_trip(&out);
        let finished = std::fs::read(&out).unwrap();
        let mut w = BagWriter::create(&out, true).unwrap();
        w.add_topic("/z", schemas::IMAGE, None).unwrap();
        drop(w);
        assert_eq!(std::fs::read(&out).unwrap(), finished);
        assert!(!partial.exists());

        // A folder bag: the same, `metadata.yaml` and its MCAP file moved in together.
        let dir = tmp("unfinished_dir");
        let _ = std::fs::remove_dir_all(&dir);
        let w = BagWriter::create(&dir, false).unwrap();
        assert!(tmp("unfinished_dir.partial").is_dir() && !dir.exists());
        drop(w);
        assert!(!tmp("unfinished_dir.partial").exists() && !dir.exists());
    }

    /// `--force` replaces bags alone: a lone MCAP or sqlite3 file, an empty file, a folder of
    /// bag files; never another file or a folder holding one, nor the input or its folder.
    #[test]
    fn force_replaces_bags_alone() {
        let root = tmp("force_cases");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let file = |name: &str, bytes: &[u8]| {
            let p = root.join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        let mcap = file("a.mcap", b"\x89MCAP0\r\nrest");
        // An sqlite3 file by its magic bytes (named `.db3` it is refused: MCAP is written).
        let db3 = file("b", b"SQLite format 3\0rest");
        let named_db3 = file("b.db3", b"SQLite format 3\0rest");
        assert!(matches!(
            check_bag_output(&named_db3, true, &[]),
            Err(BagError::Format { .. })
        ));
        let empty = file("c.mcap", b"");
        let text = file("d.mcap", b"not a bag");
        for ok in [&mcap, &db3, &empty] {
            assert!(check_bag_output(ok, true, &[]).is_ok(), "{}", ok.display());
            assert!(matches!(
                check_bag_output(ok, false, &[]),
                Err(BagError::OutputExists(_))
            ));
        }
        assert!(matches!(
            check_bag_output(&text, true, &[]),
            Err(BagError::OutputNotABag { .. })
        ));
        let bag_dir = root.join("bag");
        std::fs::create_dir(&bag_dir).unwrap();
        std::fs::write(bag_dir.join("metadata.yaml"), "x").unwrap();
        std::fs::write(bag_dir.join("bag_0.mcap"), "x").unwrap();
        assert!(check_bag_output(&bag_dir, true, &[]).is_ok());
        std::fs::write(bag_dir.join("notes.txt"), "x").unwrap();
        let refused = check_bag_output(&bag_dir, true, &[]).unwrap_err();
        assert!(
            refused.to_string().contains("a folder holding notes.txt"),
            "{refused}"
        );
        // The input, and the folder that holds it, even when both are bags.
        let input = bag_dir.join("bag_0.mcap");
        std::fs::remove_file(bag_dir.join("notes.txt")).unwrap();
        for out in [&input, &bag_dir] {
            assert!(matches!(
                check_bag_output(out, true, &[&input]),
                Err(BagError::OutputIsInput { .. })
            ));
        }
        // Not yet there: nothing to check.
        assert!(check_bag_output(&root.join("new.mcap"), false, &[&input]).is_ok());
    }

    /// A copied topic's recorded QoS goes out unchanged (quotes, backslashes and newlines
    /// too): in its MCAP channel and in `metadata.yaml`, which the reader takes it from when
    /// the storage file lacks it.
    #[test]
    fn recorded_qos_is_written_unchanged() {
        let qos = "- history: 1\n  depth: 1\n  durability: 1\n  note: \"a\\b\"\t\n";
        let out = tmp("qos_dir");
        let mut w = BagWriter::create(&out, true).unwrap();
        w.add_topic_with_qos("/tf_static", "tf2_msgs/msg/TFMessage", None, Some(qos))
            .unwrap();
        w.add_topic("/depth/image", schemas::IMAGE, None).unwrap();
        w.write("/tf_static", 10, 10, &[0, 1, 0, 0]).unwrap();
        w.write("/depth/image", 20, 20, &[0, 1, 0, 0]).unwrap();
        w.finish().unwrap();
        let reader = BagReader::open(&out).unwrap();
        assert_eq!(reader.offered_qos("/tf_static"), Some(qos));
        assert_eq!(reader.offered_qos("/depth/image"), None);
        let lone = BagReader::open(&out.join("qos_dir_0.mcap")).unwrap();
        assert_eq!(lone.offered_qos("/tf_static"), Some(qos));
        // metadata.yaml alone: the MCAP file replaced by one without the profile.
        let bare = tmp("qos_bare.mcap");
        let mut w = BagWriter::create(&bare, true).unwrap();
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", None)
            .unwrap();
        w.write("/tf_static", 10, 10, &[0, 1, 0, 0]).unwrap();
        w.finish().unwrap();
        std::fs::rename(&bare, out.join("qos_dir_0.mcap")).unwrap();
        let reader = BagReader::open(&out).unwrap();
        assert_eq!(reader.offered_qos("/tf_static"), Some(qos));
    }

    #[test]
    fn existing_output_is_refused_without_force() {
        let out = tmp("exists.mcap");
        std::fs::write(&out, b"\x89MCAP0\r\n").unwrap();
        assert!(matches!(
            BagWriter::create(&out, false),
            Err(BagError::OutputExists(_))
        ));
        assert!(BagWriter::create(&out, true).is_ok());
    }

    /// OUT's name decides the layout whatever its case (`OUT.MCAP` is one file); a `.db3` OUT
    /// is refused (sqlite3 is read, not written) instead of becoming a directory of MCAP.
    #[test]
    fn out_names_mcap_file_or_refused_sqlite3() {
        let upper = tmp("upper.MCAP");
        let _ = std::fs::remove_file(&upper);
        let mut writer = BagWriter::create(&upper, false).unwrap();
        writer.add_topic("/a", "std_msgs/msg/Empty", None).unwrap();
        writer.finish().unwrap();
        assert!(upper.is_file(), "OUT.MCAP is one MCAP file");
        let db3 = tmp("out.db3");
        let e = BagWriter::create(&db3, false).err().expect("a .db3 OUT");
        assert!(e.to_string().contains("not sqlite3"), "{e}");
        assert!(!db3.exists());
    }
}
