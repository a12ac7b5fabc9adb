//! The node's own parameters as typed values ([`NodeValues`]), read from a [`ParamSet`] once,
//! by name, in one place: the configurations of the depth node, `bag`, the `fuse` node and the
//! live view read its fields. (The engine's parameters have their typed form in
//! [`crate::sweep::SweepParams`], through [`super::apply_to_sweep`].) Also the node's checks
//! across these values ([`NodeValues::check`]).

use super::set::{ParamSet, ParamSource};
use super::table::param_spec;
use super::ParamError;
use crate::ros::param_value::ParamValue;

/// A Rust type that a parameter's value reads as (the table's kind of that parameter).
trait ReadAs: Sized {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError>;
}

impl ReadAs for bool {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_bool(name)
    }
}

impl ReadAs for i64 {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_i64(name)
    }
}

impl ReadAs for f64 {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_f64(name)
    }
}

impl ReadAs for String {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_str(name).map(str::to_string)
    }
}

impl ReadAs for Vec<String> {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_string_array(name).map(<[String]>::to_vec)
    }
}

impl ReadAs for Vec<f64> {
    fn read_as(set: &ParamSet, name: &str) -> Result<Self, ParamError> {
        set.get_f64_array(name).map(<[f64]>::to_vec)
    }
}

/// Declares [`NodeValues`]: each field with its type and the parameter it is read from.
macro_rules! node_values {
    ($($(#[$doc:meta])* $field:ident: $ty:ty = $name:literal;)*) => {
        /// The values of the node's own parameters (`params/node.rs`), typed, as one
        /// [`ParamSet`] holds them. Integers stay `i64` as the table has them: each user
        /// converts and refuses a value that does not fit with its own error.
        #[derive(Debug, Clone, PartialEq)]
        pub struct NodeValues {
            $($(#[$doc])* pub $field: $ty,)*
        }

        impl NodeValues {
            /// The parameters read, one per field (every node parameter of the table; a test
            /// keeps them equal).
            pub const NAMES: &'static [&'static str] = &[$($name),*];

            /// Every node parameter's value in `set`.
            pub fn read(set: &ParamSet) -> Result<Self, ParamError> {
                Ok(Self {
                    $($field: ReadAs::read_as(set, $name)?,)*
                })
            }
        }
    };
}

node_values! {
    /// `cameras`: the camera namespaces, left to right.
    cameras: Vec<String> = "cameras";
    /// `image_topic`: the image topic under each camera's namespace.
    image_topic: String = "image_topic";
    /// `image_transport`: `raw` or `compressed`.
    image_transport: String = "image_transport";
    /// `image_kinds`: per camera `raw`, `rect` or `auto` (empty: all `auto`).
    image_kinds: Vec<String> = "image_kinds";
    /// `reference_camera` (empty: the middle camera, [`NodeValues::reference_camera`]).
    reference_camera: String = "reference_camera";
    /// `references`: several reference cameras (empty: the one of `reference_camera`).
    references: Vec<String> = "references";
    /// `world_frame`: the fixed frame a moving rig is posed in (empty: a rigid rig).
    world_frame: String = "world_frame";
    /// `tf_timeout`, seconds.
    tf_timeout_s: f64 = "tf_timeout";
    /// `fusion`: live fusion on.
    fusion: bool = "fusion";
    /// `voxel_size`, metres.
    voxel_size_m: f64 = "voxel_size";
    /// `max_blocks` (0: no limit).
    max_blocks: i64 = "max_blocks";
    /// `mesh_rate`, Hz.
    mesh_rate_hz: f64 = "mesh_rate";
    /// `fusion_device`: `auto`, `gpu` or `cpu`.
    fusion_device: String = "fusion_device";
    /// `depth_topics`: the `fuse` node's inputs.
    depth_topics: Vec<String> = "depth_topics";
    /// `color_topics`: the colour beside each of the `fuse` node's depth inputs.
    color_topics: Vec<String> = "color_topics";
    /// `device`: `auto`, `gpu` or `cpu`.
    device: String = "device";
    /// `sync`: `exact` or `approximate`.
    sync: String = "sync";
    /// `camera_timeout`, seconds (0: never).
    camera_timeout_s: f64 = "camera_timeout";
    /// `sync_max_interval`, seconds.
    sync_max_interval_s: f64 = "sync_max_interval";
    /// `queue_size`, images per camera.
    queue_size: i64 = "queue_size";
    /// `age_penalty`.
    age_penalty: f64 = "age_penalty";
    /// `sync_future_window`, seconds.
    sync_future_window_s: f64 = "sync_future_window";
    /// `sync_reset_backwards`, seconds.
    sync_reset_backwards_s: f64 = "sync_reset_backwards";
    /// `rig_file`: its path (empty: CameraInfo and `/tf_static`).
    rig_file: String = "rig_file";
    /// `publish_points`.
    publish_points: bool = "publish_points";
    /// `input_qos_reliable`.
    input_qos_reliable: bool = "input_qos_reliable";
    /// `input_qos_depth`.
    input_qos_depth: i64 = "input_qos_depth";
    /// `output_qos_depth`.
    output_qos_depth: i64 = "output_qos_depth";
    /// `foxglove_port` (0: no live view).
    foxglove_port: i64 = "foxglove_port";
    /// `foxglove_address`.
    foxglove_address: String = "foxglove_address";
    /// `virtual_reference`.
    virtual_reference: bool = "virtual_reference";
    /// `virtual_frame_id`.
    virtual_frame_id: String = "virtual_frame_id";
    /// `virtual_pose`, unchecked (checked: [`NodeValues::virtual_pose`]).
    virtual_pose: Vec<f64> = "virtual_pose";
    /// `virtual_width`, pixels (0: the reference camera's).
    virtual_width: i64 = "virtual_width";
    /// `virtual_height`, pixels (0: the reference camera's).
    virtual_height: i64 = "virtual_height";
    /// `virtual_fx`, pixels (0: the reference camera's).
    virtual_fx: f64 = "virtual_fx";
    /// `virtual_fy`, pixels (0: the reference camera's).
    virtual_fy: f64 = "virtual_fy";
    /// `virtual_cx`, pixels (0: the reference camera's).
    virtual_cx: f64 = "virtual_cx";
    /// `virtual_cy`, pixels (0: the reference camera's).
    virtual_cy: f64 = "virtual_cy";
}

impl NodeValues {
    /// The node's checks across parameters: `cameras` is set (>= 2 distinct names),
    /// `reference_camera` is empty or one of them, and a virtual reference has a valid
    /// `virtual_pose` and no explicit `pairs: reference` (`set`: where `pairs` came from).
    pub fn check(&self, set: &ParamSet) -> Result<(), ParamError> {
        if let Some(spec) = param_spec("cameras") {
            spec.range
                .check(&ParamValue::StringArray(self.cameras.clone()))
                .map_err(|e| ParamError::Required {
                    name: "cameras".into(),
                    source: Box::new(e),
                })?;
        }
        let reference = &self.reference_camera;
        if !reference.is_empty() && !self.cameras.iter().any(|c| c == reference) {
            return Err(ParamError::UnknownReference {
                reference: reference.clone(),
                cameras: self.cameras.clone(),
            });
        }
        if self.virtual_reference {
            if set.get_str("pairs")? == "reference"
                && set.source("pairs") != Some(&ParamSource::Default)
            {
                return Err(ParamError::VirtualNeedsAllPairs);
            }
            self.virtual_pose()?;
        }
        Ok(())
    }

    /// `virtual_pose` checked: 7 finite numbers `[x, y, z, qx, qy, qz, qw]` with a unit
    /// quaternion by tf2's rule (`geometry::pose::unit_quaternion`).
    pub fn virtual_pose(&self) -> Result<[f64; 7], ParamError> {
        let v = &self.virtual_pose;
        let pose: [f64; 7] = v
            .as_slice()
            .try_into()
            .map_err(|_| ParamError::PoseLength(v.len()))?;
        if pose.iter().any(|x| !x.is_finite()) {
            return Err(ParamError::PoseNotFinite);
        }
        crate::geometry::pose::unit_quaternion(glam::DQuat::from_xyzw(
            pose[3], pose[4], pose[5], pose[6],
        ))
        .map_err(ParamError::PoseNotUnit)?;
        Ok(pose)
    }

    /// `reference_camera`, or the middle entry of `cameras` when it is empty, the first of the
    /// two middle ones for an even count (a stereo pair's first camera, its left by ROS's
    /// convention; None without cameras).
    pub fn reference_camera(&self) -> Option<String> {
        if !self.reference_camera.is_empty() {
            return Some(self.reference_camera.clone());
        }
        self.cameras
            .get(self.cameras.len().saturating_sub(1) / 2)
            .cloned()
    }
}

impl ParamSet {
    /// [`NodeValues::check`] on this set's values.
    pub fn check_node(&self) -> Result<(), ParamError> {
        NodeValues::read(self)?.check(self)
    }

    /// [`NodeValues::reference_camera`] of this set's values.
    pub fn reference_camera(&self) -> Option<String> {
        NodeValues::read(self).ok()?.reference_camera()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::node::node_params;

    #[test]
    fn every_node_parameter_is_read_once() {
        let mut declared: Vec<&str> = node_params().iter().map(|p| p.name).collect();
        let mut read = NodeValues::NAMES.to_vec();
        declared.sort_unstable();
        read.sort_unstable();
        assert_eq!(read, declared);
    }

    #[test]
    fn defaults_read_as_the_table_has_them() {
        let values = NodeValues::read(&ParamSet::defaults()).unwrap();
        assert_eq!(values.image_topic, "image_raw");
        assert_eq!(values.queue_size, 5);
        assert_eq!(values.virtual_pose, vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        assert_eq!(values.virtual_pose().unwrap()[6], 1.0);
        assert!(!values.fusion);
        assert_eq!(values.reference_camera(), None);
    }

    /// Without `reference_camera`: the middle camera, of two middle ones the first (a stereo
    /// pair's left, as stereo_image_proc and OpenCV give a pair's depth).
    #[test]
    fn the_default_reference_is_the_middle_camera_and_a_pairs_first() {
        let mut values = NodeValues::read(&ParamSet::defaults()).unwrap();
        for (cameras, reference) in [
            (&["left", "right"][..], "left"),
            (&["a", "b", "c"][..], "b"),
            (&["a", "b", "c", "d"][..], "b"),
            (&["only"][..], "only"),
        ] {
            values.cameras = cameras.iter().map(|c| c.to_string()).collect();
            assert_eq!(values.reference_camera().as_deref(), Some(reference));
        }
    }
}
