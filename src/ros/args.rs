//! `--ros-args` parsing and the parameter table (in progress).
