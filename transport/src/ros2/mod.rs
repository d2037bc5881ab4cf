//! ROS 2 over rmw_zenoh, without a ROS installation: the wire format (issue 35, first step).
//!
//! * [`cdr`]: little-endian plain CDR writer and reader (the reader never panics);
//! * [`msgs`]: the messages and the [`msgs::Ros2Message`] trait: encode, decode, finiteness;
//! * [`type_hash`]: REP 2011 type descriptions and their RIHS01 hashes;
//! * [`keys`]: topic key expressions, liveliness tokens, the QoS chunk and the attachment.

pub mod cdr;
pub mod keys;
pub mod msgs;
pub mod type_hash;
