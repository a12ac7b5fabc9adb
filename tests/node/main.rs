//! The nodes over DDS: `sweepdepth node` with RustDDS, Cyclone DDS and rclpy peers, its "no
//! depth" reasons, shutdown, live rate, RustDDS's delivery of large images against Fast DDS,
//! `--ros-args` against rcl, `sweepdepth fuse` on two hosts, and the overload soak (ignored).
//!
//! One test binary per subject (issue 30 item 5): each file below was its own binary. Every test
//! here runs its body in a child process in a network namespace of its own
//! (`common::netns::in_private_netns`, given the test's module-qualified name); the tests whose
//! assertions compare times of one run take the binary to themselves
//! (`in_private_netns_alone`).

#[path = "../common/mod.rs"]
mod common;

mod fuse_node;
mod node_cyclone;
mod node_dds;
mod node_live_rate;
mod node_rclpy;
mod node_shutdown;
mod node_why;
mod rcl_latency;
mod ros_args_rcl;
mod soak;
