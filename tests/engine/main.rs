//! The engines and fusion: analytic depth, the WGSL engine against its CPU twin, quality on the
//! built-in and shared datasets, fused models against ground truth, and fusion's memory soak
//! (ignored).
//!
//! One test binary per subject (issues 32 and 30): each file below was its own binary.

#[path = "../common/mod.rs"]
mod common;

mod cost_rows;
mod datasets_eval;
mod engine_analytic;
mod fusion_accuracy;
mod fusion_soak;
mod gpu_vs_cpu;
mod lent_maps;
mod many_cameras;
mod quality;
mod raw_pairs;
mod real_cameras;
