//! Master/slave links for h4-teleop. Not yet implemented: see the open transport issues.
