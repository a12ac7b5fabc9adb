//! The outputs of one reference, listed once ([`OUTPUTS`]): each output's topic name (under the
//! node's namespace, or `<camera>/` with several references), its message type and whether it
//! is always published. The node's publishers, the bag writer's topics, the live view's
//! channels and [`OutputTopics`] are all made from this list, and
//! [`FrameMessages::with_topics`] / [`FrameMessages::into_list`] give a set's messages in the
//! same order; adding an output is one line here plus the field that carries its message.

use serde::Serialize;

use super::FrameMessages;
use crate::msgdefs;
use crate::msgs::{CameraInfo, Image, PointCloud2};

/// One output of a reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Output {
    Depth,
    DepthInfo,
    Confidence,
    Cost,
    Selection,
    Points,
}

/// The message types the outputs use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MsgType {
    Image,
    CameraInfo,
    PointCloud2,
}

impl MsgType {
    /// The ROS package and type name (`sensor_msgs`, `Image`).
    pub fn ros_name(self) -> (&'static str, &'static str) {
        match self {
            MsgType::Image => ("sensor_msgs", "Image"),
            MsgType::CameraInfo => ("sensor_msgs", "CameraInfo"),
            MsgType::PointCloud2 => ("sensor_msgs", "PointCloud2"),
        }
    }

    /// The full type name of the bag's and the live view's schemas (`sensor_msgs/msg/Image`).
    pub fn schema_name(self) -> &'static str {
        match self {
            MsgType::Image => msgdefs::IMAGE,
            MsgType::CameraInfo => msgdefs::CAMERA_INFO,
            MsgType::PointCloud2 => msgdefs::POINT_CLOUD2,
        }
    }
}

/// What the list says of one output.
#[derive(Debug, Clone, Copy)]
pub struct OutputSpec {
    pub output: Output,
    /// The topic's relative name.
    pub name: &'static str,
    pub msg_type: MsgType,
    /// Published over DDS and written into bags always (`false`: only with `publish_points`;
    /// the live view always has it).
    pub always: bool,
    /// What it carries (for the reference pages).
    pub doc: &'static str,
}

/// Every output of a reference, in the order they are published.
pub const OUTPUTS: [OutputSpec; 6] = [
    spec(
        Output::Depth,
        "depth/image",
        MsgType::Image,
        true,
        "32FC1, metres along the reference optical axis, NaN invalid",
    ),
    spec(
        Output::DepthInfo,
        "depth/camera_info",
        MsgType::CameraInfo,
        true,
        "the CameraInfo of the depth image",
    ),
    spec(
        Output::Confidence,
        "confidence/image",
        MsgType::Image,
        true,
        "32FC1 in [0, 1]",
    ),
    spec(
        Output::Cost,
        "cost/image",
        MsgType::Image,
        true,
        "32FC1, the winning score",
    ),
    spec(
        Output::Selection,
        "selection/image",
        MsgType::Image,
        true,
        "rgb8, the half-sequence selection (the paper's Fig. 7 colours)",
    ),
    spec(
        Output::Points,
        "points",
        MsgType::PointCloud2,
        false,
        "PointCloud2 of the valid depths (publish_points)",
    ),
];

const fn spec(
    output: Output,
    name: &'static str,
    msg_type: MsgType,
    always: bool,
    doc: &'static str,
) -> OutputSpec {
    OutputSpec {
        output,
        name,
        msg_type,
        always,
        doc,
    }
}

impl Output {
    /// Its row of [`OUTPUTS`].
    pub fn spec(self) -> &'static OutputSpec {
        // The list is in the enum's order (a test checks it).
        &OUTPUTS[self as usize]
    }
}

/// The fully qualified (remapped) names of one reference's outputs, in [`OUTPUTS`]' order:
/// every output that is published (`points` only with `publish_points`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputTopics {
    topics: Vec<(Output, String)>,
}

impl OutputTopics {
    /// Made from the list: `resolve` names each output's relative name; `points`: whether the
    /// point cloud is published.
    pub fn new<E>(points: bool, resolve: impl Fn(&str) -> Result<String, E>) -> Result<Self, E> {
        let mut topics = Vec::with_capacity(OUTPUTS.len());
        for spec in OUTPUTS.iter().filter(|s| s.always || points) {
            topics.push((spec.output, resolve(spec.name)?));
        }
        Ok(Self { topics })
    }

    /// The topic of `output`, `None` when it is not published.
    pub fn get(&self, output: Output) -> Option<&str> {
        self.topics
            .iter()
            .find(|(o, _)| *o == output)
            .map(|(_, t)| t.as_str())
    }

    /// The depth image's topic (always published: [`OutputTopics::new`] names it).
    pub fn depth(&self) -> &str {
        self.get(Output::Depth).unwrap_or_default()
    }

    /// Each published output with its topic, in the list's order.
    pub fn iter(&self) -> impl Iterator<Item = (&'static OutputSpec, &str)> {
        self.topics.iter().map(|(o, t)| (o.spec(), t.as_str()))
    }
}

/// One output's message, borrowed from a [`FrameMessages`]; serialises as the message itself.
#[derive(Debug, Clone, Copy, Serialize)]
#[serde(untagged)]
pub enum OutputRef<'a> {
    Image(&'a Image),
    CameraInfo(&'a CameraInfo),
    PointCloud2(&'a PointCloud2),
}

/// One output's message, owned (what a publisher takes).
#[derive(Debug, Clone)]
pub enum OutputMsg {
    Image(Image),
    CameraInfo(Box<CameraInfo>),
    PointCloud2(PointCloud2),
}

impl FrameMessages {
    /// The message of `output`, if this set has one.
    pub fn get(&self, output: Output) -> Option<OutputRef<'_>> {
        Some(match output {
            Output::Depth => OutputRef::Image(&self.depth),
            Output::DepthInfo => OutputRef::CameraInfo(&self.depth_info),
            Output::Confidence => OutputRef::Image(&self.confidence),
            Output::Cost => OutputRef::Image(self.cost.as_ref()?),
            Output::Selection => OutputRef::Image(self.selection.as_ref()?),
            Output::Points => OutputRef::PointCloud2(self.points.as_ref()?),
        })
    }

    /// The set's messages for `topics`, in the list's order, each with its topic.
    pub fn with_topics<'a>(
        &'a self,
        topics: &'a OutputTopics,
    ) -> impl Iterator<Item = (&'a str, OutputRef<'a>)> {
        topics
            .iter()
            .filter_map(|(spec, topic)| Some((topic, self.get(spec.output)?)))
    }

    /// The messages the set has, moved out (for publishers), in the list's order.
    pub fn into_list(self) -> Vec<(Output, OutputMsg)> {
        let mut out = Vec::with_capacity(OUTPUTS.len());
        out.push((Output::Depth, OutputMsg::Image(self.depth)));
        out.push((
            Output::DepthInfo,
            OutputMsg::CameraInfo(Box::new(self.depth_info)),
        ));
        out.push((Output::Confidence, OutputMsg::Image(self.confidence)));
        if let Some(cost) = self.cost {
            out.push((Output::Cost, OutputMsg::Image(cost)));
        }
        if let Some(selection) = self.selection {
            out.push((Output::Selection, OutputMsg::Image(selection)));
        }
        if let Some(points) = self.points {
            out.push((Output::Points, OutputMsg::PointCloud2(points)));
        }
        // The list's order (the enum's, a test checks), those made on demand left out.
        debug_assert!(out
            .windows(2)
            .all(|w| (w[0].0 as usize) < (w[1].0 as usize)));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_output_once_with_a_distinct_topic() {
        for (i, a) in OUTPUTS.iter().enumerate() {
            assert_eq!(a.output as usize, i, "OUTPUTS is in the enum's order");
            assert_eq!(a.output.spec().name, a.name);
            for b in &OUTPUTS[i + 1..] {
                assert_ne!(a.output, b.output);
                assert_ne!(a.name, b.name);
            }
        }
    }

    #[test]
    fn topics_follow_the_list_and_points_only_when_published() {
        let resolve = |n: &str| Ok::<_, ()>(format!("/rig/{n}"));
        let without = OutputTopics::new(false, resolve).unwrap();
        assert_eq!(without.iter().count(), 5);
        assert_eq!(without.get(Output::Points), None);
        assert_eq!(without.depth(), "/rig/depth/image");
        let with = OutputTopics::new(true, resolve).unwrap();
        let names: Vec<_> = with.iter().map(|(_, t)| t.to_string()).collect();
        assert_eq!(names, OUTPUTS.map(|s| format!("/rig/{}", s.name)).to_vec());
    }
}
