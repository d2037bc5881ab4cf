//! A tool pushed into steel harder than its spindle can cut stalls safely: the spindle stops
//! (the cut needs more torque than it has), the tool then rubs on the steel, the slave's
//! force limit holds the true force, and the tool does not go through the part.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master::session;

#[test]
fn a_weak_spindle_in_steel_stalls_within_the_force_limit() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let o: Vec<String> = [
        "cutting.material=steel",
        "environment.material=steel",
        // No depth floor: only the stall and the force limit stand between the push and
        // the part.
        "fixtures.depth_floor.z_mm=-400",
        // A ~60 W spindle: 50 N·mm at 12 000 rev/min.
        "cutting.tool.max_torque_n_mm=50",
        "duration_s=10",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let cfg = session::load(&path, &o).unwrap();
    let limit = cfg.slave.controller.force_limit_n;
    let s = session::run(&cfg, None).unwrap();
    let c = s.cutting.as_ref().unwrap();
    assert!(c.spindle_stalls >= 1, "the spindle never stalled: {c:?}");
    assert!(
        s.max_force_n <= limit,
        "true force {} N over the slave's limit {limit} N",
        s.max_force_n
    );
    // Not through the part: nothing cut below the pocket's depth (2 mm).
    assert_eq!(c.gouge_max_mm, 0.0, "cut {} mm below 2 mm", c.gouge_max_mm);
    // The control: the default spindle (300 N·mm) cuts the same steel without stalling.
    let o2: Vec<String> = o
        .iter()
        .filter(|s| !s.starts_with("cutting.tool.max_torque"))
        .cloned()
        .collect();
    let s2 = session::run(&session::load(&path, &o2).unwrap(), None).unwrap();
    let c2 = s2.cutting.as_ref().unwrap();
    assert_eq!(c2.spindle_stalls, 0);
    assert!(c2.removed_volume_mm3 > c.removed_volume_mm3);
}
