//! The house: the architecture rules, the colcon package, the engine against a failing device.
//!
//! One test binary per subject (issue 32): each file below was its own binary.

mod architecture;
mod colcon;
mod gpu_faults;
