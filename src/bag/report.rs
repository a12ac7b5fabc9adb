//! What a `sweepdepth bag` run did ([`BagReport`]) and its one-line summary.

use std::time::Duration;

use crate::pipeline::{Counts, NoticeKind, SkipCounts};

use super::reader::StepsBack;
use crate::ros::sync::SyncStats;

/// What a bag run did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BagReport {
    /// Messages read from the bag.
    pub messages: u64,
    /// Synchronised frame sets found.
    pub sets_found: u64,
    pub sets_processed: u64,
    /// Depth maps written: one per reference of each processed set (`references`).
    pub depth_maps: u64,
    /// Sets not processed, by reason ([`crate::pipeline::SkipKind::label`]).
    pub skipped: SkipCounts,
    /// Messages that could not be decoded or had the wrong type, by topic.
    pub bad_messages: Counts<String>,
    /// The synchroniser's verdicts, counted: partial sets it abandoned (a camera's image
    /// missing), images its time rules dropped (duplicate, late, future stamps), its resets
    /// (time going backwards).
    pub sync: SyncStats,
    /// Topics of the bag the pipeline does not read.
    pub ignored_topics: Vec<String>,
    pub mean_time_per_set: Option<Duration>,
    /// The most sets on the engine at once: 2 where the WGSL engine ran one set while the host
    /// finished the one before (`--sets-ahead`), else 1.
    pub most_in_flight: u64,
    /// Read errors (a truncated or corrupt file: each names the file and byte offset); reading
    /// goes on at the next intact chunk where the file allows.
    pub read_errors: Vec<String>,
    pub output: Option<super::WriteSummary>,
    /// `--mesh`: what was fused and where it went.
    pub mesh: Option<String>,
    /// The last skip's reason (engine skips included).
    pub last_skip: Option<String>,
    /// No set processed: why ([`crate::pipeline::Pipeline::why_no_depth`], the same reasons
    /// as the live node's "no depth" line, e.g. "camera_info never recorded for cam3").
    pub no_depth: Option<String>,
    /// Ctrl-C stopped the reading: the outputs hold the sets processed before it.
    pub interrupted: bool,
}

impl BagReport {
    /// The one-line summary printed at the end.
    pub fn summary_line(&self) -> String {
        let skipped = self.skipped.total();
        let mut s = format!(
            "bag: {} frame sets found{}, {} processed, {} incomplete, {} skipped",
            self.sets_found,
            if self.interrupted {
                " before Ctrl-C"
            } else {
                ""
            },
            self.sets_processed,
            self.sync.incomplete,
            skipped
        );
        if self.depth_maps > self.sets_processed {
            s += &format!(" ({} depth maps)", self.depth_maps);
        }
        if skipped > 0 {
            let reasons: Vec<String> = self
                .skipped
                .iter()
                .map(|(k, n)| format!("{n} {k}"))
                .collect();
            s += &format!(" ({})", reasons.join(", "));
        }
        let time_rules: Vec<String> = [
            (self.sync.duplicates, NoticeKind::DuplicateStamp),
            (self.sync.future, NoticeKind::FutureStamp),
            (self.sync.out_of_order, NoticeKind::LateStamp),
            (self.sync.resets, NoticeKind::TimeReset),
        ]
        .iter()
        .filter(|(n, _)| *n > 0)
        .map(|(n, kind)| format!("{n} {}", kind.label()))
        .collect();
        if !time_rules.is_empty() {
            s += &format!(", time rules: {}", time_rules.join(", "));
        }
        if !self.read_errors.is_empty() {
            s += &format!(", {} read errors (damaged bag)", self.read_errors.len());
        }
        if !self.bad_messages.is_empty() {
            let bad = self.bad_messages.total();
            s += &format!(", {bad} unreadable messages");
        }
        match (self.mean_time_per_set, &self.no_depth) {
            (Some(t), _) => s += &format!("; {:.1} ms per set", t.as_secs_f64() * 1e3),
            (None, Some(why)) => s += &format!("; no set processed: {why}"),
            (None, None) => s += "; no set processed",
        }
        if self.most_in_flight > 1 {
            s += &format!(" ({} sets on the device at once)", self.most_in_flight);
        }
        if let Some(out) = &self.output {
            s += &format!(
                "; wrote {} messages to {}",
                out.messages,
                out.path.display()
            );
        }
        s
    }
}

/// The warning for an MCAP bag whose log times go backwards in file order: how many messages
/// stepped back, by how much at most, and what it does to the run.
pub fn log_times_back_note(input: &std::path::Path, steps: StepsBack) -> String {
    format!(
        "{}: log times go backwards in the MCAP file order: {} message{} logged before the one \
         read before {}, by up to {:.3} s (a bag merged or written out of order?). MCAP is read \
         in file order, so frame sets are made in file order, not time order: images out of \
         place may miss their set or be dropped by the time rules (sqlite3 is read in time \
         order)",
        input.display(),
        steps.messages,
        if steps.messages == 1 { "" } else { "s" },
        if steps.messages == 1 { "it" } else { "them" },
        steps.max_ns as f64 / 1e9
    )
}
