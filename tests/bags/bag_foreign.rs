//! Bags that other tools wrote: an MCAP with channels that are not ROS 2 (a Foxglove `json`
//! topic beside the cameras) runs as a healthy bag, the foreign topic named once.

use super::util::{messages, ok, root, scratch, sweepdepth};
use std::collections::BTreeMap;
use std::io::BufWriter;

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
        let header = |channel_id| mcap::records::MessageHeader {
            channel_id,
            sequence: sequence as u32,
            log_time: m.log_time_ns,
            publish_time: m.publish_time_ns,
        };
        writer
            .write_to_known_channel(&header(channel), &m.data)
            .expect("a message");
        writer
            .write_to_known_channel(&header(json), br#"{"message": "hello"}"#)
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
