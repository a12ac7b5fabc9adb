//! Bags as recorders leave them: each topic's recorded QoS (`offered_qos_profiles`), kept by
//! `--copy-inputs` so that `ros2 bag play` of the output offers `/tf_static` transient local
//! again; an MCAP file whose log times go backwards (said once: its sets are made in file
//! order); an sqlite3 file cut short (read as far as it goes, then said).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use super::util::{fixture_bag, messages, root, scratch};
use sweepdepth::bag::{BagMessage, BagReader, StepsBack};

fn fixture() -> PathBuf {
    root().join("tests/fixtures/bags/tsukuba_half.mcap")
}

/// `sweepdepth bag IN OUT` with the fixture's parameters plus `extra`.
fn bag(input: &Path, output: &Path, extra: &[&str]) -> Output {
    fixture_bag(input, output, extra)
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// What Humble's `ros2 bag record` writes for a `/tf_static` publisher: transient local, keep
/// last 1, reliable.
const TF_STATIC_QOS: &str = "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n  \
deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    \
nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    \
nsec: 4294967295\n  avoid_ros_namespace_conventions: false";

/// ... and for a camera driver's sensor-data publisher: best effort, volatile, keep last 5.
const SENSOR_QOS: &str = "- history: 1\n  depth: 5\n  reliability: 2\n  durability: 2\n  \
deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    \
nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    \
nsec: 4294967295\n  avoid_ros_namespace_conventions: false";

fn recorded_qos(topic: &str) -> &'static str {
    if topic == "/tf_static" {
        TF_STATIC_QOS
    } else {
        SENSOR_QOS
    }
}

/// Writes `msgs`, in this order, as an MCAP as rosbag2 does: each channel's metadata holding
/// its `offered_qos_profiles`.
pub fn write_mcap(path: &Path, msgs: &[BagMessage]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .create(file)
        .unwrap();
    let mut channels = std::collections::HashMap::new();
    for m in msgs {
        let id = *channels.entry(m.topic.clone()).or_insert_with(|| {
            let schema = w.add_schema(&m.msg_type, "ros2msg", b"").unwrap();
            let metadata = BTreeMap::from([(
                "offered_qos_profiles".to_string(),
                recorded_qos(&m.topic).to_string(),
            )]);
            w.add_channel(schema, &m.topic, "cdr", &metadata).unwrap()
        });
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: 0,
            log_time: m.log_time_ns,
            publish_time: m.publish_time_ns,
        };
        w.write_to_known_channel(&header, &m.data).unwrap();
    }
    w.finish().unwrap();
}

/// Writes `msgs` as a rosbag2 sqlite3 database (the tables of Humble's sqlite3 storage), each
/// topic with its `offered_qos_profiles`.
pub fn write_db3(path: &Path, msgs: &[BagMessage]) {
    let _ = std::fs::remove_file(path);
    let mut db = rusqlite::Connection::open(path).unwrap();
    db.execute_batch(
        "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
         INSERT INTO schema VALUES (3, 'humble');
         CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
             metadata TEXT NOT NULL);
         CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         CREATE INDEX timestamp_idx ON messages (timestamp ASC);",
    )
    .unwrap();
    let tx = db.transaction().unwrap();
    let mut ids: BTreeMap<String, i64> = BTreeMap::new();
    for m in msgs {
        if !ids.contains_key(&m.topic) {
            let id = ids.len() as i64 + 1;
            tx.execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', ?4)",
                rusqlite::params![id, m.topic, m.msg_type, recorded_qos(&m.topic)],
            )
            .unwrap();
            ids.insert(m.topic.clone(), id);
        }
        tx.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![ids[&m.topic], m.log_time_ns as i64, m.data],
        )
        .unwrap();
    }
    tx.commit().unwrap();
}

/// `offered_qos_profiles` of each channel of an MCAP file, by topic.
fn mcap_qos(path: &Path) -> BTreeMap<String, String> {
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    summary
        .channels
        .values()
        .map(|c| {
            let qos = c.metadata.get("offered_qos_profiles").expect("the key");
            (c.topic.clone(), qos.clone())
        })
        .collect()
}

/// `offered_qos_profiles` of each topic of a rosbag2 directory's `metadata.yaml`, by topic.
fn metadata_qos(dir: &Path) -> BTreeMap<String, String> {
    let text = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    let yaml: serde_yaml_ng::Value = serde_yaml_ng::from_str(&text).unwrap();
    yaml["rosbag2_bagfile_information"]["topics_with_message_count"]
        .as_sequence()
        .unwrap()
        .iter()
        .map(|t| {
            let meta = &t["topic_metadata"];
            let qos = meta["offered_qos_profiles"].as_str().expect("a string");
            (meta["name"].as_str().unwrap().to_string(), qos.to_string())
        })
        .collect()
}

/// `--copy-inputs` keeps each copied topic's recorded QoS, from MCAP channel metadata and from
/// sqlite3's topics table, in the output's MCAP channels and `metadata.yaml`; what the node
/// makes keeps the empty profile (`ros2 bag play`'s default).
#[test]
fn copied_topics_keep_their_recorded_qos() {
    let dir = scratch("recorded_qos");
    let fixture = messages(&fixture());
    let mcap_in = dir.join("in.mcap");
    write_mcap(&mcap_in, &fixture);
    let db3_in = dir.join("in.db3");
    write_db3(&db3_in, &fixture);
    for (input, name) in [(&mcap_in, "from_mcap"), (&db3_in, "from_db3")] {
        let out = dir.join(name);
        let run = bag(input, &out, &["--copy-inputs"]);
        assert!(run.status.success(), "{name}: {}", stderr_of(&run));
        let in_metadata = metadata_qos(&out);
        let in_channels = mcap_qos(&out.join(format!("{name}_0.mcap")));
        for qos in [&in_metadata, &in_channels] {
            assert_eq!(qos["/tf_static"], TF_STATIC_QOS, "{name}");
            assert_eq!(qos["/cam2/image_raw"], SENSOR_QOS, "{name}");
            assert_eq!(qos["/cam0/camera_info"], SENSOR_QOS, "{name}");
            assert_eq!(qos["/depth/image"], "", "{name}: the node's own");
        }
        // Read back by our reader: from metadata.yaml, and from the MCAP channel alone.
        let reader = BagReader::open(&out).unwrap();
        assert_eq!(reader.offered_qos("/tf_static"), Some(TF_STATIC_QOS));
        assert_eq!(reader.offered_qos("/depth/image"), None);
        let lone = BagReader::open(&out.join(format!("{name}_0.mcap"))).unwrap();
        assert_eq!(lone.offered_qos("/tf_static"), Some(TF_STATIC_QOS));
    }
}

/// MCAP is read in file order: a file whose log times go backwards (merged or written out of
/// order) is said once, with how many messages stepped back and by how much at most; a file in
/// order says nothing.
#[test]
fn mcap_log_times_going_backwards_are_said_once() {
    let dir = scratch("backwards");
    let mut msgs = messages(&fixture());
    msgs.sort_by_key(|m| m.log_time_ns);
    // The last message logged, moved to the middle: the one after it steps back.
    let last = msgs.pop().unwrap();
    let at = msgs.len() / 2;
    let step = last.log_time_ns - msgs[at].log_time_ns;
    assert!(step > 0);
    msgs.insert(at, last);
    let path = dir.join("out_of_order.mcap");
    write_mcap(&path, &msgs);
    let mut reader = BagReader::open(&path).unwrap();
    assert_eq!(reader.by_ref().count(), msgs.len());
    let steps = StepsBack {
        messages: 1,
        max_ns: step,
    };
    assert_eq!(reader.log_times_back(), Some(steps));
    let mut in_order = BagReader::open(&fixture()).unwrap();
    in_order.by_ref().for_each(drop);
    assert_eq!(in_order.log_times_back(), None);

    let run = bag(&path, &dir.join("out.mcap"), &[]);
    let stderr = stderr_of(&run);
    assert!(run.status.success(), "{stderr}");
    assert_eq!(
        stderr.matches("log times go backwards").count(),
        1,
        "{stderr}"
    );
    let said = format!(
        "1 message logged before the one read before it, by up to {:.3} s",
        step as f64 / 1e9
    );
    assert!(stderr.contains(&said), "{said}: {stderr}");
    assert!(
        stderr.contains("frame sets are made in file order"),
        "{stderr}"
    );
}

/// An sqlite3 bag cut short (a recording killed mid-write, a copy that stopped) gives every
/// message its pages still hold, then one error naming the file, the messages read and the
/// last one's time; `bag` processes the sets it holds and exits 0 (non-zero with
/// `--strict`). Cut inside its first page: nothing readable, an error that says so.
#[test]
fn sqlite3_bag_cut_short_gives_what_it_holds() {
    let dir = scratch("cut_db3");
    let fixture = messages(&fixture());
    let whole = dir.join("whole.db3");
    write_db3(&whole, &fixture);
    assert_eq!(messages(&whole), fixture);
    let bytes = std::fs::read(&whole).unwrap();
    let page = usize::from(u16::from_be_bytes([bytes[16], bytes[17]]));
    // The last quarter of its pages gone.
    let keep = bytes.len() * 3 / 4 / page * page;
    let cut = dir.join("cut.db3");
    std::fs::write(&cut, &bytes[..keep]).unwrap();
    let (mut read, mut errors) = (Vec::new(), Vec::new());
    for item in BagReader::open(&cut).unwrap() {
        match item {
            Ok(m) => read.push(m),
            Err(e) => errors.push(e.to_string()),
        }
    }
    assert!(
        !read.is_empty() && read.len() < fixture.len(),
        "{}",
        read.len()
    );
    // Each message read is one written, in recording order.
    let mut written = fixture.iter();
    assert!(read.iter().all(|m| written.any(|w| w == m)));
    assert_eq!(errors.len(), 1, "{errors:?}");
    let error = &errors[0];
    let last_ns = read.last().unwrap().log_time_ns;
    for said in [
        "cut.db3",
        "cut short",
        &format!("{} messages read", read.len()),
        &format!("({last_ns} ns)"),
        "the rest of the file is damaged",
    ] {
        assert!(error.contains(said), "{said}: {error}");
    }

    let run = bag(&cut, &dir.join("out.mcap"), &[]);
    let stderr = stderr_of(&run);
    assert!(run.status.success(), "{stderr}");
    assert!(stderr.contains(error.as_str()), "{stderr}");
    assert!(stderr.contains("1 read errors (damaged bag)"), "{stderr}");
    let depths = messages(&dir.join("out.mcap"))
        .into_iter()
        .filter(|m| m.topic == "/depth/image")
        .count();
    assert!(depths >= 1, "{stderr}");
    let strict = bag(&cut, &dir.join("strict.mcap"), &["--strict"]);
    assert!(!strict.status.success());
    assert!(stderr_of(&strict).contains("the bag is damaged"));

    // Cut inside a page: read as far as it goes too.
    let ragged = dir.join("ragged.db3");
    std::fs::write(&ragged, &bytes[..keep + page / 3]).unwrap();
    let items: Vec<_> = BagReader::open(&ragged).unwrap().collect();
    let errors: Vec<String> = items
        .iter()
        .filter_map(|i| i.as_ref().err().map(|e| e.to_string()))
        .collect();
    assert!(items.len() > read.len(), "{}", items.len());
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("ragged.db3"), "{}", errors[0]);

    // Its first page alone (the topics are gone), or not even a header: a clear error.
    for (name, len) in [("page1.db3", page), ("header.db3", 60)] {
        let path = dir.join(name);
        std::fs::write(&path, &bytes[..len]).unwrap();
        let run = bag(&path, &dir.join(format!("{name}.out")), &[]);
        let stderr = stderr_of(&run);
        assert!(!run.status.success(), "{stderr}");
        assert!(
            stderr.contains(name) && stderr.contains("cut short"),
            "{stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}
