//! Bags that other tools wrote: an MCAP with channels that are not ROS 2 (a Foxglove `json`
//! topic beside the cameras) runs as a healthy bag, the foreign topic named once.

use super::util::{messages, ok, root, scratch, sweepdepth};
use std::collections::BTreeMap;
use std::io::BufWriter;

/// Writes `m` as ROS 2 CDR on its topic's channel (made on its first message, with an empty
/// `ros2msg` schema as a recorder without the definition writes it).
fn write_cdr<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
    channels: &mut BTreeMap<String, u16>,
    sequence: usize,
    m: &sweepdepth::bag::BagMessage,
) {
    let channel = match channels.get(&m.topic) {
        Some(&id) => id,
        None => {
            let schema = writer
                .add_schema(&m.msg_type, "ros2msg", b"")
                .expect("a schema");
            let id = writer
                .add_channel(schema, &m.topic, "cdr", &BTreeMap::new())
                .expect("a channel");
            channels.insert(m.topic.clone(), id);
            id
        }
    };
    let header = mcap::records::MessageHeader {
        channel_id: channel,
        sequence: sequence as u32,
        log_time: m.log_time_ns,
        publish_time: m.publish_time_ns,
    };
    writer
        .write_to_known_channel(&header, &m.data)
        .expect("a message");
}

#[test]
fn a_json_channel_beside_the_cameras_is_skipped_not_damage() {
    let dir = scratch("foreign-json");
    let input = dir.join("with_json.mcap");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let file = std::fs::File::create(&input).expect("create the bag");
    let mut writer = mcap::Writer::new(BufWriter::new(file)).expect("an MCAP writer");
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    let json_schema = writer
        .add_schema("foxglove.Log", "jsonschema", b"{}")
        .expect("a schema");
    let json = writer
        .add_channel(json_schema, "/foxglove/log", "json", &BTreeMap::new())
        .expect("a channel");
    for (sequence, m) in messages(&fixture).into_iter().enumerate() {
        write_cdr(&mut writer, &mut channels, sequence, &m);
        let header = mcap::records::MessageHeader {
            channel_id: json,
            sequence: sequence as u32,
            log_time: m.log_time_ns,
            publish_time: m.publish_time_ns,
        };
        writer
            .write_to_known_channel(&header, br#"{"message": "hello"}"#)
            .expect("a json message");
    }
    writer.finish().expect("finish the bag");
    drop(writer);
    let out = dir.join("out.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            input.to_str().unwrap(),
            out.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
            "--strict",
        ]),
        "bag --strict on a bag with a json channel",
    );
    assert!(
        stderr.contains("3 processed") && !stderr.contains("damaged"),
        "{stderr}"
    );
    assert_eq!(
        stderr
            .matches("topic /foxglove/log has message encoding 'json'")
            .count(),
        1,
        "named once: {stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A rosbag2 directory compressed per file (`compression_mode: FILE`) whose `.zstd` was cut
/// short (a recording killed while compressing): the sets before the cut are processed, the
/// cut reported as damage; and no decompressed copy is left in the temporary folder, neither
/// then nor when a metadata.yaml claims compression its file does not have.
#[test]
fn a_file_compressed_bag_cut_short_gives_its_first_sets_and_leaves_no_copy() {
    let dir = scratch("foreign-zstd");
    let bag = dir.join("rec");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let mut writer = sweepdepth::bag::BagWriter::create(&bag, false).expect("create the bag");
    for m in messages(&fixture) {
        writer.add_topic(&m.topic, &m.msg_type, None).unwrap();
        writer
            .write(&m.topic, m.log_time_ns, m.publish_time_ns, &m.data)
            .unwrap();
    }
    writer.finish().expect("finish the bag");
    // The storage file again as a recorder writes it: chunks of 64 KiB, uncompressed (a cut
    // loses the chunk it falls in, not the file).
    let file = bag.join("rec_0.mcap");
    let small = std::fs::File::create(&file).unwrap();
    let mut storage = mcap::WriteOptions::new()
        .compression(None)
        .chunk_size(Some(64 * 1024))
        .create(BufWriter::new(small))
        .expect("an MCAP writer");
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    // In time order, as recorded: a set's messages side by side.
    let mut recorded = messages(&fixture);
    recorded.sort_by_key(|m| m.log_time_ns);
    for (sequence, m) in recorded.into_iter().enumerate() {
        write_cdr(&mut storage, &mut channels, sequence, &m);
    }
    storage.finish().unwrap();
    drop(storage);
    let raw = std::fs::read(&file).expect("the storage file");
    let packed = zstd::encode_all(&raw[..], 3).expect("compress");
    std::fs::remove_file(&file).unwrap();
    // Cut 16 bytes short: the stream's last block (up to 128 KiB of the file's end) is lost,
    // the first sets' images are whole (the fixture's sets repeat their images, so the
    // later sets take few compressed bytes).
    std::fs::write(bag.join("rec_0.mcap.zstd"), &packed[..packed.len() - 16]).unwrap();
    let metadata = bag.join("metadata.yaml");
    let yaml = std::fs::read_to_string(&metadata)
        .unwrap()
        .replace("rec_0.mcap", "rec_0.mcap.zstd")
        .replace(
            "compression_format: \"\"\n  compression_mode: \"\"",
            "compression_format: zstd\n  compression_mode: FILE",
        );
    assert!(yaml.contains("compression_mode: FILE"), "{yaml}");
    std::fs::write(&metadata, &yaml).unwrap();
    let tmp = dir.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let run = |input: &std::path::Path, out: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
            .args([
                "bag",
                input.to_str().unwrap(),
                dir.join(out).to_str().unwrap(),
                "--params-file",
                params.to_str().unwrap(),
            ])
            .env("RUST_LOG", "warn,sweepdepth=info")
            .env("TMPDIR", &tmp)
            .stdin(std::process::Stdio::null())
            .output()
            .expect("run sweepdepth bag")
    };
    let cut = run(&bag, "out.mcap");
    let stderr = String::from_utf8_lossy(&cut.stderr);
    assert!(cut.status.success(), "{stderr}");
    assert!(
        stderr.contains("zstd file compression")
            && stderr.contains("read errors (damaged bag)")
            && !stderr.contains(" 0 processed"),
        "{stderr}"
    );
    let left = || std::fs::read_dir(&tmp).unwrap().count();
    assert_eq!(left(), 0, "a decompressed copy was left behind");
    // The same folder claiming compression of an uncompressed file: an error, no copy.
    std::fs::write(bag.join("rec_0.mcap.zstd"), &raw).unwrap();
    let claimed = run(&bag, "out2.mcap");
    let stderr = String::from_utf8_lossy(&claimed.stderr);
    assert!(
        !claimed.status.success() && stderr.contains("zstd file compression"),
        "{stderr}"
    );
    assert_eq!(left(), 0, "a copy was left behind after the error");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--copy-inputs` from a rosbag2 directory (whose metadata.yaml carries no message
/// definitions) copies a topic of a type sweepdepth does not know with the definition its
/// storage file recorded: readers of OUT (rosbags, Foxglove) decode it.
#[test]
fn copied_topics_keep_the_definitions_of_a_directory_bag() {
    let dir = scratch("foreign-copy");
    let bag = dir.join("rec");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let mut writer = sweepdepth::bag::BagWriter::create(&bag, false).expect("create the bag");
    let definition: &[u8] = b"uint8[] data\n";
    writer
        .add_topic("/my/blob", "my_pkg/msg/Blob", Some(definition))
        .unwrap();
    for m in messages(&fixture) {
        writer.add_topic(&m.topic, &m.msg_type, None).unwrap();
        writer
            .write(&m.topic, m.log_time_ns, m.publish_time_ns, &m.data)
            .unwrap();
        // A CDR uint8[] of three bytes.
        let blob = [0u8, 1, 0, 0, 3, 0, 0, 0, 7, 8, 9];
        writer
            .write("/my/blob", m.log_time_ns, m.publish_time_ns, &blob)
            .unwrap();
    }
    writer.finish().expect("finish the bag");
    assert!(bag.join("metadata.yaml").is_file());
    let out = dir.join("out.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    ok(
        &sweepdepth(&[
            "bag",
            bag.to_str().unwrap(),
            out.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
            "--copy-inputs",
        ]),
        "bag --copy-inputs from a directory",
    );
    let reader = sweepdepth::bag::BagReader::open(&out).expect("open OUT");
    let blob = reader
        .topics()
        .iter()
        .find(|t| t.name == "/my/blob")
        .expect("the copied topic");
    assert_eq!(blob.schema.as_deref(), Some(definition));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A rosbag2 directory without its metadata.yaml (a recording that did not finish): its
/// storage files are read in name order, with a warning.
#[test]
fn a_directory_without_metadata_is_read_from_its_storage_files() {
    let dir = scratch("foreign-nometa");
    let bag = dir.join("rec");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let mut writer = sweepdepth::bag::BagWriter::create(&bag, false).expect("create the bag");
    for m in messages(&fixture) {
        writer.add_topic(&m.topic, &m.msg_type, None).unwrap();
        writer
            .write(&m.topic, m.log_time_ns, m.publish_time_ns, &m.data)
            .unwrap();
    }
    writer.finish().expect("finish the bag");
    std::fs::remove_file(bag.join("metadata.yaml")).unwrap();
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            bag.to_str().unwrap(),
            dir.join("out.mcap").to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
        ]),
        "bag on a directory without metadata.yaml",
    );
    assert!(
        stderr.contains("no metadata.yaml") && stderr.contains("3 processed"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
