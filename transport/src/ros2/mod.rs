//! ROS 2 over rmw_zenoh, without a ROS installation: the wire format (issue 35, first step).
//!
//! * [`cdr`]: little-endian plain CDR writer and reader (the reader never panics);
//! * [`type_hash`]: REP 2011 type descriptions and their RIHS01 hashes.

pub mod cdr;
pub mod type_hash;
