//! A tf2-style buffer of transforms for `/tf_static` (and `/tf`, without time interpolation).
//!
//! Semantics follow tf2:
//! - A `TransformStamped` with `header.frame_id = parent` and `child_frame_id = child` is the
//!   pose of the child frame in the parent frame, i.e. `parent_from_child`: a point expressed
//!   in the child frame maps into the parent frame by it.
//! - The frames form a forest: each child has exactly one parent. Inserting a child again
//!   replaces its transform, and its parent too if that changed (tf2 behaviour), unless the new
//!   edge would close a cycle.
//! - Frame ids as tf2 has them (`BufferCore` in tf2's `buffer_core.cpp`): an inserted
//!   transform's `header.frame_id` and `child_frame_id` lose one leading `/` (tf2's
//!   `stripSlash`), but a frame id *looked up* must not start with `/`: tf2 refuses it ("in tf2
//!   frame_ids cannot start with a '/'", `validateFrameId`), and so does [`TfBuffer::lookup`].
//!   An image whose `header.frame_id` is `/cam0_optical` therefore gets no transform, with that
//!   message, however `/tf_static` spelt the frame.
//! - A rotation is accepted as tf2 accepts it, `|x² + y² + z² + w² - 1| < 0.01`, and then
//!   normalised ([`crate::geometry::pose::unit_quaternion`]); tf2 refuses NaN, and we refuse
//!   infinite values too.
//! - Only the latest transform of each child is kept (no history, no interpolation): the last
//!   accepted insertion wins, whatever its stamp.
//!
//! [`TfBuffer::lookup`] returns `target_from_source` (`point_in_target =
//! target_from_source.transform_point(point_in_source)`), chaining through the lowest common
//! ancestor of the two frames.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;

use glam::{DQuat, DVec3};

use crate::geometry::{GeometryError, RigidTransform};
use crate::msgs::{TFMessage, Time, TransformStamped};

/// How many known frames an "is not in the tree" message lists at most.
const MAX_LISTED_FRAMES: usize = 20;

/// Errors of [`TfBuffer`]. None is fatal: a rejected insertion leaves the buffer unchanged.
#[derive(Debug, Clone, PartialEq)]
pub enum TfError {
    /// `header.frame_id` or `child_frame_id` is empty (after stripping a leading `/`).
    InvalidFrameId {
        parent: String,
        child: String,
        reason: String,
    },
    /// `header.frame_id == child_frame_id`.
    SelfParent { frame: String },
    /// NaN / infinite translation or rotation, or a quaternion tf2 would not accept
    /// (`|x² + y² + z² + w² - 1| >= 0.01`).
    InvalidTransform {
        parent: String,
        child: String,
        reason: String,
    },
    /// `child` is already an ancestor of `parent`. `path` is the existing chain from `child`
    /// down to `parent` (each frame the parent of the next).
    Cycle {
        parent: String,
        child: String,
        path: Vec<String>,
    },
    /// A frame id given to [`TfBuffer::lookup`] that tf2 refuses: empty, or starting with `/`.
    InvalidLookupFrame {
        /// "target" or "source".
        argument: &'static str,
        frame: String,
        reason: String,
    },
    /// No transform `target_from_source` can be formed (unknown frame, different trees).
    NotConnected {
        target: String,
        source: String,
        reason: String,
    },
}

impl fmt::Display for TfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TfError::InvalidFrameId {
                parent,
                child,
                reason,
            }
            | TfError::InvalidTransform {
                parent,
                child,
                reason,
            } => write!(f, "rejected transform '{parent}' -> '{child}': {reason}"),
            TfError::SelfParent { frame } => write!(
                f,
                "rejected transform '{frame}' -> '{frame}': a frame cannot be its own parent"
            ),
            TfError::Cycle {
                parent,
                child,
                path,
            } => write!(
                f,
                "rejected transform '{parent}' -> '{child}': it would create a cycle \
                 ('{child}' is already an ancestor of '{parent}': {})",
                path.join(" -> ")
            ),
            TfError::InvalidLookupFrame {
                argument,
                frame,
                reason,
            } => write!(f, "invalid {argument} frame id \"{frame}\": {reason}"),
            TfError::NotConnected {
                target,
                source,
                reason,
            } => write!(f, "no transform from '{source}' to '{target}': {reason}"),
        }
    }
}

impl std::error::Error for TfError {}

/// Strips one leading `/` from a frame id, as tf2 does on insertion (`stripSlash`:
/// `"/base_link"` -> `"base_link"`, `"//a"` -> `"/a"`).
pub fn normalize_frame_id(frame_id: &str) -> &str {
    frame_id.strip_prefix('/').unwrap_or(frame_id)
}

/// tf2's check of a frame id passed to a lookup (`BufferCore::validateFrameId`): not empty and
/// not starting with `/`; the reasons are tf2's words.
pub fn validate_lookup_frame_id(frame_id: &str) -> Result<(), &'static str> {
    if frame_id.is_empty() {
        Err("in tf2 frame_ids cannot be empty")
    } else if frame_id.starts_with('/') {
        Err("in tf2 frame_ids cannot start with a '/'")
    } else {
        Ok(())
    }
}

/// The stored edge of one child frame.
#[derive(Debug, Clone, PartialEq)]
struct Edge {
    parent: String,
    parent_from_child: RigidTransform,
    stamp: Time,
}

/// A tree (forest) of the latest transform of every child frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfBuffer {
    /// Child frame -> its edge to its parent.
    edges: BTreeMap<String, Edge>,
}

impl TfBuffer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of stored transforms (one per child frame).
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Removes every transform.
    pub fn clear(&mut self) {
        self.edges.clear();
    }

    /// All frames in the tree (children and parents, roots included), sorted.
    pub fn frames(&self) -> Vec<&str> {
        let set: BTreeSet<&str> = self
            .edges
            .iter()
            .flat_map(|(child, edge)| [child.as_str(), edge.parent.as_str()])
            .collect();
        set.into_iter().collect()
    }

    /// Whether `frame` appears in the tree, as a child or as a parent.
    pub fn contains(&self, frame: &str) -> bool {
        self.edges.contains_key(frame) || self.edges.values().any(|e| e.parent == frame)
    }

    /// The parent of `frame`, or `None` for a root or an unknown frame.
    pub fn parent_of(&self, frame: &str) -> Option<&str> {
        self.edges.get(frame).map(|e| e.parent.as_str())
    }

    /// The stamp of the stored transform of child `frame`.
    pub fn stamp_of(&self, frame: &str) -> Option<Time> {
        self.edges.get(frame).map(|e| e.stamp)
    }

    /// The stored `parent_from_child` of child `frame`.
    pub fn parent_from_child(&self, frame: &str) -> Option<&RigidTransform> {
        self.edges.get(frame).map(|e| &e.parent_from_child)
    }

    /// The root of the tree `frame` belongs to (the frame itself for a root or unknown frame).
    pub fn root_of<'a>(&'a self, frame: &'a str) -> &'a str {
        let mut current = frame;
        // The forest has no cycles (insert guarantees it); the bound is only a safeguard.
        for _ in 0..=self.edges.len() {
            match self.edges.get(current) {
                Some(edge) => current = &edge.parent,
                None => break,
            }
        }
        current
    }

    /// Inserts (or replaces) the transform of `msg.child_frame_id` in `msg.header.frame_id`.
    ///
    /// On error the buffer is unchanged, so the previous good transform of that child is kept.
    pub fn insert(&mut self, msg: &TransformStamped) -> Result<(), TfError> {
        let (parent, child, parent_from_child) = validated(msg)?;

        // The new edge closes a cycle iff `child` is an ancestor of `parent`. The walk up from
        // `parent` never uses the edge of `child` before reaching it, so the replaced edge does
        // not matter.
        let mut up = vec![parent.to_string()];
        let mut current = parent;
        while let Some(edge) = self.edges.get(current) {
            current = &edge.parent;
            up.push(current.to_string());
            if current == child {
                up.reverse();
                return Err(TfError::Cycle {
                    parent: parent.to_string(),
                    child: child.to_string(),
                    path: up,
                });
            }
            if up.len() > self.edges.len() + 1 {
                break; // safeguard; cannot happen in a forest
            }
        }

        self.edges.insert(
            child.to_string(),
            Edge {
                parent: parent.to_string(),
                parent_from_child,
                stamp: msg.header.stamp,
            },
        );
        Ok(())
    }

    /// Inserts every transform of a `/tf` or `/tf_static` message, in order; returns the errors
    /// of the rejected ones (the others are inserted).
    pub fn insert_message(&mut self, msg: &TFMessage) -> Vec<TfError> {
        msg.transforms
            .iter()
            .filter_map(|t| self.insert(t).err())
            .collect()
    }

    /// `target_from_source`: maps a point in `source_frame` into `target_frame`.
    ///
    /// Identity when the two frame ids are equal, even if the frame is not in the tree (as tf2
    /// does). Otherwise each must be a valid tf2 frame id (not empty, no leading `/`:
    /// [`TfError::InvalidLookupFrame`], tf2's message) and both must be in the same tree; the
    /// chain goes through their lowest common ancestor.
    pub fn lookup(
        &self,
        target_frame: &str,
        source_frame: &str,
    ) -> Result<RigidTransform, TfError> {
        let (target, source) = (target_frame, source_frame);
        // As tf2: equal frame ids are the identity before any check (tf2 even for empty ids;
        // we refuse those below).
        if target == source && !target.is_empty() {
            return Ok(RigidTransform::IDENTITY);
        }
        for (argument, frame) in [("target", target), ("source", source)] {
            validate_lookup_frame_id(frame).map_err(|reason| TfError::InvalidLookupFrame {
                argument,
                frame: frame.to_string(),
                reason: reason.to_string(),
            })?;
        }
        let not_connected = |reason: String| TfError::NotConnected {
            target: target.to_string(),
            source: source.to_string(),
            reason,
        };

        match (self.contains(target), self.contains(source)) {
            (true, true) => {}
            (false, false) => {
                return Err(not_connected(format!(
                    "neither '{source}' nor '{target}' is in the tree (waiting for /tf_static){}",
                    self.known_frames_suffix()
                )))
            }
            (true, false) => {
                return Err(not_connected(format!(
                    "'{source}' is not in the tree (waiting for /tf_static){}",
                    self.known_frames_suffix()
                )))
            }
            (false, true) => {
                return Err(not_connected(format!(
                    "'{target}' is not in the tree (waiting for /tf_static){}",
                    self.known_frames_suffix()
                )))
            }
        }

        let source_chain = self.chain_to_root(source);
        let target_chain = self.chain_to_root(target);
        let source_index: HashMap<&str, usize> = source_chain
            .iter()
            .enumerate()
            .map(|(i, (frame, _))| (*frame, i))
            .collect();
        for (frame, ancestor_from_target) in &target_chain {
            if let Some(&i) = source_index.get(frame) {
                let ancestor_from_source = &source_chain[i].1;
                let target_from_source =
                    ancestor_from_target.inverse().compose(ancestor_from_source);
                // Each transform is finite, but huge translations can overflow when chained.
                if !(target_from_source.translation.is_finite()
                    && target_from_source.rotation.is_finite())
                {
                    return Err(TfError::InvalidTransform {
                        parent: target.to_string(),
                        child: source.to_string(),
                        reason: "the chained transform is not finite (translations too large)"
                            .into(),
                    });
                }
                return Ok(target_from_source);
            }
        }
        let root = |chain: &[(&'_ str, RigidTransform)]| {
            chain.last().map(|(f, _)| f.to_string()).unwrap_or_default()
        };
        Err(not_connected(format!(
            "'{source}' and '{target}' are in different trees (roots '{}' and '{}')",
            root(&source_chain),
            root(&target_chain)
        )))
    }

    /// `frame` and its ancestors up to the root, each with `ancestor_from_frame`.
    fn chain_to_root<'a>(&'a self, frame: &'a str) -> Vec<(&'a str, RigidTransform)> {
        let mut chain = vec![(frame, RigidTransform::IDENTITY)];
        let mut current = frame;
        let mut current_from_frame = RigidTransform::IDENTITY;
        while let Some(edge) = self.edges.get(current) {
            current_from_frame = edge.parent_from_child.compose(&current_from_frame);
            current = &edge.parent;
            chain.push((current, current_from_frame));
            if chain.len() > self.edges.len() + 1 {
                break; // safeguard; cannot happen in a forest
            }
        }
        chain
    }

    fn known_frames_suffix(&self) -> String {
        let frames = self.frames();
        if frames.is_empty() {
            return "; no transform received yet".to_string();
        }
        let listed: Vec<&str> = frames.iter().copied().take(MAX_LISTED_FRAMES).collect();
        let more = frames.len().saturating_sub(MAX_LISTED_FRAMES);
        if more > 0 {
            format!("; known frames: {} and {more} more", listed.join(", "))
        } else {
            format!("; known frames: {}", listed.join(", "))
        }
    }
}

/// A transform as tf2 accepts it on insertion: frame ids stripped of one leading `/`, not
/// empty, not their own parent; a finite rotation within tf2's tolerance of unit length
/// (normalised) and a finite translation. Returns `(parent, child, parent_from_child)`.
pub(crate) fn validated(msg: &TransformStamped) -> Result<(&str, &str, RigidTransform), TfError> {
    let parent = normalize_frame_id(&msg.header.frame_id);
    let child = normalize_frame_id(&msg.child_frame_id);
    let invalid_id = |reason: &str| TfError::InvalidFrameId {
        parent: parent.to_string(),
        child: child.to_string(),
        reason: reason.to_string(),
    };
    if parent.is_empty() {
        return Err(invalid_id("header.frame_id (the parent frame) is empty"));
    }
    if child.is_empty() {
        return Err(invalid_id("child_frame_id is empty"));
    }
    if parent == child {
        return Err(TfError::SelfParent {
            frame: child.to_string(),
        });
    }
    let t = msg.transform.translation;
    let q = msg.transform.rotation;
    let parent_from_child = RigidTransform::from_quat_translation(
        child,
        DQuat::from_xyzw(q.x, q.y, q.z, q.w),
        DVec3::new(t.x, t.y, t.z),
    )
    .map_err(|e| {
        let reason = match e {
            GeometryError::InvalidPose { reason, .. } => reason,
            other => other.to_string(),
        };
        TfError::InvalidTransform {
            parent: parent.to_string(),
            child: child.to_string(),
            reason: format!(
                "{reason} (translation = [{}, {}, {}], rotation xyzw = [{}, {}, {}, {}])",
                t.x, t.y, t.z, q.x, q.y, q.z, q.w
            ),
        }
    })?;
    Ok((parent, child, parent_from_child))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, Transform, Vector3};

    /// The standard camera_link -> camera_optical rotation (rpy = -pi/2, 0, -pi/2).
    const OPTICAL: [f64; 4] = [-0.5, 0.5, -0.5, 0.5];
    const IDENT: [f64; 4] = [0.0, 0.0, 0.0, 1.0];
    const BASELINE_HALF: f64 = 0.06;
    const TILT_DEG: f64 = 15.0; // rig pitched about base y
    const YAW_DEG: f64 = -10.0; // cam1 toed in about rig z

    fn ts(parent: &str, child: &str, t: [f64; 3], q: [f64; 4]) -> TransformStamped {
        TransformStamped {
            header: Header {
                stamp: Time { sec: 7, nanosec: 0 },
                frame_id: parent.to_string(),
            },
            child_frame_id: child.to_string(),
            transform: Transform {
                translation: Vector3 {
                    x: t[0],
                    y: t[1],
                    z: t[2],
                },
                rotation: Quaternion {
                    x: q[0],
                    y: q[1],
                    z: q[2],
                    w: q[3],
                },
            },
        }
    }

    fn half_angle(deg: f64) -> (f64, f64) {
        let h = deg.to_radians() / 2.0;
        (h.sin(), h.cos())
    }

    fn rig_buffer() -> TfBuffer {
        let (ty_s, ty_c) = half_angle(TILT_DEG);
        let (yz_s, yz_c) = half_angle(YAW_DEG);
        let msg = TFMessage {
            transforms: vec![
                ts("base", "rig", [0.3, 0.0, 1.2], [0.0, ty_s, 0.0, ty_c]),
                ts("rig", "cam0", [0.0, BASELINE_HALF, 0.0], IDENT),
                ts("cam0", "cam0_optical", [0.0, 0.0, 0.0], OPTICAL),
                ts(
                    "rig",
                    "cam1",
                    [0.0, -BASELINE_HALF, 0.0],
                    [0.0, 0.0, yz_s, yz_c],
                ),
                ts("cam1", "cam1_optical", [0.0, 0.0, 0.0], OPTICAL),
                ts("base", "imu", [0.1, 0.0, 0.2], IDENT),
            ],
        };
        let mut buffer = TfBuffer::new();
        let errors = buffer.insert_message(&msg);
        assert!(errors.is_empty(), "{errors:?}");
        buffer
    }

    // Hand-written maps, independent of glam / RigidTransform.
    /// camera_link_from_optical for the OPTICAL quaternion: optical (x right, y down, z fwd)
    /// -> link (x fwd, y left, z up).
    fn link_from_optical(p: DVec3) -> DVec3 {
        DVec3::new(p.z, -p.x, -p.y)
    }
    fn optical_from_link(p: DVec3) -> DVec3 {
        DVec3::new(-p.y, -p.z, p.x)
    }
    fn rot_z(deg: f64, p: DVec3) -> DVec3 {
        let (s, c) = deg.to_radians().sin_cos();
        DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
    }
    fn rot_y(deg: f64, p: DVec3) -> DVec3 {
        let (s, c) = deg.to_radians().sin_cos();
        DVec3::new(c * p.x + s * p.z, p.y, -s * p.x + c * p.z)
    }

    fn assert_close(a: DVec3, b: DVec3, what: &str) {
        assert!((a - b).length() < 1e-9, "{what}: {a} vs {b}");
    }

    fn assert_identity(t: &RigidTransform, what: &str) {
        assert!(t.translation.length() < 1e-9, "{what}: {t:?}");
        assert!(
            t.rotation.dot(DQuat::IDENTITY).abs() > 1.0 - 1e-12,
            "{what}: {t:?}"
        );
    }

    #[test]
    fn optical_quaternion_matches_hand_formula() {
        let b = rig_buffer();
        let link_from_opt = b.lookup("cam0", "cam0_optical").unwrap();
        let p = DVec3::new(0.3, -0.7, 2.5);
        assert_close(
            link_from_opt.transform_point(p),
            link_from_optical(p),
            "cam0_from_cam0_optical",
        );
        assert_close(
            b.lookup("cam0_optical", "cam0").unwrap().transform_point(p),
            optical_from_link(p),
            "cam0_optical_from_cam0",
        );
    }

    #[test]
    fn camera_to_camera_matches_hand_composition() {
        let b = rig_buffer();
        let cam0_opt_from_cam1_opt = b.lookup("cam0_optical", "cam1_optical").unwrap();
        for p in [
            DVec3::new(0.1, -0.2, 2.0),
            DVec3::new(-1.5, 0.4, 7.0),
            DVec3::ZERO,
        ] {
            // cam1_optical -> cam1 -> rig -> cam0 -> cam0_optical, by hand.
            let in_cam1 = link_from_optical(p);
            let in_rig = rot_z(YAW_DEG, in_cam1) + DVec3::new(0.0, -BASELINE_HALF, 0.0);
            let in_cam0 = in_rig - DVec3::new(0.0, BASELINE_HALF, 0.0);
            let expected = optical_from_link(in_cam0);
            assert_close(cam0_opt_from_cam1_opt.transform_point(p), expected, "p");
        }
        // cam1's optical centre, seen from cam0_optical: 12 cm to the right (+x), same height.
        assert_close(
            cam0_opt_from_cam1_opt.translation,
            DVec3::new(2.0 * BASELINE_HALF, 0.0, 0.0),
            "baseline",
        );
    }

    #[test]
    fn lookup_through_the_root_matches_hand_composition() {
        let b = rig_buffer();
        let imu_from_cam0_opt = b.lookup("imu", "cam0_optical").unwrap();
        let p = DVec3::new(0.25, 0.1, 3.0);
        let in_rig = link_from_optical(p) + DVec3::new(0.0, BASELINE_HALF, 0.0);
        let in_base = rot_y(TILT_DEG, in_rig) + DVec3::new(0.3, 0.0, 1.2);
        let in_imu = in_base - DVec3::new(0.1, 0.0, 0.2);
        assert_close(imu_from_cam0_opt.transform_point(p), in_imu, "imu");
        // Target is the root itself.
        assert_close(
            b.lookup("base", "cam0_optical").unwrap().transform_point(p),
            in_base,
            "base",
        );
        // Ancestor lookups in both directions.
        assert_close(
            b.lookup("rig", "cam0_optical").unwrap().transform_point(p),
            in_rig,
            "rig",
        );
        assert_close(
            b.lookup("cam0_optical", "base")
                .unwrap()
                .transform_point(in_base),
            p,
            "cam0_optical from base",
        );
    }

    #[test]
    fn inverse_lookups_are_inverses() {
        let b = rig_buffer();
        let frames: Vec<String> = b.frames().iter().map(|f| f.to_string()).collect();
        assert_eq!(frames.len(), 7);
        for a in &frames {
            for c in &frames {
                let a_from_c = b.lookup(a, c).unwrap();
                let c_from_a = b.lookup(c, a).unwrap();
                assert_identity(&a_from_c.compose(&c_from_a), &format!("{a} <-> {c}"));
                // Chaining via a third frame agrees with the direct lookup.
                let via = b
                    .lookup(a, "imu")
                    .unwrap()
                    .compose(&b.lookup("imu", c).unwrap());
                let p = DVec3::new(0.5, -0.25, 1.75);
                assert_close(
                    via.transform_point(p),
                    a_from_c.transform_point(p),
                    &format!("{a} <- imu <- {c}"),
                );
            }
        }
    }

    #[test]
    fn same_frame_is_identity() {
        let b = rig_buffer();
        assert_eq!(b.lookup("rig", "rig").unwrap(), RigidTransform::IDENTITY);
        // tf2 answers equal ids before it checks them.
        assert_eq!(b.lookup("/rig", "/rig").unwrap(), RigidTransform::IDENTITY);
        // As in tf2, even for a frame the buffer has never seen.
        assert_eq!(
            TfBuffer::new().lookup("x", "x").unwrap(),
            RigidTransform::IDENTITY
        );
    }

    #[test]
    fn accessors() {
        let b = rig_buffer();
        assert_eq!(b.len(), 6);
        assert!(!b.is_empty());
        assert_eq!(
            b.frames(),
            vec![
                "base",
                "cam0",
                "cam0_optical",
                "cam1",
                "cam1_optical",
                "imu",
                "rig"
            ]
        );
        assert_eq!(b.parent_of("cam1_optical"), Some("cam1"));
        assert_eq!(b.parent_of("/cam1"), None);
        assert_eq!(b.parent_of("base"), None);
        assert_eq!(b.parent_of("nope"), None);
        assert!(b.contains("base"));
        assert!(!b.contains("nope"));
        assert_eq!(b.root_of("cam1_optical"), "base");
        assert_eq!(b.stamp_of("rig"), Some(Time { sec: 7, nanosec: 0 }));
        assert_eq!(
            b.parent_from_child("cam0").map(|t| t.translation),
            Some(DVec3::new(0.0, BASELINE_HALF, 0.0))
        );
    }

    #[test]
    fn unknown_frame_errors_say_what_is_missing() {
        let b = rig_buffer();
        let err = b.lookup("rig", "cam9_optical").unwrap_err();
        assert!(matches!(&err, TfError::NotConnected { target, source, .. }
            if target == "rig" && source == "cam9_optical"));
        let msg = err.to_string();
        assert!(
            msg.starts_with(
                "no transform from 'cam9_optical' to 'rig': 'cam9_optical' is not in the tree \
                 (waiting for /tf_static); known frames: base, cam0,"
            ),
            "{msg}"
        );
        let msg = b.lookup("cam9", "rig").unwrap_err().to_string();
        assert!(msg.contains("'cam9' is not in the tree"), "{msg}");
        let msg = b.lookup("x", "y").unwrap_err().to_string();
        assert!(msg.contains("neither 'y' nor 'x' is in the tree"), "{msg}");
        let msg = TfBuffer::new()
            .lookup("rig", "cam1_optical")
            .unwrap_err()
            .to_string();
        assert_eq!(
            msg,
            "no transform from 'cam1_optical' to 'rig': neither 'cam1_optical' nor 'rig' is in \
             the tree (waiting for /tf_static); no transform received yet"
        );
        let msg = b.lookup("", "rig").unwrap_err().to_string();
        assert_eq!(
            msg,
            "invalid target frame id \"\": in tf2 frame_ids cannot be empty"
        );
        assert!(b.lookup("", "").is_err());
    }

    #[test]
    fn disconnected_trees_name_their_roots() {
        let mut b = rig_buffer();
        b.insert(&ts("odom", "other", [1.0, 0.0, 0.0], IDENT))
            .unwrap();
        let err = b.lookup("other", "cam0_optical").unwrap_err();
        assert_eq!(
            err.to_string(),
            "no transform from 'cam0_optical' to 'other': 'cam0_optical' and 'other' are in \
             different trees (roots 'base' and 'odom')"
        );
        // Joining the trees fixes it.
        b.insert(&ts("base", "odom", [0.0, 0.0, 0.0], IDENT))
            .unwrap();
        assert!(b.lookup("other", "cam0_optical").is_ok());
    }

    #[test]
    fn nan_or_infinite_rejected_and_last_good_kept() {
        let mut b = rig_buffer();
        let before = b.lookup("cam0_optical", "cam1_optical").unwrap();
        let err = b
            .insert(&ts(
                "rig",
                "cam1",
                [0.0, 0.5, 0.0],
                [f64::NAN, 0.0, 0.0, 1.0],
            ))
            .unwrap_err();
        assert!(
            matches!(&err, TfError::InvalidTransform { parent, child, .. }
            if parent == "rig" && child == "cam1")
        );
        assert!(err.to_string().contains("NaN"), "{err}");
        let err = b
            .insert(&ts("rig", "cam1", [f64::INFINITY, 0.0, 0.0], IDENT))
            .unwrap_err();
        assert!(matches!(err, TfError::InvalidTransform { .. }));
        assert_eq!(b.lookup("cam0_optical", "cam1_optical").unwrap(), before);
        assert_eq!(b.len(), 6);
    }

    #[test]
    fn non_unit_quaternion_rejected_near_unit_normalised() {
        let mut b = rig_buffer();
        let before = b.parent_from_child("cam1").copied();
        let err = b
            .insert(&ts("rig", "cam1", [0.0; 3], [0.0, 0.0, 0.0, 1.1]))
            .unwrap_err();
        assert!(err.to_string().contains("not unit length"), "{err}");
        let err = b
            .insert(&ts("rig", "cam1", [0.0; 3], [0.0, 0.0, 0.0, 0.0]))
            .unwrap_err();
        assert!(matches!(err, TfError::InvalidTransform { .. }));
        assert_eq!(b.parent_from_child("cam1").copied(), before);
        // Just outside tf2's tolerance (|x²+y²+z²+w² - 1| = 0.0101): refused.
        let err = b
            .insert(&ts("rig", "cam1", [0.0; 3], [0.0, 0.0, 0.0, 1.00504]))
            .unwrap_err();
        assert!(err.to_string().contains("tf2 accepts"), "{err}");
        assert_eq!(b.parent_from_child("cam1").copied(), before);
        // A hand-typed static_transform_publisher quaternion (0.71, 0, 0, 0.71): squared
        // norm 1.0082, accepted as tf2 accepts it and normalised: 90 degrees about x.
        b.insert(&ts("rig", "cam1", [0.0; 3], [0.71, 0.0, 0.0, 0.71]))
            .unwrap();
        let parent_from_child = b.parent_from_child("cam1").unwrap();
        assert!((parent_from_child.rotation.length() - 1.0).abs() < 1e-12);
        assert_close(
            parent_from_child.transform_point(DVec3::Y),
            DVec3::Z,
            "90 degrees about x",
        );
    }

    #[test]
    fn chained_transforms_that_overflow_are_an_error() {
        // Found by the cdr_tf fuzz target: each translation is finite, their chain is not.
        let mut buf = TfBuffer::new();
        buf.insert(&ts("root", "a", [1e308, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]))
            .unwrap();
        buf.insert(&ts("root", "b", [-1e308, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]))
            .unwrap();
        let e = buf.lookup("a", "b").unwrap_err();
        assert!(matches!(e, TfError::InvalidTransform { .. }), "{e}");
        assert!(e.to_string().contains("not finite"), "{e}");
        assert!(buf.lookup("root", "b").is_ok());
    }

    #[test]
    fn bad_frame_ids_rejected() {
        let mut b = rig_buffer();
        let err = b.insert(&ts("cam0", "cam0", [0.0; 3], IDENT)).unwrap_err();
        assert_eq!(
            err,
            TfError::SelfParent {
                frame: "cam0".into()
            }
        );
        assert!(matches!(
            b.insert(&ts("/cam0", "cam0", [0.0; 3], IDENT)),
            Err(TfError::SelfParent { .. })
        ));
        assert!(matches!(
            b.insert(&ts("", "x", [0.0; 3], IDENT)),
            Err(TfError::InvalidFrameId { .. })
        ));
        let err = b.insert(&ts("rig", "/", [0.0; 3], IDENT)).unwrap_err();
        assert!(err.to_string().contains("child_frame_id is empty"), "{err}");
        assert_eq!(b.len(), 6);
        assert_eq!(b.parent_of("cam0"), Some("rig"));
    }

    #[test]
    fn cycles_rejected() {
        let mut b = rig_buffer();
        let err = b.insert(&ts("rig", "base", [0.0; 3], IDENT)).unwrap_err();
        assert_eq!(
            err,
            TfError::Cycle {
                parent: "rig".into(),
                child: "base".into(),
                path: vec!["base".into(), "rig".into()],
            }
        );
        let err = b
            .insert(&ts("cam0_optical", "rig", [0.0; 3], IDENT))
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            "rejected transform 'cam0_optical' -> 'rig': it would create a cycle ('rig' is \
             already an ancestor of 'cam0_optical': rig -> cam0 -> cam0_optical)"
        );
        // Unchanged.
        assert_eq!(b.parent_of("rig"), Some("base"));
        assert_eq!(b.parent_of("base"), None);
        assert!(b.lookup("cam0_optical", "imu").is_ok());
    }

    #[test]
    fn reparenting_replaces() {
        let mut b = rig_buffer();
        b.insert(&ts("base", "cam1", [0.0, 0.0, 2.0], IDENT))
            .unwrap();
        assert_eq!(b.len(), 6);
        assert_eq!(b.parent_of("cam1"), Some("base"));
        let base_from_cam1 = b.lookup("base", "cam1").unwrap();
        assert_identity(
            &RigidTransform {
                rotation: base_from_cam1.rotation,
                translation: base_from_cam1.translation - DVec3::new(0.0, 0.0, 2.0),
            },
            "re-parented cam1",
        );
        // The old branch no longer goes through rig.
        let p = DVec3::new(0.0, 0.0, 1.0);
        assert_close(
            b.lookup("base", "cam1_optical").unwrap().transform_point(p),
            DVec3::new(1.0, 0.0, 2.0),
            "cam1_optical forward axis in base",
        );
        // Re-parenting a subtree root under a frame of another tree is fine too.
        b.insert(&ts("odom", "base", [0.0; 3], IDENT)).unwrap();
        assert_eq!(b.root_of("cam0_optical"), "odom");
    }

    #[test]
    fn leading_slash_is_stripped_on_insert_and_refused_in_lookups() {
        let mut b = TfBuffer::new();
        b.insert(&ts("/base", "/rig", [1.0, 2.0, 3.0], IDENT))
            .unwrap();
        b.insert(&ts("rig", "/cam0", [0.5, 0.0, 0.0], IDENT))
            .unwrap();
        assert_eq!(b.frames(), vec!["base", "cam0", "rig"]);
        assert_eq!(b.parent_of("rig"), Some("base"));
        let expected = DVec3::new(1.5, 2.0, 3.0);
        assert_close(
            b.lookup("base", "cam0").unwrap().translation,
            expected,
            "plain",
        );
        // Lookups with a leading '/' are refused, as tf2's validateFrameId refuses them.
        let err = b.lookup("base", "/cam0").unwrap_err();
        assert_eq!(
            err,
            TfError::InvalidLookupFrame {
                argument: "source",
                frame: "/cam0".into(),
                reason: "in tf2 frame_ids cannot start with a '/'".into(),
            }
        );
        assert_eq!(
            err.to_string(),
            "invalid source frame id \"/cam0\": in tf2 frame_ids cannot start with a '/'"
        );
        let err = b.lookup("/base", "cam0").unwrap_err();
        assert!(
            matches!(
                &err,
                TfError::InvalidLookupFrame {
                    argument: "target",
                    ..
                }
            ),
            "{err}"
        );
        // tf2 strips one slash only: "//x" is stored as "/x", which no lookup can name.
        b.insert(&ts("base", "//x", [0.0; 3], IDENT)).unwrap();
        assert!(b.contains("/x"));
        assert!(b.lookup("base", "/x").is_err());
        // "/rig" and "rig" are the same child: replaced, not duplicated.
        b.insert(&ts("base", "rig", [0.0; 3], IDENT)).unwrap();
        assert_eq!(b.len(), 3);
        assert_eq!(normalize_frame_id("/a/b"), "a/b");
        assert_eq!(normalize_frame_id("a"), "a");
    }

    #[test]
    fn insert_message_reports_only_rejected() {
        let mut b = TfBuffer::new();
        let errors = b.insert_message(&TFMessage {
            transforms: vec![
                ts("base", "rig", [0.0; 3], IDENT),
                ts("rig", "rig", [0.0; 3], IDENT),
                ts("rig", "cam0", [0.0; 3], [0.0, 0.0, 0.0, 2.0]),
                ts("rig", "cam1", [0.0; 3], IDENT),
                ts("cam1", "base", [0.0; 3], IDENT),
            ],
        });
        assert_eq!(errors.len(), 3, "{errors:?}");
        assert!(matches!(errors[0], TfError::SelfParent { .. }));
        assert!(matches!(errors[1], TfError::InvalidTransform { .. }));
        assert!(matches!(errors[2], TfError::Cycle { .. }));
        assert_eq!(b.frames(), vec!["base", "cam1", "rig"]);
    }
}
