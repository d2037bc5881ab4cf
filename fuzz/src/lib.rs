//! h4-teleop's fuzz targets (see src/targets.rs).
#![allow(clippy::unwrap_used, clippy::expect_used)]

pub mod targets;
