//! The h4-teleop slave: the H-4 arm's force loop, its simulated plant, and the tools of
//! the `h4-slave` command.

pub mod kin_tool;
