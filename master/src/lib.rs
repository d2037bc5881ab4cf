//! The h4-teleop master. Not yet implemented: see the open master issue.
