//! Messages, camera models, rig files, parameter files and command lines: what sweepdepth reads and writes, checked without DDS.
//!
//! One test binary per subject (issue 32): each file below was its own binary.

#[path = "../common/mod.rs"]
mod common;

mod camera_conventions;
mod camera_kinds;
mod hostile_inputs;
mod launch_configs;
mod msgs_cdr;
mod rig_file;
mod ros_args;
