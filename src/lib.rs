//! sweepdepth: multi-camera plane-sweep depth (Woetzel & Koch 2004) on wgpu compute shaders.
//!
//! See `ARCHITECTURE.md` for the map of modules and the path a frame takes.

// No unwrap()/expect() in library code: input reaches most of it (messages, bags, parameter
// files), and every failure there is an error with a reason. Tests may unwrap.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod bag;
pub mod bench;
pub mod datasets;
pub mod demo;
pub mod engine;
pub mod eval;
pub mod fusion;
pub mod geometry;
pub mod gpu_context;
pub mod image;
pub mod io;
pub mod logging;
pub mod msgdefs;
pub mod msgs;
pub mod node;
pub mod params;
pub mod pipeline;
pub mod process_env;
pub mod rig_file;
pub mod ros;
pub mod sweep;
pub mod synthetic;
pub mod viewer;
