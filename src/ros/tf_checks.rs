//! tf2's rules for what goes into a transform tree and what may be asked of it, shared by
//! [`super::tf_history::TfHistory`] (the tree) and [`super::tf::TfBuffer`] (its static view):
//! the frame-id rules (one leading `/` stripped on insertion, none allowed in a lookup), the
//! checks of an inserted transform, and the errors: [`TfError`] (a transform refused),
//! [`TfInsertError`] (the history's refusals, those and data too old) and [`TfLookupError`]
//! (why a lookup at a time gave no transform).

use std::fmt;
use std::time::Duration;

use glam::{DQuat, DVec3};

use crate::geometry::{GeometryError, RigidTransform};
use crate::msgs::{Time, TransformStamped};

/// Why a transform was refused (by [`super::tf_history::TfHistory::insert`] or
/// [`super::tf::TfBuffer::insert`]) or a [`super::tf::TfBuffer::lookup`] failed. None is fatal:
/// a rejected insertion leaves the tree unchanged.
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
    /// A frame id given to [`super::tf::TfBuffer::lookup`] that tf2 refuses: empty, or starting
    /// with `/`.
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

/// Why a transform was not inserted into a [`super::tf_history::TfHistory`]. The history is then unchanged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TfInsertError {
    /// Refused by tf2's rules (bad frame id, self-parent, bad rotation or translation), or
    /// because it would close a cycle.
    #[error(transparent)]
    Rejected(#[from] TfError),
    /// A dynamic transform older than the cache time before the newest stamp of its edge
    /// (tf2's `TF_OLD_DATA`: "ignoring data from the past").
    #[error(
        "ignoring transform '{parent}' -> '{child}' stamped {} s: older than the {} s cache \
         before the newest stamp {} s of '{child}' (tf2's TF_OLD_DATA)",
        secs(.stamp),
        .cache_time.as_secs_f64(),
        secs(.newest)
    )]
    TooOld {
        parent: String,
        child: String,
        stamp: Time,
        newest: Time,
        cache_time: Duration,
    },
}

/// Why [`super::tf_history::TfHistory::lookup_at`] gave no transform.
///
/// (The frames are `target_frame` / `source_frame`, not `target` / `source`: `thiserror` would
/// take a field named `source` for the underlying error.)
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TfLookupError {
    /// A frame id tf2 refuses in a lookup: empty, or starting with `/`.
    #[error("invalid {argument} frame id \"{frame}\": {reason}")]
    InvalidFrame {
        /// "target" or "source".
        argument: &'static str,
        frame: String,
        reason: String,
    },
    /// Unknown frame, or the two frames are in different trees. `reason` lists the known
    /// frames or names the two roots.
    #[error("no transform from '{source_frame}' to '{target_frame}': {reason}")]
    NotConnected {
        target_frame: String,
        source_frame: String,
        reason: String,
    },
    /// `requested` is after the newest entry of the dynamic edge `parent -> child`: the
    /// transform may still arrive, waiting may help.
    #[error(
        "no transform from '{source_frame}' to '{target_frame}': lookup would require \
         extrapolation into the future: requested {} s, newest {} s for frame \
         '{parent}' -> '{child}'",
        secs(.requested),
        secs(.newest)
    )]
    ExtrapolationFuture {
        target_frame: String,
        source_frame: String,
        parent: String,
        child: String,
        requested: Time,
        newest: Time,
    },
    /// `requested` is before the oldest entry of the dynamic edge `parent -> child` (older than
    /// the cache holds, or before the first transform arrived): waiting will not help.
    #[error(
        "no transform from '{source_frame}' to '{target_frame}': lookup would require \
         extrapolation into the past: requested {} s, oldest {} s for frame \
         '{parent}' -> '{child}'",
        secs(.requested),
        secs(.oldest)
    )]
    ExtrapolationPast {
        target_frame: String,
        source_frame: String,
        parent: String,
        child: String,
        requested: Time,
        oldest: Time,
    },
    /// Every stored transform is finite, but their chain is not (huge translations).
    #[error(
        "no transform from '{source_frame}' to '{target_frame}': the chained transform is not \
         finite (translations too large)"
    )]
    NonFinite {
        target_frame: String,
        source_frame: String,
    },
}

impl TfLookupError {
    /// Whether the lookup asked for a time after the newest transform of an edge: the
    /// transform may still arrive on `/tf`, so retrying later may succeed.
    pub fn is_future(&self) -> bool {
        matches!(self, TfLookupError::ExtrapolationFuture { .. })
    }

    /// Whether waiting may help at all: [`Self::is_future`], or a frame not (yet) connected
    /// (its first transform may not have arrived). Past extrapolation, invalid frame ids and
    /// non-finite chains do not fix themselves.
    pub fn may_resolve_by_waiting(&self) -> bool {
        matches!(
            self,
            TfLookupError::ExtrapolationFuture { .. } | TfLookupError::NotConnected { .. }
        )
    }
}

/// A [`Time`] shown as seconds, exactly (`12.5`, `1700000000.000000001`, `-0.5`).
struct Secs(Time);

fn secs(time: &Time) -> Secs {
    Secs(*time)
}

impl fmt::Display for Secs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let nanos = self.0.to_nanos();
        let sign = if nanos < 0 { "-" } else { "" };
        let abs = nanos.unsigned_abs();
        let (whole, frac) = (abs / 1_000_000_000, abs % 1_000_000_000);
        if frac == 0 {
            write!(f, "{sign}{whole}")
        } else {
            let digits = format!("{frac:09}");
            write!(f, "{sign}{whole}.{}", digits.trim_end_matches('0'))
        }
    }
}

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

    const SEC: i64 = 1_000_000_000;

    fn t(nanos: i64) -> Time {
        Time::from_nanos(nanos)
    }

    #[test]
    fn seconds_are_shown_exactly() {
        assert_eq!(Secs(t(12 * SEC + 500_000_000)).to_string(), "12.5");
        assert_eq!(
            Secs(t(1_700_000_000 * SEC + 1)).to_string(),
            "1700000000.000000001"
        );
        assert_eq!(Secs(t(-SEC / 2)).to_string(), "-0.5");
        assert_eq!(Secs(t(0)).to_string(), "0");
    }
}
