//! Rig files: the node's own YAML format and Kalibr camchain.yaml (in progress).
