//! Dataset loaders (placeholder).
