//! The `sweepdepth` command line.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "sweepdepth",
    version,
    about = "Multi-camera plane-sweep depth on the GPU (Woetzel & Koch 2004)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the engine on datasets with ground truth and print bad-pixel rates.
    Eval(sweepdepth::eval::EvalArgs),
    /// Measure hypotheses per second and per-stage GPU times.
    Bench(sweepdepth::cli::bench::BenchArgs),
    /// Run the engine on the built-in sample data and write depth images.
    Demo(sweepdepth::cli::demo::DemoArgs),
    /// The ROS 2 node: `sweepdepth node --ros-args -p 'cameras:=[left, centre, right]' ...`.
    Node {
        /// Everything after `node` (the `--ros-args ...` block), parsed as rcl does.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, num_args = 0..)]
        args: Vec<String>,
    },
    /// Fusion alone, as a node: depth image topics (of sweepdepth nodes on other machines, a
    /// RealSense, ...) + /tf into one mesh: `sweepdepth fuse --ros-args -p
    /// 'depth_topics:=[/a/cam0/depth/image, /b/cam4/depth/image]' -p world_frame:=map` (a list
    /// with spaces in quotes).
    Fuse {
        /// Everything after `fuse` (the `--ros-args ...` block), parsed as rcl does.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, num_args = 0..)]
        args: Vec<String>,
    },
    /// Process a rosbag2 bag (MCAP or sqlite3) offline through the node's pipeline.
    Bag(sweepdepth::bag::process::BagArgs),
    /// Pack a dataset folder (or images + a rig file) into a bag with a parameter file.
    Pack(sweepdepth::bag::pack::PackArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // A node's `--log-level` (rcl's rules) where `RUST_LOG` is not set.
    let level = match &cli.command {
        Command::Node { args } => {
            sweepdepth::ros::args::node_log_level(args, sweepdepth::ros::args::DEFAULT_NODE_NAME)
        }
        Command::Fuse { args } => sweepdepth::ros::args::node_log_level(
            args,
            sweepdepth::node::fuse_command::DEFAULT_FUSE_NODE_NAME,
        ),
        _ => None,
    };
    sweepdepth::logging::init(level.as_deref());
    // Before any thread starts (set_var is only sound then).
    let mut defaults = vec![
        sweepdepth::process_env::quiet_vulkan_device_select(),
        sweepdepth::process_env::keep_freed_memory(),
    ];
    if matches!(cli.command, Command::Node { .. } | Command::Fuse { .. }) {
        defaults.push(sweepdepth::process_env::default_ros_distro());
    }
    for note in defaults.into_iter().flatten() {
        tracing::debug!("{note}");
    }
    let result = match cli.command {
        Command::Eval(args) => sweepdepth::eval::run(&args).map_err(anyhow::Error::from),
        Command::Bench(args) => sweepdepth::cli::bench::run(&args),
        Command::Demo(args) => sweepdepth::cli::demo::run(&args),
        Command::Node { args } => sweepdepth::node::run(&args).map_err(anyhow::Error::from),
        Command::Fuse { args } => {
            sweepdepth::node::fuse_command::run(&args).map_err(anyhow::Error::from)
        }
        Command::Bag(args) => sweepdepth::bag::process::run(&args).map_err(anyhow::Error::from),
        Command::Pack(args) => sweepdepth::bag::pack::run(&args).map_err(anyhow::Error::from),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", sweepdepth::cli::error_line(&error));
            ExitCode::FAILURE
        }
    }
}
