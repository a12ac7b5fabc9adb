//! sweepdepth: multi-camera plane-sweep depth (Woetzel & Koch 2004) on wgpu compute shaders
//! and on the CPU, as a ROS 2 node, a rosbag2 tool and a library.
//!
//! As a library, the engine takes calibrated images in memory and gives depth maps:
//! - [`geometry`]: [`geometry::CameraModel`] (pinhole intrinsics, lens distortion),
//!   [`geometry::RigidTransform`] (poses named `a_from_b`), [`geometry::Rig`] (the cameras and
//!   the reference);
//! - [`engine::Engine`]: the WGSL engine on a GPU or the CPU engine ([`engine::Device`]), run
//!   through [`engine::Sweeper`]: `run` for one reference, `run_references` for several
//!   references of one set, each with its own neighbours;
//! - [`sweep::SweepParams`]: depth range, planes, cost, scoring, SGM, coarse to fine (their
//!   defaults are the node's);
//! - [`fusion`]: depth maps at their poses into one mesh.
//!
//! ```
//! use sweepdepth::engine::{Device, Engine, Sweeper};
//! use sweepdepth::geometry::CameraModel;
//! use sweepdepth::sweep::SweepParams;
//! use sweepdepth::synthetic::{self, Scene};
//!
//! // Three cameras 10 cm apart looking at a textured wall 2 m away (rendered here; a real
//! // rig's images come from its cameras).
//! let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
//! let rig = synthetic::row_rig(3, 0.1, model, 1)?;
//! let scene = Scene::wall_and_box(2.0, None, model.intrinsics.fx_px);
//! let images = synthetic::render_rig(&scene, &rig);
//!
//! let mut engine = Engine::new(Device::Cpu)?;
//! let params = SweepParams { min_depth_m: 1.0, max_depth_m: 4.0, num_planes: 48, ..SweepParams::default() };
//! let maps = engine.run(&rig, &images, &params)?;
//! // Depth in metres along the reference camera's optical axis, NaN where invalid.
//! let valid: Vec<f32> = maps.depth_m.data.iter().copied().filter(|d| d.is_finite()).collect();
//! let near_2m = valid.iter().filter(|d| (**d - 2.0).abs() < 0.05).count();
//! assert!(near_2m * 10 >= valid.len() * 9);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! See `ARCHITECTURE.md` for the map of modules and the path a frame takes, and `docs/` for the
//! node, bags, the live view, quality and speed.

// No unwrap()/expect() in library code: input reaches most of it (messages, bags, parameter
// files), and every failure there is an error with a reason. Tests may unwrap.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod bag;
pub mod cli;
pub mod datasets;
pub mod engine;
pub mod eval;
pub mod fusion;
pub mod geometry;
pub mod gpu_context;
pub mod handoff;
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
pub mod simd;
pub mod sweep;
pub mod synthetic;
pub mod viewer;
