//! rosbag2 bags: `sweepdepth bag` and `pack` end to end (raw and compressed images, faults, why no depth).
//!
//! One test binary per subject (issue 32): each file below was its own binary.

#[path = "../common/mod.rs"]
mod common;

mod bag;
mod bag_compressed;
mod bag_faults;
mod bag_foreign;
mod bag_maps;
mod bag_outputs;
mod bag_recorded;
mod bag_references;
mod bag_why;
mod util;
