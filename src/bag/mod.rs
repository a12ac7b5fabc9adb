//! rosbag2 bags: reading ([`reader`]: MCAP and sqlite3), writing ([`writer`]: MCAP, lone or as
//! a rosbag2 directory), `sweepdepth bag` ([`process`]: a bag through the node's pipeline,
//! [`report`]: what it did) and `sweepdepth pack` ([`pack`]: a dataset folder into a bag).

mod interrupt;
pub mod pace;
pub mod pack;
pub mod process;
pub mod reader;
pub mod report;
mod sink;
/// The message definitions (shared with `viewer/`).
pub use crate::msgdefs as schemas;
pub mod writer;

use std::path::{Path, PathBuf};

pub use reader::{BagMessage, BagReader, StepsBack, TopicInfo};
pub use writer::{BagWriter, WriteSummary};

/// Errors reading or writing bags; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("{path}: corrupt or truncated at byte {offset}: {reason}")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        reason: String,
    },
    #[error("{path}: writing MCAP: {reason}")]
    Write { path: PathBuf, reason: String },
    #[error("{0} exists (pass --force to replace it)")]
    OutputExists(PathBuf),
    #[error("{out} is the input {input} or holds it: write the output elsewhere")]
    OutputIsInput { out: PathBuf, input: PathBuf },
    #[error(
        "{out} exists and is not a bag ({what}): not replaced, even with --force; remove it \
         yourself or write the output elsewhere"
    )]
    OutputNotABag { out: PathBuf, what: String },
    #[error("topic {0} was not declared before writing")]
    UnknownTopic(String),
    #[error("the bag writer is already finished")]
    Finished,
}

impl BagError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub(crate) fn write(path: &Path, e: mcap::McapError) -> Self {
        Self::Write {
            path: path.to_path_buf(),
            reason: e.to_string(),
        }
    }
}

/// The ROS time of nanoseconds since the epoch.
pub fn ns_time(ns: u64) -> crate::msgs::Time {
    crate::msgs::Time {
        sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
        nanosec: (ns % 1_000_000_000) as u32,
    }
}
