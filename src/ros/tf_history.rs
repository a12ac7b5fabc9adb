//! The transform tree: a tf2-style buffer with time history (`/tf` and `/tf_static`), the one
//! tree of the crate. [`super::tf::TfBuffer`], all a rigid rig needs, is a view of it whose
//! every edge is static. When the rig moves (a `world_frame` pose published on `/tf`), a camera
//! frame must be placed at the *image's* stamp: [`TfHistory`] keeps, per child frame, a short
//! history of stamped transforms and interpolates in it, as tf2's `BufferCore` / `TimeCache` do.
//!
//! Semantics follow tf2 (`buffer_core.cpp`, `cache.cpp`, `static_cache.cpp`):
//! - A `TransformStamped` with `header.frame_id = parent` and `child_frame_id = child` is
//!   `parent_from_child`: a point expressed in the child frame maps into the parent frame by it.
//! - Two kinds of edges. A **static** edge (`/tf_static`, `is_static = true`) is valid at any
//!   time; the last accepted insertion wins whatever its stamp (tf2's `StaticCache`). A
//!   **dynamic** edge (`/tf`) is a history of stamped transforms, sorted by stamp; an insertion
//!   with a stamp already present replaces that entry (tf2's `TimeCache::insertData`). A child
//!   frame has one edge: inserting it with the other kind replaces the edge. (tf2's
//!   `setTransformImpl` allocates a frame's cache on its first transform and then puts every
//!   later one into that cache whatever its kind, so the kind depends on arrival order; here
//!   the latest publisher's kind wins.)
//! - The history of a dynamic edge is bounded by a cache time (default 10 s, tf2's
//!   `BUFFER_CORE_DEFAULT_CACHE_TIME`) measured back from the newest stamp *of that edge*:
//!   entries older than `newest - cache_time` are pruned (tf2's `pruneList`), and an insertion
//!   older than that is refused ([`TfInsertError::TooOld`], tf2's `TF_OLD_DATA`). A hard cap on
//!   the entries of one edge (default 10 000, dropping the oldest) bounds memory whatever the
//!   stamps of hostile input.
//! - A child has one parent. tf2 stores a parent per entry; here a dynamic edge whose parent
//!   changes starts a new history (the old one is dropped), so the tree is the same at every
//!   time. An insertion that would close a cycle is refused ([`TfError::Cycle`]); tf2 accepts it
//!   and fails later lookups, but a refused edge keeps every other lookup working.
//! - Frame ids and transforms are checked by tf2's rules ([`super::tf_checks`], refusals as
//!   [`TfError`]): one leading `/` is stripped on insertion (tf2's `stripSlash`), an empty id
//!   or a self-parent is refused, a quaternion is accepted when `|x² + y² + z² + w² - 1| <
//!   0.01` and then normalised, NaN / infinite values are refused. A frame id *looked up* must
//!   pass [`validate_lookup_frame_id`] (tf2's `validateFrameId`).
//! - [`TfHistory::lookup_at`] returns `target_from_source` at a time, chaining through the
//!   lowest common ancestor. For each dynamic edge of the chain: an exact stamp returns that
//!   entry; between two entries, linear interpolation of the translation and slerp of the
//!   rotation (tf2's `TimeCache::interpolate`); before the oldest or after the newest entry, an
//!   extrapolation error (tf2 never extrapolates, so a single-entry history answers only its own
//!   stamp). [`TfLookupError::is_future`] tells a caller that waiting for `/tf` may help.
//! - Time zero means "the latest common time" (tf2's `getLatestCommonTime`): the newest time at
//!   which every dynamic edge of the chain has data, i.e. the minimum over those edges of their
//!   newest stamp. A chain of static edges only has no such time and is valid at any time.
//! - [`TfHistory::clear_dynamic`] drops every dynamic edge and keeps the static ones, as tf2's
//!   `BufferCore::clear()` does on a jump back of the ROS clock (it empties every `TimeCache`;
//!   `StaticCache::clearList` does nothing). tf2 keeps the emptied frames known; here they
//!   leave the tree until `/tf` brings them again, so a lookup through them is
//!   [`TfLookupError::NotConnected`].
//!   [`TfHistory::note_time`] detects such a jump from the clock times it is given.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::time::Duration;

use glam::{DQuat, DVec3};

use super::tf_checks::{validate_lookup_frame_id, validated, TfError};
pub use super::tf_checks::{TfInsertError, TfLookupError};
use crate::geometry::RigidTransform;
use crate::msgs::{TFMessage, Time, TransformStamped};

/// tf2's default cache time (`tf2::BUFFER_CORE_DEFAULT_CACHE_TIME`, 10 s).
pub const DEFAULT_CACHE_TIME: Duration = Duration::from_secs(10);

/// Default cap on the entries of one dynamic edge: 10 s of a 1 kHz publisher.
pub const DEFAULT_MAX_ENTRIES: usize = 10_000;

/// How far the clock may step back before [`TfHistory::note_time`] calls it a jump (1 s).
pub const TIME_JUMP_TOLERANCE: Duration = Duration::from_secs(1);

/// How many known frames an "is not in the tree" message lists at most.
const MAX_LISTED_FRAMES: usize = 20;

/// What a frame not in the tree waits for, as [`TfLookupError::NotConnected`] says it.
const TF_TOPICS: &str = "/tf or /tf_static";

/// One stamped transform, stamp in nanoseconds ([`Time::to_nanos`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    stamp: i64,
    parent_from_child: RigidTransform,
}

#[derive(Debug, Clone, PartialEq)]
enum History {
    /// `/tf_static`: valid at any time.
    Static(Entry),
    /// `/tf`: never empty, sorted by stamp, stamps unique.
    Dynamic(VecDeque<Entry>),
}

/// The edge of one child frame to its parent.
#[derive(Debug, Clone, PartialEq)]
struct Edge {
    parent: String,
    history: History,
}

/// Why one edge has no value at a time.
enum EdgeMiss {
    Past { oldest: i64 },
    Future { newest: i64 },
}

impl Edge {
    /// `parent_from_child` at `time` (ns).
    fn at(&self, time: i64) -> Result<RigidTransform, EdgeMiss> {
        let entries = match &self.history {
            History::Static(entry) => return Ok(entry.parent_from_child),
            History::Dynamic(entries) => entries,
        };
        let (Some(oldest), Some(newest)) = (entries.front(), entries.back()) else {
            // Never stored empty; answer as tf2 answers an empty cache.
            return Err(EdgeMiss::Future { newest: i64::MIN });
        };
        if time < oldest.stamp {
            return Err(EdgeMiss::Past {
                oldest: oldest.stamp,
            });
        }
        if time > newest.stamp {
            return Err(EdgeMiss::Future {
                newest: newest.stamp,
            });
        }
        // First entry with stamp >= time; exists because time <= newest.
        let i = entries.partition_point(|e| e.stamp < time);
        match (
            i.checked_sub(1).and_then(|j| entries.get(j)),
            entries.get(i),
        ) {
            (_, Some(hit)) if hit.stamp == time => Ok(hit.parent_from_child),
            (Some(before), Some(after)) => Ok(interpolate(before, after, time)),
            // Unreachable given the bounds checks above; refuse rather than guess.
            _ => Err(EdgeMiss::Future {
                newest: newest.stamp,
            }),
        }
    }

    fn newest_stamp(&self) -> Option<i64> {
        match &self.history {
            History::Static(_) => None,
            History::Dynamic(entries) => entries.back().map(|e| e.stamp),
        }
    }
}

/// tf2's `TimeCache::interpolate`: lerp of the translation, slerp of the rotation, at the
/// fraction of `time` between the two stamps (`before.stamp < time < after.stamp`).
fn interpolate(before: &Entry, after: &Entry, time: i64) -> RigidTransform {
    // Differences of i64 nanoseconds within one cache are far below 2^53: exact in f64.
    let span = after.stamp.saturating_sub(before.stamp) as f64;
    let s = (time.saturating_sub(before.stamp) as f64 / span).clamp(0.0, 1.0);
    let (a, b) = (before.parent_from_child, after.parent_from_child);
    RigidTransform {
        // Written as a weighted sum, so that two finite translations never give inf - inf.
        translation: a.translation * (1.0 - s) + b.translation * s,
        rotation: slerp(a.rotation, b.rotation, s),
    }
}

/// Spherical interpolation of unit quaternions along the shorter arc (as tf2's `slerp`).
///
/// Computed as `q0 * (q0⁻¹ q1)^s` with the angle from `atan2`, which stays accurate for tiny
/// angles (glam's `DQuat::slerp` uses an approximate `acos` of the dot product).
fn slerp(q0: DQuat, q1: DQuat, s: f64) -> DQuat {
    let mut delta = q0.conjugate() * q1;
    if delta.w < 0.0 {
        delta = -delta; // the same rotation, along the shorter arc
    }
    let axis = DVec3::new(delta.x, delta.y, delta.z);
    let sin_half = axis.length();
    if sin_half == 0.0 || !sin_half.is_finite() {
        return q0;
    }
    let half_angle = sin_half.atan2(delta.w);
    let step = DQuat::from_axis_angle(axis / sin_half, 2.0 * half_angle * s);
    (q0 * step).normalize()
}

/// Nanoseconds of a [`Duration`], saturating at `i64::MAX`.
fn duration_nanos(d: Duration) -> i64 {
    i64::try_from(d.as_nanos()).unwrap_or(i64::MAX)
}

/// The edges from a frame up to (not including) the lowest common ancestor: `(child, edge)`.
type ChainEdges<'a> = Vec<(&'a str, &'a Edge)>;

/// A tf2-style transform buffer with a time history of each dynamic edge.
#[derive(Debug, Clone, PartialEq)]
pub struct TfHistory {
    /// Child frame -> its edge to its parent.
    edges: BTreeMap<String, Edge>,
    cache_time: Duration,
    max_entries: usize,
    /// The latest clock time given to [`Self::note_time`] (ns).
    latest_noted: Option<i64>,
}

impl Default for TfHistory {
    fn default() -> Self {
        Self::with_limits(DEFAULT_CACHE_TIME, DEFAULT_MAX_ENTRIES)
    }
}

impl TfHistory {
    /// An empty buffer with tf2's 10 s cache time and [`DEFAULT_MAX_ENTRIES`].
    pub fn new() -> Self {
        Self::default()
    }

    /// An empty buffer keeping `cache_time` of history per dynamic edge, and at most
    /// `max_entries` entries per edge (at least 1).
    pub fn with_limits(cache_time: Duration, max_entries: usize) -> Self {
        Self {
            edges: BTreeMap::new(),
            cache_time,
            max_entries: max_entries.max(1),
            latest_noted: None,
        }
    }

    pub fn cache_time(&self) -> Duration {
        self.cache_time
    }

    pub fn max_entries(&self) -> usize {
        self.max_entries
    }

    /// Number of edges (one per child frame, static or dynamic).
    pub fn len(&self) -> usize {
        self.edges.len()
    }

    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
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

    /// The root of the tree `frame` belongs to (the frame itself for a root or unknown frame).
    pub fn root_of<'a>(&'a self, frame: &'a str) -> &'a str {
        self.edges_to_root(frame)
            .last()
            .map_or(frame, |(_, edge)| edge.parent.as_str())
    }

    /// The latest transform stored for child `frame`, with its stamp: its static one, or the
    /// newest of its dynamic history (`None` for a root or an unknown frame).
    pub(super) fn latest_of(&self, frame: &str) -> Option<(Time, &RigidTransform)> {
        let entry = match &self.edges.get(frame)?.history {
            History::Static(entry) => entry,
            History::Dynamic(entries) => entries.back()?,
        };
        Some((Time::from_nanos(entry.stamp), &entry.parent_from_child))
    }

    /// Whether child `frame` has a static edge (`None` for a root or an unknown frame).
    pub fn is_static(&self, frame: &str) -> Option<bool> {
        self.edges
            .get(frame)
            .map(|e| matches!(e.history, History::Static(_)))
    }

    /// Number of stored entries of child `frame`'s edge (1 for a static edge, 0 if unknown).
    pub fn history_len(&self, frame: &str) -> usize {
        match self.edges.get(frame).map(|e| &e.history) {
            None => 0,
            Some(History::Static(_)) => 1,
            Some(History::Dynamic(entries)) => entries.len(),
        }
    }

    /// The oldest stamp of child `frame`'s dynamic history (`None` if static or unknown).
    pub fn oldest_stamp(&self, frame: &str) -> Option<Time> {
        match &self.edges.get(frame)?.history {
            History::Static(_) => None,
            History::Dynamic(entries) => entries.front().map(|e| Time::from_nanos(e.stamp)),
        }
    }

    /// The newest stamp of child `frame`'s dynamic history (`None` if static or unknown).
    pub fn newest_stamp(&self, frame: &str) -> Option<Time> {
        self.edges.get(frame)?.newest_stamp().map(Time::from_nanos)
    }

    /// The newest stamp over all dynamic edges (`None` if there is none).
    pub fn newest_dynamic_stamp(&self) -> Option<Time> {
        self.edges
            .values()
            .filter_map(Edge::newest_stamp)
            .max()
            .map(Time::from_nanos)
    }

    /// Drops every edge, static and dynamic (the clock time noted so far stays).
    pub fn clear(&mut self) {
        self.edges.clear();
    }

    /// Drops every dynamic edge (and its history); the static edges stay. Frames known only
    /// through dynamic edges disappear until `/tf` brings them again.
    pub fn clear_dynamic(&mut self) {
        self.edges
            .retain(|_, edge| matches!(edge.history, History::Static(_)));
    }

    /// Tells the buffer the current clock time; on a jump back, clears the dynamic edges
    /// ([`Self::clear_dynamic`]) and returns `true`.
    ///
    /// A jump back is `now` earlier than the latest time noted so far by more than
    /// [`TIME_JUMP_TOLERANCE`] (1 s). This is tf's rule (ROS 1 `TransformListener` compares
    /// the clock to its last update, with 0.5 s; ROS 2 `tf2_ros::Buffer` clears on a clock jump
    /// callback), and deliberately not a comparison with the newest `/tf` stamp: localisers
    /// publish `map -> odom` stamped ahead of the clock (AMCL's `transform_tolerance`, 1 s by
    /// default), which such a rule would take for a jump and clear again and again. Time zero
    /// (a ROS clock not yet set, e.g. sim time before `/clock`) is ignored.
    pub fn note_time(&mut self, now: Time) -> bool {
        if now == Time::default() {
            return false;
        }
        let now = now.to_nanos();
        let tolerance = duration_nanos(TIME_JUMP_TOLERANCE);
        match self.latest_noted {
            Some(latest) if now < latest.saturating_sub(tolerance) => {
                self.clear_dynamic();
                self.latest_noted = Some(now);
                true
            }
            Some(latest) => {
                self.latest_noted = Some(latest.max(now));
                false
            }
            None => {
                self.latest_noted = Some(now);
                false
            }
        }
    }

    /// Inserts the transform of `msg.child_frame_id` in `msg.header.frame_id`: the static edge
    /// (`is_static`, from `/tf_static`) or an entry of the dynamic history (from `/tf`).
    ///
    /// On error the buffer is unchanged.
    pub fn insert(&mut self, msg: &TransformStamped, is_static: bool) -> Result<(), TfInsertError> {
        let (parent, child, parent_from_child) = validated(msg)?;
        self.check_cycle(parent, child)?;
        let entry = Entry {
            stamp: msg.header.stamp.to_nanos(),
            parent_from_child,
        };
        let cache_time = duration_nanos(self.cache_time);
        let max_entries = self.max_entries;

        let existing = self.edges.get_mut(child).and_then(|edge| {
            match (&mut edge.history, edge.parent == parent, is_static) {
                (History::Dynamic(entries), true, false) => Some(entries),
                _ => None,
            }
        });
        let Some(entries) = existing else {
            // New child, static edge, re-parented edge, or a change of kind: a fresh edge.
            let history = if is_static {
                History::Static(entry)
            } else {
                History::Dynamic(VecDeque::from([entry]))
            };
            self.edges.insert(
                child.to_string(),
                Edge {
                    parent: parent.to_string(),
                    history,
                },
            );
            return Ok(());
        };

        let newest = entries.back().map_or(entry.stamp, |e| e.stamp);
        if entry.stamp < newest.saturating_sub(cache_time) {
            return Err(TfInsertError::TooOld {
                parent: parent.to_string(),
                child: child.to_string(),
                stamp: msg.header.stamp,
                newest: Time::from_nanos(newest),
                cache_time: self.cache_time,
            });
        }
        let i = entries.partition_point(|e| e.stamp < entry.stamp);
        match entries.get_mut(i) {
            Some(same) if same.stamp == entry.stamp => *same = entry,
            _ => entries.insert(i, entry),
        }
        // Prune by age (tf2's pruneList: strictly older than newest - cache_time), then by count.
        let newest = entries.back().map_or(entry.stamp, |e| e.stamp);
        let horizon = newest.saturating_sub(cache_time);
        while entries.front().is_some_and(|e| e.stamp < horizon) {
            entries.pop_front();
        }
        while entries.len() > max_entries {
            entries.pop_front();
        }
        Ok(())
    }

    /// Inserts every transform of a `/tf` (`is_static = false`) or `/tf_static` message, in
    /// order; returns the errors of the rejected ones (the others are inserted).
    pub fn insert_message(&mut self, msg: &TFMessage, is_static: bool) -> Vec<TfInsertError> {
        msg.transforms
            .iter()
            .filter_map(|t| self.insert(t, is_static).err())
            .collect()
    }

    /// `target_from_source` at `time` (`point_in_target = target_from_source
    /// .transform_point(point_in_source)`); time zero asks for the latest common time of the
    /// chain ([`Self::latest_common_time`]).
    ///
    /// Identity when the two frame ids are equal, even if the frame is unknown (as tf2 does).
    /// Otherwise both must be valid tf2 frame ids ([`TfLookupError::InvalidFrame`]) in the same
    /// tree ([`TfLookupError::NotConnected`]), and every dynamic edge on the chain through
    /// their lowest common ancestor must have data around `time`
    /// ([`TfLookupError::ExtrapolationPast`] / [`TfLookupError::ExtrapolationFuture`]).
    pub fn lookup_at(
        &self,
        target_frame: &str,
        source_frame: &str,
        time: Time,
    ) -> Result<RigidTransform, TfLookupError> {
        self.lookup_waiting_for(target_frame, source_frame, time, TF_TOPICS)
    }

    /// [`Self::lookup_at`], whose "not in the tree" reason names `topics` as what the tree
    /// waits for (the static view: `/tf_static` only).
    pub(super) fn lookup_waiting_for(
        &self,
        target_frame: &str,
        source_frame: &str,
        time: Time,
        topics: &str,
    ) -> Result<RigidTransform, TfLookupError> {
        if target_frame == source_frame && !target_frame.is_empty() {
            return Ok(RigidTransform::IDENTITY);
        }
        let (source_edges, target_edges) = self.chain(target_frame, source_frame, topics)?;
        let time = if time == Time::default() {
            common_time(&source_edges, &target_edges)
        } else {
            time.to_nanos()
        };
        let ancestor_from = |edges: &ChainEdges<'_>| {
            edges_at(edges, time).map_err(|(parent, child, miss)| {
                let (target_frame, source_frame) =
                    (target_frame.to_string(), source_frame.to_string());
                let (parent, child) = (parent.to_string(), child.to_string());
                let requested = Time::from_nanos(time);
                match miss {
                    EdgeMiss::Past { oldest } => TfLookupError::ExtrapolationPast {
                        target_frame,
                        source_frame,
                        parent,
                        child,
                        requested,
                        oldest: Time::from_nanos(oldest),
                    },
                    EdgeMiss::Future { newest } => TfLookupError::ExtrapolationFuture {
                        target_frame,
                        source_frame,
                        parent,
                        child,
                        requested,
                        newest: Time::from_nanos(newest),
                    },
                }
            })
        };
        let ancestor_from_source = ancestor_from(&source_edges)?;
        let ancestor_from_target = ancestor_from(&target_edges)?;
        let target_from_source = ancestor_from_target
            .inverse()
            .compose(&ancestor_from_source);
        if !(target_from_source.translation.is_finite() && target_from_source.rotation.is_finite())
        {
            return Err(TfLookupError::NonFinite {
                target_frame: target_frame.to_string(),
                source_frame: source_frame.to_string(),
            });
        }
        Ok(target_from_source)
    }

    /// `target_from_source` at the latest common time: [`Self::lookup_at`] with time zero.
    pub fn lookup_latest(
        &self,
        target_frame: &str,
        source_frame: &str,
    ) -> Result<RigidTransform, TfLookupError> {
        self.lookup_at(target_frame, source_frame, Time::default())
    }

    /// The time [`Self::lookup_at`] uses for time zero (tf2's `getLatestCommonTime`): the
    /// minimum over the dynamic edges of the chain of their newest stamp; time zero for a chain
    /// without dynamic edges (valid at any time) and for equal frame ids.
    pub fn latest_common_time(
        &self,
        target_frame: &str,
        source_frame: &str,
    ) -> Result<Time, TfLookupError> {
        if target_frame == source_frame && !target_frame.is_empty() {
            return Ok(Time::default());
        }
        let (source_edges, target_edges) = self.chain(target_frame, source_frame, TF_TOPICS)?;
        let common = common_time(&source_edges, &target_edges);
        Ok(if common == i64::MAX {
            Time::default()
        } else {
            Time::from_nanos(common)
        })
    }

    /// Refuses the edge `parent -> child` if `child` is an ancestor of `parent`. The walk up
    /// from `parent` never uses the edge of `child` before reaching it, so the edge the
    /// insertion replaces does not matter.
    fn check_cycle(&self, parent: &str, child: &str) -> Result<(), TfError> {
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
        Ok(())
    }

    /// The edges from `source` and from `target` up to their lowest common ancestor; a frame
    /// not in the tree is waited for on `topics`.
    fn chain<'a>(
        &'a self,
        target_frame: &str,
        source_frame: &str,
        topics: &str,
    ) -> Result<(ChainEdges<'a>, ChainEdges<'a>), TfLookupError> {
        let (target, source) = (target_frame, source_frame);
        for (argument, frame) in [("target", target), ("source", source)] {
            validate_lookup_frame_id(frame).map_err(|reason| TfLookupError::InvalidFrame {
                argument,
                frame: frame.to_string(),
                reason: reason.to_string(),
            })?;
        }
        let not_connected = |reason: String| TfLookupError::NotConnected {
            target_frame: target.to_string(),
            source_frame: source.to_string(),
            reason,
        };
        let missing = match (self.contains(target), self.contains(source)) {
            (true, true) => None,
            (false, false) => Some(format!("neither '{source}' nor '{target}' is in the tree")),
            (true, false) => Some(format!("'{source}' is not in the tree")),
            (false, true) => Some(format!("'{target}' is not in the tree")),
        };
        if let Some(missing) = missing {
            return Err(not_connected(format!(
                "{missing} (waiting for {topics}){}",
                self.known_frames_suffix()
            )));
        }

        let source_up = self.edges_to_root(source);
        let target_up = self.edges_to_root(target);
        // frame -> number of edges from `source` up to it.
        let mut source_depth: HashMap<&str, usize> = HashMap::new();
        source_depth.insert(source, 0);
        for (i, (_, edge)) in source_up.iter().enumerate() {
            source_depth.insert(edge.parent.as_str(), i + 1);
        }
        let target_frames =
            std::iter::once(target).chain(target_up.iter().map(|(_, e)| e.parent.as_str()));
        for (j, frame) in target_frames.enumerate() {
            if let Some(&i) = source_depth.get(frame) {
                let mut source_up = source_up;
                let mut target_up = target_up;
                source_up.truncate(i);
                target_up.truncate(j);
                return Ok((source_up, target_up));
            }
        }
        let root = |frame: &str, up: &ChainEdges<'_>| {
            up.last()
                .map_or_else(|| frame.to_string(), |(_, e)| e.parent.clone())
        };
        Err(not_connected(format!(
            "'{source}' and '{target}' are in different trees (roots '{}' and '{}')",
            root(source, &source_up),
            root(target, &target_up)
        )))
    }

    /// The edges from `frame` up to its root, `(child, edge)` from `frame` upwards.
    fn edges_to_root<'a>(&'a self, frame: &str) -> ChainEdges<'a> {
        let mut up = Vec::new();
        let mut current = self.edges.get_key_value(frame);
        while let Some((child, edge)) = current {
            up.push((child.as_str(), edge));
            if up.len() > self.edges.len() {
                break; // safeguard; cannot happen in a forest
            }
            current = self.edges.get_key_value(edge.parent.as_str());
        }
        up
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

/// `ancestor_from_frame` at `time` (ns) for the edges from a frame up to an ancestor; on a
/// miss, the `(parent, child)` of the edge without data and why.
fn edges_at<'a>(
    edges: &ChainEdges<'a>,
    time: i64,
) -> Result<RigidTransform, (&'a str, &'a str, EdgeMiss)> {
    let mut current_from_frame = RigidTransform::IDENTITY;
    for &(child, edge) in edges {
        let parent_from_child = edge
            .at(time)
            .map_err(|miss| (edge.parent.as_str(), child, miss))?;
        current_from_frame = parent_from_child.compose(&current_from_frame);
    }
    Ok(current_from_frame)
}

/// The minimum over the dynamic edges of their newest stamp (ns); `i64::MAX` if there is no
/// dynamic edge (static edges answer any time).
fn common_time(a: &ChainEdges<'_>, b: &ChainEdges<'_>) -> i64 {
    a.iter()
        .chain(b.iter())
        .filter_map(|(_, edge)| edge.newest_stamp())
        .min()
        .unwrap_or(i64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, Transform, Vector3};

    const IDENT: [f64; 4] = [0.0, 0.0, 0.0, 1.0];
    const SEC: i64 = 1_000_000_000;

    fn t(nanos: i64) -> Time {
        Time::from_nanos(nanos)
    }

    fn ts(parent: &str, child: &str, stamp: i64, tr: [f64; 3], q: [f64; 4]) -> TransformStamped {
        TransformStamped {
            header: Header {
                stamp: t(stamp),
                frame_id: parent.to_string(),
            },
            child_frame_id: child.to_string(),
            transform: Transform {
                translation: Vector3 {
                    x: tr[0],
                    y: tr[1],
                    z: tr[2],
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

    /// Rotation by `angle` rad about z, as xyzw.
    fn yaw(angle: f64) -> [f64; 4] {
        let (s, c) = (angle / 2.0).sin_cos();
        [0.0, 0.0, s, c]
    }

    /// The rotation angle about z of a quaternion whose axis is z (checked).
    fn yaw_of(q: DQuat) -> f64 {
        assert!(q.x.abs() < 1e-12 && q.y.abs() < 1e-12, "axis not z: {q:?}");
        2.0 * q.z.atan2(q.w)
    }

    fn assert_close(a: DVec3, b: DVec3, what: &str) {
        assert!((a - b).length() < 1e-9, "{what}: {a} vs {b}");
    }

    /// Angles equal modulo 2 pi, to 1e-9 rad.
    fn assert_angle(a: f64, b: f64, what: &str) {
        let d = (a - b).rem_euclid(std::f64::consts::TAU);
        let d = d.min(std::f64::consts::TAU - d);
        assert!(d < 1e-9, "{what}: {a} vs {b} (diff {d})");
    }

    fn dynamic(
        h: &mut TfHistory,
        parent: &str,
        child: &str,
        stamp: i64,
        tr: [f64; 3],
        q: [f64; 4],
    ) {
        h.insert(&ts(parent, child, stamp, tr, q), false).unwrap();
    }

    fn fixed(h: &mut TfHistory, parent: &str, child: &str, tr: [f64; 3], q: [f64; 4]) {
        h.insert(&ts(parent, child, 0, tr, q), true).unwrap();
    }

    /// odom -> base: at 1 s at the origin with yaw 0, at 3 s at (2, 4, -8) with yaw 90 deg.
    fn two_entries() -> TfHistory {
        let mut h = TfHistory::new();
        dynamic(&mut h, "odom", "base", SEC, [0.0; 3], yaw(0.0));
        dynamic(
            &mut h,
            "odom",
            "base",
            3 * SEC,
            [2.0, 4.0, -8.0],
            yaw(90f64.to_radians()),
        );
        h
    }

    #[test]
    fn interpolates_at_midpoint_and_quarter() {
        let h = two_entries();
        let mid = h.lookup_at("odom", "base", t(2 * SEC)).unwrap();
        assert_close(
            mid.translation,
            DVec3::new(1.0, 2.0, -4.0),
            "mid translation",
        );
        assert_angle(yaw_of(mid.rotation), 45f64.to_radians(), "mid yaw");
        let quarter = h.lookup_at("odom", "base", t(3 * SEC / 2)).unwrap();
        assert_close(
            quarter.translation,
            DVec3::new(0.5, 1.0, -2.0),
            "1/4 translation",
        );
        assert_angle(yaw_of(quarter.rotation), 22.5f64.to_radians(), "1/4 yaw");
        // The inverse lookup is the inverse transform.
        let base_from_odom = h.lookup_at("base", "odom", t(3 * SEC / 2)).unwrap();
        let p = DVec3::new(0.3, -1.0, 2.0);
        assert_close(
            base_from_odom.transform_point(quarter.transform_point(p)),
            p,
            "inverse",
        );
    }

    #[test]
    fn slerp_is_exact_for_tiny_angles_and_takes_the_short_arc() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "odom", "base", 0, [0.0; 3], yaw(0.0));
        dynamic(&mut h, "odom", "base", 4 * SEC, [0.0; 3], yaw(1e-6));
        let q = h.lookup_at("odom", "base", t(SEC)).unwrap().rotation;
        assert!((yaw_of(q) - 0.25e-6).abs() < 1e-15, "{}", yaw_of(q));

        // From +170 deg to -170 deg: the short way is through 180 deg, not through 0.
        let mut h = TfHistory::new();
        dynamic(
            &mut h,
            "odom",
            "base",
            0,
            [0.0; 3],
            yaw(170f64.to_radians()),
        );
        dynamic(
            &mut h,
            "odom",
            "base",
            2 * SEC,
            [0.0; 3],
            yaw(-170f64.to_radians()),
        );
        let mid = h.lookup_at("odom", "base", t(SEC)).unwrap();
        assert_angle(yaw_of(mid.rotation), std::f64::consts::PI, "short arc");
        assert_close(
            mid.transform_point(DVec3::X),
            -DVec3::X,
            "x axis at 180 deg",
        );
        // Quaternions of opposite sign (the same rotation) interpolate to that rotation.
        let mut h = TfHistory::new();
        let q = yaw(0.5);
        dynamic(&mut h, "odom", "base", 0, [0.0; 3], q);
        dynamic(&mut h, "odom", "base", SEC, [0.0; 3], q.map(|c| -c));
        let r = h.lookup_at("odom", "base", t(SEC / 3)).unwrap();
        assert_angle(yaw_of(r.rotation), 0.5, "q and -q");
    }

    #[test]
    fn exact_stamps_return_the_entry() {
        let h = two_entries();
        let first = h.lookup_at("odom", "base", t(SEC)).unwrap();
        assert_eq!(first.translation, DVec3::ZERO);
        assert_angle(yaw_of(first.rotation), 0.0, "first");
        let last = h.lookup_at("odom", "base", t(3 * SEC)).unwrap();
        assert_eq!(last.translation, DVec3::new(2.0, 4.0, -8.0));
        assert_angle(yaw_of(last.rotation), 90f64.to_radians(), "last");
        // One nanosecond inside the bracket is still an interpolation, not a refusal.
        let near = h.lookup_at("odom", "base", t(3 * SEC - 1)).unwrap();
        assert_close(
            near.translation,
            DVec3::new(2.0, 4.0, -8.0) * (1.0 - 0.5e-9),
            "3 s - 1 ns",
        );
    }

    #[test]
    fn chain_of_dynamic_and_static_edges_is_the_composed_product() {
        // world -> odom (dynamic) -> base (static) -> camera (static).
        let mut h = TfHistory::new();
        dynamic(&mut h, "world", "odom", 10 * SEC, [1.0, 0.0, 0.0], yaw(0.0));
        dynamic(
            &mut h,
            "world",
            "odom",
            12 * SEC,
            [3.0, 2.0, 0.0],
            yaw(std::f64::consts::FRAC_PI_2),
        );
        fixed(&mut h, "odom", "base", [0.5, 0.0, 0.2], yaw(-0.3));
        fixed(
            &mut h,
            "base",
            "camera",
            [0.1, 0.05, 1.0],
            [-0.5, 0.5, -0.5, 0.5],
        );
        let time = t(11 * SEC);
        let world_from_odom = RigidTransform::from_quat_translation(
            "odom",
            DQuat::from_rotation_z(std::f64::consts::FRAC_PI_4),
            DVec3::new(2.0, 1.0, 0.0),
        )
        .unwrap();
        let odom_from_base = h.lookup_at("odom", "base", time).unwrap();
        let base_from_camera = h.lookup_at("base", "camera", time).unwrap();
        let expected = world_from_odom
            .compose(&odom_from_base)
            .compose(&base_from_camera);
        let world_from_camera = h.lookup_at("world", "camera", time).unwrap();
        for p in [
            DVec3::ZERO,
            DVec3::new(0.2, -0.4, 3.0),
            DVec3::new(-5.0, 1.0, 0.5),
        ] {
            assert_close(
                world_from_camera.transform_point(p),
                expected.transform_point(p),
                "world <- camera",
            );
            // Independent of RigidTransform::compose: by hand.
            let in_base = DQuat::from_xyzw(-0.5, 0.5, -0.5, 0.5) * p + DVec3::new(0.1, 0.05, 1.0);
            let in_odom = DQuat::from_rotation_z(-0.3) * in_base + DVec3::new(0.5, 0.0, 0.2);
            let (s, c) = std::f64::consts::FRAC_PI_4.sin_cos();
            let in_world = DVec3::new(
                c * in_odom.x - s * in_odom.y + 2.0,
                s * in_odom.x + c * in_odom.y + 1.0,
                in_odom.z,
            );
            assert_close(world_from_camera.transform_point(p), in_world, "by hand");
            let camera_from_world = h.lookup_at("camera", "world", time).unwrap();
            assert_close(camera_from_world.transform_point(in_world), p, "inverse");
        }
        // Static edges answer at any time; the chain only at the dynamic edge's times.
        assert!(h.lookup_at("base", "camera", t(999 * SEC)).is_ok());
        assert!(h.lookup_at("odom", "camera", t(1)).is_ok());
        assert!(h
            .lookup_at("world", "camera", t(13 * SEC))
            .unwrap_err()
            .is_future());
        // Time zero: the newest data of the one dynamic edge.
        assert_eq!(
            h.latest_common_time("world", "camera").unwrap(),
            t(12 * SEC)
        );
        assert_eq!(
            h.latest_common_time("base", "camera").unwrap(),
            Time::default()
        );
        assert_eq!(
            h.lookup_latest("world", "camera").unwrap(),
            h.lookup_at("world", "camera", t(12 * SEC)).unwrap()
        );
        // A lookup between two branches under the common ancestor `odom` skips world -> odom.
        fixed(&mut h, "odom", "imu", [0.0, 0.0, 0.1], IDENT);
        assert!(h.lookup_at("imu", "camera", t(1)).is_ok());
    }

    #[test]
    fn extrapolation_past_and_future_are_refused() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "world", "x", 12 * SEC, [0.0; 3], IDENT);
        dynamic(
            &mut h,
            "world",
            "x",
            12 * SEC + 300_000_000,
            [0.0; 3],
            IDENT,
        );
        fixed(&mut h, "x", "cam", [0.0; 3], IDENT);
        let err = h
            .lookup_at("world", "cam", t(12 * SEC + 500_000_000))
            .unwrap_err();
        assert_eq!(
            err,
            TfLookupError::ExtrapolationFuture {
                target_frame: "world".into(),
                source_frame: "cam".into(),
                parent: "world".into(),
                child: "x".into(),
                requested: t(12 * SEC + 500_000_000),
                newest: t(12 * SEC + 300_000_000),
            }
        );
        assert_eq!(
            err.to_string(),
            "no transform from 'cam' to 'world': lookup would require extrapolation into the \
             future: requested 12.5 s, newest 12.3 s for frame 'world' -> 'x'"
        );
        assert!(err.is_future() && err.may_resolve_by_waiting());

        let err = h.lookup_at("cam", "world", t(11 * SEC)).unwrap_err();
        assert!(
            matches!(&err, TfLookupError::ExtrapolationPast { oldest, requested, .. }
                if *oldest == t(12 * SEC) && *requested == t(11 * SEC)),
            "{err:?}"
        );
        assert_eq!(
            err.to_string(),
            "no transform from 'world' to 'cam': lookup would require extrapolation into the \
             past: requested 11 s, oldest 12 s for frame 'world' -> 'x'"
        );
        assert!(!err.is_future() && !err.may_resolve_by_waiting());
    }

    #[test]
    fn single_entry_history_matches_only_its_stamp() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "odom", "base", 5 * SEC, [1.0, 2.0, 3.0], yaw(0.25));
        let at = h.lookup_at("odom", "base", t(5 * SEC)).unwrap();
        assert_eq!(at.translation, DVec3::new(1.0, 2.0, 3.0));
        assert_angle(yaw_of(at.rotation), 0.25, "yaw");
        assert!(matches!(
            h.lookup_at("odom", "base", t(5 * SEC + 1)),
            Err(TfLookupError::ExtrapolationFuture { .. })
        ));
        assert!(matches!(
            h.lookup_at("odom", "base", t(5 * SEC - 1)),
            Err(TfLookupError::ExtrapolationPast { .. })
        ));
        // Time zero: its own stamp.
        assert_eq!(h.latest_common_time("odom", "base").unwrap(), t(5 * SEC));
        assert_eq!(h.lookup_latest("odom", "base").unwrap(), at);
    }

    #[test]
    fn latest_common_time_of_two_dynamic_edges_at_different_rates() {
        let mut h = TfHistory::new();
        // world -> odom at 10 Hz over [1, 2] s, x = stamp in s.
        for i in 0..=10 {
            let stamp = SEC + i * SEC / 10;
            dynamic(
                &mut h,
                "world",
                "odom",
                stamp,
                [stamp as f64 / 1e9, 0.0, 0.0],
                IDENT,
            );
        }
        // odom -> base at 3 Hz: 1 s, 1.333.. s, 1.666.. s; y = stamp in s.
        let base_stamps = [SEC, SEC + SEC / 3, SEC + 2 * SEC / 3];
        for stamp in base_stamps {
            dynamic(
                &mut h,
                "odom",
                "base",
                stamp,
                [0.0, stamp as f64 / 1e9, 0.0],
                IDENT,
            );
        }
        fixed(&mut h, "base", "cam", [0.0, 0.0, 1.0], IDENT);
        let common = h.latest_common_time("world", "cam").unwrap();
        assert_eq!(common, t(base_stamps[2]));
        // Either argument order, and from a frame in the middle.
        assert_eq!(h.latest_common_time("cam", "world").unwrap(), common);
        assert_eq!(h.latest_common_time("world", "odom").unwrap(), t(2 * SEC));
        let latest = h.lookup_latest("world", "cam").unwrap();
        assert_eq!(latest, h.lookup_at("world", "cam", common).unwrap());
        let s = base_stamps[2] as f64 / 1e9;
        assert_close(
            latest.translation,
            DVec3::new(s, s, 1.0),
            "at the common time",
        );
        // A later odom -> base moves the common time to the newest world -> odom stamp.
        dynamic(&mut h, "odom", "base", 2 * SEC + SEC / 3, [0.0; 3], IDENT);
        assert_eq!(h.latest_common_time("world", "cam").unwrap(), t(2 * SEC));
        // Histories that do not overlap: the common time is before one of them, which tf2
        // reports as extrapolation into the past.
        let mut h = TfHistory::new();
        dynamic(&mut h, "world", "odom", SEC, [0.0; 3], IDENT);
        dynamic(&mut h, "world", "odom", 2 * SEC, [0.0; 3], IDENT);
        dynamic(&mut h, "odom", "base", 5 * SEC, [0.0; 3], IDENT);
        let err = h.lookup_latest("world", "base").unwrap_err();
        assert!(
            matches!(&err, TfLookupError::ExtrapolationPast { child, requested, .. }
                if child == "base" && *requested == t(2 * SEC)),
            "{err:?}"
        );
    }

    #[test]
    fn cache_time_prunes_and_refuses_old_data() {
        let mut h = TfHistory::new();
        assert_eq!(h.cache_time(), Duration::from_secs(10));
        for s in 0..=20 {
            dynamic(&mut h, "odom", "base", s * SEC, [s as f64, 0.0, 0.0], IDENT);
        }
        // Entries older than newest - 10 s are gone; the one exactly at 10 s stays (tf2).
        assert_eq!(h.history_len("base"), 11);
        assert_eq!(h.oldest_stamp("base"), Some(t(10 * SEC)));
        assert_eq!(h.newest_stamp("base"), Some(t(20 * SEC)));
        assert!(matches!(
            h.lookup_at("odom", "base", t(9 * SEC + SEC / 2)),
            Err(TfLookupError::ExtrapolationPast { .. })
        ));
        assert!(h.lookup_at("odom", "base", t(10 * SEC + SEC / 2)).is_ok());
        // Data older than the cache is refused, and changes nothing.
        let err = h
            .insert(&ts("odom", "base", 5 * SEC, [0.0; 3], IDENT), false)
            .unwrap_err();
        assert!(matches!(&err, TfInsertError::TooOld { stamp, newest, .. }
            if *stamp == t(5 * SEC) && *newest == t(20 * SEC)));
        assert_eq!(
            err.to_string(),
            "ignoring transform 'odom' -> 'base' stamped 5 s: older than the 10 s cache before \
             the newest stamp 20 s of 'base' (tf2's TF_OLD_DATA)"
        );
        assert_eq!(h.history_len("base"), 11);
        // The horizon is per edge: a new edge far in the past is fine.
        dynamic(&mut h, "odom", "wheel", SEC, [0.0; 3], IDENT);
        assert_eq!(h.history_len("wheel"), 1);
        // A shorter cache.
        let mut h = TfHistory::with_limits(Duration::from_millis(500), DEFAULT_MAX_ENTRIES);
        for i in 0..10 {
            dynamic(&mut h, "odom", "base", i * SEC / 10, [0.0; 3], IDENT);
        }
        assert_eq!(h.oldest_stamp("base"), Some(t(4 * SEC / 10)));
        assert_eq!(h.history_len("base"), 6);
    }

    #[test]
    fn entry_cap_drops_the_oldest() {
        let mut h = TfHistory::with_limits(Duration::from_secs(1000), 100);
        for i in 0..250 {
            dynamic(
                &mut h,
                "odom",
                "base",
                i * 1_000_000,
                [i as f64, 0.0, 0.0],
                IDENT,
            );
        }
        assert_eq!(h.history_len("base"), 100);
        assert_eq!(h.oldest_stamp("base"), Some(t(150 * 1_000_000)));
        assert_eq!(h.newest_stamp("base"), Some(t(249 * 1_000_000)));
        // The default cap holds against a flood within the cache time (0.5 ms apart).
        let mut h = TfHistory::new();
        assert_eq!(h.max_entries(), 10_000);
        for i in 0..12_000 {
            dynamic(&mut h, "odom", "base", i * 500_000, [0.0; 3], IDENT);
        }
        assert_eq!(h.history_len("base"), 10_000);
        assert_eq!(h.oldest_stamp("base"), Some(t(2_000 * 500_000)));
        // At least one entry is kept.
        assert_eq!(
            TfHistory::with_limits(DEFAULT_CACHE_TIME, 0).max_entries(),
            1
        );
    }

    #[test]
    fn cycles_are_refused_and_the_tree_unchanged() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "world", "odom", SEC, [0.0; 3], IDENT);
        dynamic(&mut h, "odom", "base", SEC, [0.0; 3], IDENT);
        fixed(&mut h, "base", "cam", [0.0; 3], IDENT);
        for is_static in [false, true] {
            let err = h
                .insert(&ts("cam", "world", SEC, [0.0; 3], IDENT), is_static)
                .unwrap_err();
            assert_eq!(
                err,
                TfInsertError::Rejected(TfError::Cycle {
                    parent: "cam".into(),
                    child: "world".into(),
                    path: vec!["world".into(), "odom".into(), "base".into(), "cam".into()],
                })
            );
            assert_eq!(
                err.to_string(),
                "rejected transform 'cam' -> 'world': it would create a cycle ('world' is \
                 already an ancestor of 'cam': world -> odom -> base -> cam)"
            );
        }
        assert_eq!(h.parent_of("world"), None);
        assert_eq!(h.len(), 3);
        assert!(h.lookup_at("world", "cam", t(SEC)).is_ok());
    }

    #[test]
    fn reparenting_or_changing_kind_replaces_the_edge() {
        let mut h = two_entries();
        assert_eq!(h.history_len("base"), 2);
        dynamic(&mut h, "map", "base", 2 * SEC, [7.0, 0.0, 0.0], IDENT);
        assert_eq!(h.parent_of("base"), Some("map"));
        assert_eq!(h.history_len("base"), 1);
        assert_eq!(h.frames(), vec!["base", "map"]);
        // Dynamic -> static: valid at any time from now on.
        fixed(&mut h, "map", "base", [1.0, 0.0, 0.0], IDENT);
        assert_eq!(h.is_static("base"), Some(true));
        assert_eq!(h.newest_stamp("base"), None);
        let any = h.lookup_at("map", "base", t(123 * SEC)).unwrap();
        assert_eq!(any.translation, DVec3::X);
        // Static: latest wins whatever the stamp.
        h.insert(&ts("map", "base", -5 * SEC, [2.0, 0.0, 0.0], IDENT), true)
            .unwrap();
        assert_eq!(
            h.lookup_latest("map", "base").unwrap().translation,
            2.0 * DVec3::X
        );
        // Static -> dynamic: a history again.
        dynamic(&mut h, "map", "base", 4 * SEC, [0.0; 3], IDENT);
        assert_eq!(h.is_static("base"), Some(false));
        assert!(h
            .lookup_at("map", "base", t(5 * SEC))
            .unwrap_err()
            .is_future());
        assert_eq!(h.is_static("map"), None);
    }

    #[test]
    fn time_jump_back_clears_dynamic_and_keeps_static() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "world", "odom", 100 * SEC, [0.0; 3], IDENT);
        fixed(&mut h, "odom", "base", [0.0; 3], IDENT);
        fixed(&mut h, "base", "cam", [0.0; 3], IDENT);
        assert!(!h.note_time(t(100 * SEC)));
        // Clock time zero (not set yet) and small steps back are not jumps.
        assert!(!h.note_time(Time::default()));
        assert!(!h.note_time(t(99 * SEC + SEC / 2)));
        assert!(!h.note_time(t(101 * SEC)));
        assert!(!h.note_time(t(100 * SEC)));
        assert_eq!(h.len(), 3);
        // A bag loops: the clock goes back to 40 s.
        assert!(h.note_time(t(40 * SEC)));
        assert_eq!(h.len(), 2);
        assert_eq!(h.newest_dynamic_stamp(), None);
        assert!(h.lookup_at("odom", "cam", t(40 * SEC)).is_ok());
        let err = h.lookup_at("world", "cam", t(40 * SEC)).unwrap_err();
        assert!(matches!(err, TfLookupError::NotConnected { .. }), "{err}");
        assert!(err.may_resolve_by_waiting());
        // The new clock is the reference from now on.
        assert!(!h.note_time(t(41 * SEC)));
        dynamic(&mut h, "world", "odom", 41 * SEC, [0.0; 3], IDENT);
        assert!(h.lookup_at("world", "cam", t(41 * SEC)).is_ok());
        assert_eq!(h.newest_dynamic_stamp(), Some(t(41 * SEC)));
        h.clear_dynamic();
        assert_eq!(h.frames(), vec!["base", "cam", "odom"]);
    }

    #[test]
    fn frame_ids_follow_tf2() {
        let mut h = TfHistory::new();
        // One leading slash is stripped on insertion.
        dynamic(&mut h, "/odom", "/base", SEC, [1.0, 0.0, 0.0], IDENT);
        assert_eq!(h.frames(), vec!["base", "odom"]);
        assert!(h.lookup_at("odom", "base", t(SEC)).is_ok());
        // ...but refused in lookups, as tf2's validateFrameId refuses it.
        let err = h.lookup_at("odom", "/base", t(SEC)).unwrap_err();
        assert_eq!(
            err,
            TfLookupError::InvalidFrame {
                argument: "source",
                frame: "/base".into(),
                reason: "in tf2 frame_ids cannot start with a '/'".into(),
            }
        );
        assert_eq!(
            err.to_string(),
            "invalid source frame id \"/base\": in tf2 frame_ids cannot start with a '/'"
        );
        let err = h.lookup_at("", "base", t(SEC)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid target frame id \"\": in tf2 frame_ids cannot be empty"
        );
        assert!(!err.may_resolve_by_waiting());
        assert!(h.latest_common_time("odom", "/base").is_err());
        // Equal ids are the identity, known or not (tf2).
        assert_eq!(
            h.lookup_at("x", "x", t(SEC)).unwrap(),
            RigidTransform::IDENTITY
        );
        // Refused insertions, with TfBuffer's errors.
        let bad = |h: &mut TfHistory, parent: &str, child: &str| {
            h.insert(&ts(parent, child, SEC, [0.0; 3], IDENT), false)
                .unwrap_err()
        };
        assert!(matches!(
            bad(&mut h, "", "x"),
            TfInsertError::Rejected(TfError::InvalidFrameId { .. })
        ));
        let err = bad(&mut h, "odom", "/");
        assert!(err.to_string().contains("child_frame_id is empty"), "{err}");
        assert_eq!(
            bad(&mut h, "/odom", "odom"),
            TfInsertError::Rejected(TfError::SelfParent {
                frame: "odom".into()
            })
        );
        assert_eq!(h.len(), 1);
    }

    #[test]
    fn unknown_and_disconnected_frames_are_not_connected() {
        let mut h = TfHistory::new();
        let err = h.lookup_at("a", "b", t(SEC)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "no transform from 'b' to 'a': neither 'b' nor 'a' is in the tree (waiting for /tf \
             or /tf_static); no transform received yet"
        );
        dynamic(&mut h, "odom", "base", SEC, [0.0; 3], IDENT);
        fixed(&mut h, "rig", "cam", [0.0; 3], IDENT);
        let err = h.lookup_at("base", "cam9", t(SEC)).unwrap_err();
        assert_eq!(
            err,
            TfLookupError::NotConnected {
                target_frame: "base".into(),
                source_frame: "cam9".into(),
                reason: "'cam9' is not in the tree (waiting for /tf or /tf_static); known \
                         frames: base, cam, odom, rig"
                    .into(),
            }
        );
        let err = h.lookup_at("base", "cam", t(SEC)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "no transform from 'cam' to 'base': 'cam' and 'base' are in different trees \
             (roots 'rig' and 'odom')"
        );
        // Joining the trees fixes it.
        fixed(&mut h, "base", "rig", [0.0; 3], IDENT);
        assert!(h.lookup_at("base", "cam", t(SEC)).is_ok());
        assert!(h.lookup_at("odom", "cam", t(SEC)).is_ok());
    }

    #[test]
    fn non_finite_or_non_unit_transforms_are_refused() {
        let mut h = two_entries();
        let before = h.clone();
        for (tr, q) in [
            ([0.0; 3], [f64::NAN, 0.0, 0.0, 1.0]),
            ([0.0; 3], [0.0, 0.0, f64::INFINITY, 1.0]),
            ([f64::INFINITY, 0.0, 0.0], IDENT),
            ([0.0, f64::NAN, 0.0], IDENT),
            ([0.0; 3], [0.0, 0.0, 0.0, 1.1]),
            ([0.0; 3], [0.0; 4]),
        ] {
            for is_static in [false, true] {
                let err = h
                    .insert(&ts("odom", "base", 2 * SEC, tr, q), is_static)
                    .unwrap_err();
                assert!(
                    matches!(&err, TfInsertError::Rejected(TfError::InvalidTransform { parent, child, .. })
                        if parent == "odom" && child == "base"),
                    "{err:?}"
                );
            }
        }
        assert_eq!(h, before);
        // Near-unit quaternions are accepted (tf2's tolerance) and normalised.
        dynamic(
            &mut h,
            "odom",
            "base",
            2 * SEC,
            [0.0; 3],
            [0.0, 0.0, 0.0, 1.004],
        );
        let q = h.lookup_at("odom", "base", t(2 * SEC)).unwrap().rotation;
        assert!((q.length() - 1.0).abs() < 1e-12);
        // Finite edges whose chain overflows.
        let mut h = TfHistory::new();
        dynamic(&mut h, "root", "a", SEC, [1e308, 0.0, 0.0], IDENT);
        dynamic(&mut h, "root", "b", SEC, [-1e308, 0.0, 0.0], IDENT);
        let err = h.lookup_at("a", "b", t(SEC)).unwrap_err();
        assert_eq!(
            err,
            TfLookupError::NonFinite {
                target_frame: "a".into(),
                source_frame: "b".into(),
            }
        );
        assert!(err.to_string().contains("not finite"), "{err}");
        // Interpolating between huge translations stays finite.
        dynamic(&mut h, "root", "a", 3 * SEC, [-1e308, 0.0, 0.0], IDENT);
        let mid = h.lookup_at("root", "a", t(2 * SEC)).unwrap();
        assert!(mid.translation.is_finite() && mid.translation.x.abs() < 1e-290);
    }

    #[test]
    fn late_and_duplicate_stamps_are_placed_in_order() {
        let mut h = TfHistory::new();
        dynamic(&mut h, "odom", "base", SEC, [0.0; 3], IDENT);
        dynamic(&mut h, "odom", "base", 3 * SEC, [2.0, 0.0, 0.0], IDENT);
        // 2 s arrives late, off the line between its neighbours.
        dynamic(&mut h, "odom", "base", 2 * SEC, [0.0, 5.0, 0.0], IDENT);
        assert_eq!(h.history_len("base"), 3);
        assert_eq!(h.newest_stamp("base"), Some(t(3 * SEC)));
        let at = |h: &TfHistory, ns: i64| h.lookup_at("odom", "base", t(ns)).unwrap().translation;
        assert_eq!(at(&h, 2 * SEC), DVec3::new(0.0, 5.0, 0.0));
        assert_close(at(&h, SEC + SEC / 2), DVec3::new(0.0, 2.5, 0.0), "1.5 s");
        assert_close(
            at(&h, 2 * SEC + SEC / 2),
            DVec3::new(1.0, 2.5, 0.0),
            "2.5 s",
        );
        // Older than all, still within the cache: becomes the oldest.
        dynamic(&mut h, "odom", "base", 0, [-1.0, 0.0, 0.0], IDENT);
        assert_eq!(h.oldest_stamp("base"), Some(t(0)));
        assert_close(at(&h, SEC / 2), DVec3::new(-0.5, 0.0, 0.0), "0.5 s");
        // The same stamp again replaces the entry.
        dynamic(&mut h, "odom", "base", 2 * SEC, [0.0, -5.0, 0.0], IDENT);
        assert_eq!(h.history_len("base"), 4);
        assert_eq!(at(&h, 2 * SEC), DVec3::new(0.0, -5.0, 0.0));
    }

    #[test]
    fn insert_message_reports_only_rejected() {
        let mut h = TfHistory::new();
        let errors = h.insert_message(
            &TFMessage {
                transforms: vec![
                    ts("odom", "base", SEC, [0.0; 3], IDENT),
                    ts("base", "base", SEC, [0.0; 3], IDENT),
                    ts("base", "cam", SEC, [0.0; 3], [0.0, 0.0, 0.0, 2.0]),
                    ts("base", "imu", SEC, [0.0; 3], IDENT),
                    ts("imu", "odom", SEC, [0.0; 3], IDENT),
                ],
            },
            false,
        );
        assert_eq!(errors.len(), 3, "{errors:?}");
        assert!(matches!(
            errors[0],
            TfInsertError::Rejected(TfError::SelfParent { .. })
        ));
        assert!(matches!(
            errors[1],
            TfInsertError::Rejected(TfError::InvalidTransform { .. })
        ));
        assert!(matches!(
            errors[2],
            TfInsertError::Rejected(TfError::Cycle { .. })
        ));
        assert_eq!(h.frames(), vec!["base", "imu", "odom"]);
        assert_eq!(h.is_static("imu"), Some(false));
    }
}
