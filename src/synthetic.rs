//! Synthetic scenes (placeholder).
