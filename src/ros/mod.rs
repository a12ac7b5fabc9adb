//! ROS 2 plumbing that needs no DDS: time synchronisation of camera sets and the ROS command
//! line / parameter handling. The node itself (over `ros2-client`) builds on these.

pub mod args;
pub mod camera_info;
pub mod rig_file;
pub mod sync;
pub mod tf;
