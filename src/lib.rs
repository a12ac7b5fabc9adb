//! sweepdepth: multi-camera plane-sweep depth (Woetzel & Koch 2004) on wgpu compute shaders.
//!
//! See `ARCHITECTURE.md` for the map of modules and the path a frame takes.

pub mod bag;
pub mod bench;
pub mod datasets;
pub mod demo;
pub mod engine;
pub mod eval;
pub mod geometry;
pub mod gpu_context;
pub mod image;
pub mod io;
pub mod msgs;
pub mod node;
pub mod ros;
pub mod sweep;
pub mod synthetic;
