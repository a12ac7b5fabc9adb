//! Messages, camera models, rig files, parameter files and command lines: what sweepdepth reads and writes, checked without DDS;
//! the pipeline on hostile inputs and a camera leaving and rejoining the rig.
//!
//! One test binary per subject (issue 32): each file below was its own binary (`camera_rejoin`
//! was a module of `hostile_inputs`).

#[path = "../common/mod.rs"]
mod common;

mod camera_conventions;
mod camera_kinds;
mod camera_rejoin;
mod hostile_inputs;
mod launch_configs;
mod msgs_cdr;
mod rig_file;
mod ros_args;
