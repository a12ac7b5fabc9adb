//! The node's own parameters (not the engine's): cameras and topics, synchronisation, the rig
//! file, QoS and the virtual reference camera. Each is declared here once, with its default,
//! range and description; all are read-only once the node runs.

use super::spec::{ParamRange, ParamSpec};
use crate::ros::param_value::ParamValue;

fn node_spec(
    name: &'static str,
    default: ParamValue,
    range: ParamRange,
    description: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        kind: default.kind(),
        default,
        range,
        description,
        read_only: true,
        required: false,
    }
}

fn s(v: &str) -> ParamValue {
    ParamValue::String(v.to_string())
}

/// The node parameters, in the order of the docs.
pub fn node_params() -> Vec<ParamSpec> {
    [
        input_params(),
        world_params(),
        sync_params(),
        output_params(),
        virtual_params(),
    ]
    .concat()
}

/// The cameras, their images and the references.
fn input_params() -> Vec<ParamSpec> {
    vec![
        ParamSpec {
            required: true,
            ..node_spec(
                "cameras",
                ParamValue::StringArray(Vec::new()),
                ParamRange::NameList { min_len: 2 },
                "Camera namespaces, left to right; images come from `<camera>/<image_topic>`, calibration from `<camera>/camera_info` or rig_file.",
            )
        },
        node_spec(
            "image_topic",
            s("image_raw"),
            ParamRange::RelativeName,
            "Image topic under each camera namespace.",
        ),
        node_spec(
            "image_transport",
            s("raw"),
            ParamRange::one_of(&["raw", "compressed"]),
            "How the images come, as image_transport's parameter: raw (sensor_msgs/Image on `<camera>/<image_topic>`) or compressed (sensor_msgs/CompressedImage on `<camera>/<image_topic>/compressed`, JPEG or PNG as image_transport's compressed plugin publishes them; decoded when a set is complete, in parallel across cameras). `bag` reads whichever of the two the bag has for a camera, this one first.",
        ),
        node_spec(
            "image_kinds",
            ParamValue::StringArray(Vec::new()),
            ParamRange::each_one_of(&["raw", "rect", "auto"]),
            "Per camera (in the order of cameras), what its image topic carries: raw (described by the CameraInfo's K and D) or rect (rectified: P, in the frame rotated by R); auto or an empty list = from the topic's name (image_raw, image, image_color: raw; image_rect*: rect; any other name: raw, with a note at start-up).",
        ),
        node_spec(
            "reference_camera",
            s(""),
            ParamRange::OptionalName,
            "Camera whose view the depth map is in; empty = the middle entry of cameras (of two middle entries the first: a stereo pair's first camera, its left by convention).",
        ),
        node_spec(
            "references",
            ParamValue::StringArray(Vec::new()),
            ParamRange::NameList { min_len: 0 },
            "Cameras to estimate depth for, each with its own neighbours (the cameras that see its view, at most max_neighbours) and its own half-sequence split; every set gives each of them depth, confidence, cost, selection (and points). Empty = reference_camera alone, on the topics depth/image, ...; with several, each publishes under its own camera namespace: <camera>/depth/image, <camera>/depth/camera_info, <camera>/confidence/image, <camera>/cost/image, <camera>/selection/image, <camera>/points. Not with virtual_reference.",
        ),
    ]
}

/// A moving rig and fusion.
fn world_params() -> Vec<ParamSpec> {
    use ParamValue::{Bool, Double, Int};
    vec![
        node_spec(
            "world_frame",
            s(""),
            ParamRange::OptionalName,
            "A moving rig: the fixed frame the rig moves in (e.g. odom or map). When set, /tf is read as well as /tf_static and every set's reference pose in world_frame at the set's stamp is looked up (interpolated as tf2 does); a set without a pose within tf_timeout is skipped with its reason. Empty = the rig stands still (no /tf).",
        ),
        node_spec(
            "tf_timeout",
            Double(0.5),
            ParamRange::closed(0.0, 60.0),
            "With world_frame: how long a set waits for /tf to reach its stamp (seconds; receive time live, log time in bags) before it is skipped.",
        ),
        node_spec(
            "fusion",
            Bool(false),
            ParamRange::Any,
            "Fuse every reference's depth of every set into one coloured mesh (a TSDF in blocks of 8^3 voxels, beside the engine): published as visualization_msgs/MarkerArray on mesh (one TRIANGLE_LIST per block, only the blocks that changed), saved by the ~/save_mesh service, emptied by ~/clear_map. In world_frame on a moving rig, else in the frame of the first reference's image.",
        ),
        node_spec(
            "voxel_size",
            Double(0.05),
            ParamRange::Double {
                min: 0.001,
                max: 10.0,
                min_exclusive: false,
                max_exclusive: false,
            },
            "Fusion: the side of a voxel, metres (truncation: 4 voxels).",
        ),
        node_spec(
            "max_blocks",
            Int(50_000),
            ParamRange::ints(1, 100_000_000),
            "Fusion: the most blocks of 8^3 voxels kept (8 KiB each: 50000 is about 400 MiB); beyond it the blocks farthest from the newest camera are dropped (their markers deleted).",
        ),
        node_spec(
            "mesh_rate",
            Double(1.0),
            ParamRange::closed(0.0, 100.0),
            "Fusion: how often the changed blocks' meshes are published on mesh, Hz (0 = never: ~/save_mesh only).",
        ),
        node_spec(
            "fusion_device",
            s("auto"),
            ParamRange::one_of(&["auto", "gpu", "cpu"]),
            "Fusion (the depth node, bag, the fuse node): where the TSDF integrates. auto = on the engine's GPU when the WGSL engine runs on a hardware GPU (the fuse node: a hardware GPU if wgpu offers one), else the CPU (on a CPU adapter such as lavapipe the CPU integrator is faster); gpu = on the engine's device, else one of its own (lavapipe without a GPU); cpu = the CPU. On a GPU the mesh is made there too. A device lost or failing mid-run: the map goes on on the CPU from its host copy, at most a second old (logged once; /diagnostics: fusion on), and onto the engine's new device once the engine makes one.",
        ),
        node_spec(
            "depth_topics",
            ParamValue::StringArray(Vec::new()),
            ParamRange::NameList { min_len: 0 },
            "`sweepdepth fuse` only: the depth image topics it fuses (REP 118: 32FC1 metres or 16UC1 millimetres), each with the camera_info beside it (<namespace>/camera_info, as image_transport pairs them), placed in world_frame by /tf and /tf_static at their stamps: other sweepdepth nodes (<camera>/depth/image), a RealSense, stereo_image_proc. The depth node ignores it.",
        ),
        node_spec(
            "color_topics",
            ParamValue::StringArray(Vec::new()),
            ParamRange::NameList { min_len: 0 },
            "`sweepdepth fuse` only: per entry of depth_topics, in its order, the colour image whose pixels are the depth's (the same camera and size: the reference camera's image_raw beside a sweepdepth node's depth, a RealSense's color/image_raw beside its aligned depth), taken at the depth's stamp to colour the mesh (sensor_msgs/Image: rgb8, bgr8, rgba8, bgra8, mono8, mono16; a topic ending in /compressed: sensor_msgs/CompressedImage, JPEG or PNG); empty = a grey mesh. A depth image whose colour has not come adds none (counted in /diagnostics). The depth node ignores it.",
        ),
    ]
}

/// The engine device and the synchroniser.
fn sync_params() -> Vec<ParamSpec> {
    use ParamValue::{Double, Int};
    vec![
        node_spec(
            "device",
            s("auto"),
            ParamRange::one_of(&["auto", "gpu", "cpu"]),
            "Engine: auto = a hardware GPU if wgpu offers one, else the CPU engine; gpu = the WGSL engine on the wgpu adapter (lavapipe without a GPU); cpu = the CPU engine.",
        ),
        node_spec(
            "sync",
            s("approximate"),
            ParamRange::one_of(&["exact", "approximate"]),
            "Time synchronisation of the camera images: equal stamps, or approximate.",
        ),
        node_spec(
            "camera_timeout",
            Double(1.0),
            ParamRange::closed(0.0, 3600.0),
            "A camera silent for this long (seconds; receive time live, log time in bags) leaves the rig until it sends again; the node goes on with the others while at least 2 remain with the reference among them. 0 = never.",
        ),
        node_spec(
            "sync_max_interval",
            Double(0.02),
            ParamRange::closed(0.0, 60.0),
            "Approximate sync: largest spread of the stamps of one set, seconds.",
        ),
        node_spec(
            "queue_size",
            Int(5),
            ParamRange::ints(1, 100),
            "Messages kept per camera while waiting for a matching set.",
        ),
        node_spec(
            "age_penalty",
            Double(0.1),
            ParamRange::at_least(0.0),
            "Approximate sync: penalty on waiting for newer messages (as message_filters' ApproximateTime).",
        ),
        node_spec(
            "sync_future_window",
            Double(10.0),
            ParamRange::closed(1.0, 86400.0),
            "An image stamped more than this many seconds ahead of the newest stamp of every other camera is dropped (counted as future).",
        ),
        node_spec(
            "sync_reset_backwards",
            Double(1.0),
            ParamRange::Double {
                min: 0.0,
                max: 86400.0,
                min_exclusive: true,
                max_exclusive: false,
            },
            "A camera whose stamps go back by more than this many seconds (a bag played in a loop) resets the synchroniser; less is a late image, dropped.",
        ),
    ]
}

/// Rig file, outputs, QoS and the live view.
fn output_params() -> Vec<ParamSpec> {
    use ParamValue::{Bool, Int};
    vec![
        node_spec(
            "rig_file",
            s(""),
            ParamRange::Any,
            "Rig calibration file (our YAML or Kalibr's camchain.yaml); empty = extrinsics from /tf_static and intrinsics from each camera_info.",
        ),
        node_spec(
            "publish_points",
            Bool(false),
            ParamRange::Any,
            "Also publish a sensor_msgs/PointCloud2 of the valid depths (made while subscribed).",
        ),
        node_spec(
            "input_qos_reliable",
            Bool(false),
            ParamRange::Any,
            "Subscribe to the images with reliable QoS (default: best effort, the sensor-data profile).",
        ),
        node_spec(
            "input_qos_depth",
            Int(5),
            ParamRange::ints(1, 1000),
            "History depth of the image subscriptions.",
        ),
        node_spec(
            "output_qos_depth",
            Int(1),
            ParamRange::ints(1, 1000),
            "History depth of the publishers.",
        ),
        node_spec(
            "foxglove_port",
            Int(0),
            ParamRange::ints(0, 65534),
            "Live view: TCP port of the Foxglove WebSocket server (ROS 2 CDR outputs for Foxglove and Lichtblick); the built-in page is served on the next port. 0 = off.",
        ),
        node_spec(
            "foxglove_address",
            s("127.0.0.1"),
            ParamRange::Any,
            "Live view: address the Foxglove server and the page bind (0.0.0.0 = every interface).",
        ),
    ]
}

/// The virtual reference camera.
fn virtual_params() -> Vec<ParamSpec> {
    use ParamValue::{Bool, Double, Int};
    vec![
        node_spec(
            "virtual_reference",
            Bool(false),
            ParamRange::Any,
            "Estimate depth for a virtual camera (virtual_* parameters) instead of reference_camera; needs pairs = all (the default reference becomes all).",
        ),
        node_spec(
            "virtual_frame_id",
            s(""),
            ParamRange::Any,
            "Virtual reference: tf frame of its optical frame, the outputs' frame_id; placed from /tf_static (with rig_file: by virtual_pose). Empty = virtual_pose, outputs in the reference camera's frame.",
        ),
        node_spec(
            "virtual_pose",
            ParamValue::DoubleArray(vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            ParamRange::Any,
            "Virtual reference: [x, y, z, qx, qy, qz, qw] pose of its optical frame in the reference camera's optical frame (metres; unit quaternion); unused when virtual_frame_id is placed by /tf_static.",
        ),
        node_spec(
            "virtual_width",
            Int(0),
            ParamRange::ints(0, 16384),
            "Virtual reference: image width, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_height",
            Int(0),
            ParamRange::ints(0, 16384),
            "Virtual reference: image height, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_fx",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: focal length fx, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_fy",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: focal length fy, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_cx",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: principal point cx, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_cy",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: principal point cy, pixels (0 = the reference camera's).",
        ),
    ]
}
