//! Recordings and the live view: the bag fixture and the hostile recording played live into the
//! node (and the hostile one through `sweepdepth bag`), the Foxglove WebSocket server of the node,
//! and the built-in page in headless Chromium against `bag --view`.
//!
//! One test binary per subject (issue 30 item 5): each file below was its own binary. The DDS
//! tests run their bodies in child processes, each in a network namespace of its own
//! (`common::netns::in_private_netns`, given the test's module-qualified name).

#[path = "../common/mod.rs"]
mod common;

mod bag_live;
mod hostile;
mod viewer_node;
mod viewer_page;
