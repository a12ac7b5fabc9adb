//! A tf2-style buffer of static transforms (in progress).
