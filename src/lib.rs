//! sweepdepth: multi-camera plane-sweep depth (Woetzel & Koch 2004) on wgpu compute shaders.
//!
//! See `ARCHITECTURE.md` for the map of modules and the path a frame takes.

pub mod geometry;
pub mod gpu_context;
pub mod image;
pub mod msgs;
pub mod sweep;
