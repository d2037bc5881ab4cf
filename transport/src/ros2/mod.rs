//! ROS 2 over rmw_zenoh, without a ROS installation: the wire format (issue 35, first step).
//!
//! * [`cdr`]: little-endian plain CDR writer and reader (the reader never panics).

pub mod cdr;
