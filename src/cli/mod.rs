//! The subcommands that only print: `demo` (the engine on the built-in sample) and `bench`
//! (speed beside OpenCV SGBM and Open3D). Their errors are `anyhow` (printed by `main.rs`, never
//! handled); the library under them returns typed errors. `eval` stays a library module: its
//! metrics serve the tests too.

pub mod bench;
pub mod demo;
