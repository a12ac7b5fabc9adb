//! File formats: PFM, PNG colour maps (placeholder).
