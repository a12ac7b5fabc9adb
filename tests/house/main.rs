//! The house: the architecture rules, the colcon package, the engine against a failing device,
//! the documents' links.
//!
//! One test binary per subject (issue 32): each file below was its own binary.

mod architecture;
mod colcon;
mod doc_links;
mod gpu_faults;
