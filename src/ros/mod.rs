//! ROS 2 plumbing that needs no DDS: the command line and names ([`args`]), parameter values
//! ([`param_value`]), N-ary time synchronisation of camera sets ([`sync`]) and a tf2-style
//! transform tree ([`tf_history`], with time; [`tf`], its static view; tf2's rules in
//! [`tf_checks`]). The node (over `ros2-client`) builds on these.

pub mod args;
pub mod camera_info;
pub mod param_value;
pub mod sync;
pub mod tf;
pub mod tf_checks;
pub mod tf_history;
