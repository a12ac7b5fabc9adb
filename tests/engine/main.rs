//! The engines and fusion: analytic depth, the WGSL engine against its CPU twin, quality on the
//! built-in and shared datasets, fused models against ground truth.
//!
//! One test binary per subject (issue 32): each file below was its own binary.

#[path = "../common/mod.rs"]
mod common;

mod datasets_eval;
mod engine_analytic;
mod fusion_accuracy;
mod gpu_vs_cpu;
mod quality;
