//! A tf2-style buffer of static transforms for `/tf_static` (and `/tf`, without time
//! interpolation): a view of the crate's one transform tree, [`TfHistory`], whose every edge is
//! static.
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
//!   infinite values too ([`super::tf_checks`]).
//! - Only the latest transform of each child is kept (no history, no interpolation): the last
//!   accepted insertion wins, whatever its stamp.
//!
//! [`TfBuffer::lookup`] returns `target_from_source` (`point_in_target =
//! target_from_source.transform_point(point_in_source)`), chaining through the lowest common
//! ancestor of the two frames.

use crate::geometry::RigidTransform;
use crate::msgs::{TFMessage, Time, TransformStamped};

pub use super::tf_checks::{normalize_frame_id, validate_lookup_frame_id, TfError};
use super::tf_history::{TfHistory, TfInsertError, TfLookupError};

/// A tree (forest) of the latest transform of every child frame: a [`TfHistory`] into which
/// every transform goes as a static one.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfBuffer {
    tree: TfHistory,
}

impl TfBuffer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of stored transforms (one per child frame).
    pub fn len(&self) -> usize {
        self.tree.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tree.is_empty()
    }

    /// Removes every transform.
    pub fn clear(&mut self) {
        self.tree.clear();
    }

    /// All frames in the tree (children and parents, roots included), sorted.
    pub fn frames(&self) -> Vec<&str> {
        self.tree.frames()
    }

    /// Whether `frame` appears in the tree, as a child or as a parent.
    pub fn contains(&self, frame: &str) -> bool {
        self.tree.contains(frame)
    }

    /// The parent of `frame`, or `None` for a root or an unknown frame.
    pub fn parent_of(&self, frame: &str) -> Option<&str> {
        self.tree.parent_of(frame)
    }

    /// The stamp of the stored transform of child `frame`.
    pub fn stamp_of(&self, frame: &str) -> Option<Time> {
        self.tree.latest_of(frame).map(|(stamp, _)| stamp)
    }

    /// The stored `parent_from_child` of child `frame`.
    pub fn parent_from_child(&self, frame: &str) -> Option<&RigidTransform> {
        self.tree.latest_of(frame).map(|(_, transform)| transform)
    }

    /// The root of the tree `frame` belongs to (the frame itself for a root or unknown frame).
    pub fn root_of<'a>(&'a self, frame: &'a str) -> &'a str {
        self.tree.root_of(frame)
    }

    /// Inserts (or replaces) the transform of `msg.child_frame_id` in `msg.header.frame_id`.
    ///
    /// On error the buffer is unchanged, so the previous good transform of that child is kept.
    pub fn insert(&mut self, msg: &TransformStamped) -> Result<(), TfError> {
        self.tree.insert(msg, true).map_err(|e| match e {
            TfInsertError::Rejected(e) => e,
            // Only a dynamic transform can be too old; kept for completeness.
            other @ TfInsertError::TooOld { .. } => TfError::InvalidTransform {
                parent: msg.header.frame_id.clone(),
                child: msg.child_frame_id.clone(),
                reason: other.to_string(),
            },
        })
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
        // Static edges answer any time.
        let found =
            self.tree
                .lookup_waiting_for(target_frame, source_frame, Time::default(), "/tf_static");
        found.map_err(|e| match e {
            TfLookupError::InvalidFrame {
                argument,
                frame,
                reason,
            } => TfError::InvalidLookupFrame {
                argument,
                frame,
                reason,
            },
            TfLookupError::NotConnected {
                target_frame,
                source_frame,
                reason,
            } => TfError::NotConnected {
                target: target_frame,
                source: source_frame,
                reason,
            },
            // Each transform is finite, but huge translations can overflow when chained.
            TfLookupError::NonFinite {
                target_frame,
                source_frame,
            } => TfError::InvalidTransform {
                parent: target_frame,
                child: source_frame,
                reason: "the chained transform is not finite (translations too large)".into(),
            },
            // Only dynamic edges miss a time; kept for completeness.
            other => TfError::NotConnected {
                target: target_frame.to_string(),
                source: source_frame.to_string(),
                reason: other.to_string(),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, Transform, Vector3};
    use glam::{DQuat, DVec3};

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
