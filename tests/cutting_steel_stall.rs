//! A tool pushed into steel harder than its spindle can cut stalls: the spindle stops (the
//! cut needs more torque than it has), the tool then rubs on the steel and does not go
//! through the part; the slave's force limit is meant to hold the true force (the ignored
//! test below gives the measured figure).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master::session::{self, Summary};

/// The pocket session in steel with no depth floor and a spindle of `torque_n_mm`.
fn run(torque_n_mm: Option<f64>) -> (Summary, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let mut o: Vec<String> = [
        "cutting.material=steel",
        "environment.material=steel",
        // No depth floor: only the stall and the force limit stand between the push and
        // the part.
        "fixtures.depth_floor.z_mm=-400",
        "duration_s=10",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    if let Some(t) = torque_n_mm {
        o.push(format!("cutting.tool.max_torque_n_mm={t}"));
    }
    let cfg = session::load(&path, &o).unwrap();
    let limit = cfg.slave.controller.force_limit_n;
    (session::run(&cfg, None).unwrap(), limit)
}

/// Spindles of 20 and 30 N·mm (about 25 and 40 W at 12 000 rev/min) stall in steel and the
/// tool does not cut below the pocket's depth; the shipped 300 N·mm spindle, the control,
/// cuts the same steel without stalling and removes more.
#[test]
fn a_weak_spindle_in_steel_stalls_and_stops_cutting() {
    let (strong, _) = run(None);
    let c_strong = strong.cutting.as_ref().unwrap();
    assert_eq!(c_strong.spindle_stalls, 0);
    for torque in [20.0, 30.0] {
        let (s, _) = run(Some(torque));
        let c = s.cutting.as_ref().unwrap();
        assert!(c.spindle_stalls >= 1, "{torque} N·mm never stalled: {c:?}");
        assert_eq!(
            c.gouge_max_mm, 0.0,
            "{torque} N·mm: cut {} mm too deep",
            c.gouge_max_mm
        );
        assert!(
            c.removed_volume_mm3 < 0.5 * c_strong.removed_volume_mm3,
            "{torque} N·mm removed {} mm³, the strong spindle {}",
            c.removed_volume_mm3,
            c_strong.removed_volume_mm3
        );
    }
}

/// The force limit during the stall. Measured 2026-12-02: true force peaks at 74.8 N
/// (20 N·mm) and 80.5 N (30 N·mm) against the slave's 80 N limit: the stalled tool rubs on
/// 2000 N/mm steel and the force guard backs off one overshoot late.
#[test]
#[ignore = "figure: true force 80.5 N > 80 N limit with a 30 N·mm spindle (74.8 N at 20 N·mm); see docs/cutting.md"]
fn the_stall_stays_within_the_force_limit() {
    for torque in [20.0, 30.0] {
        let (s, limit) = run(Some(torque));
        assert!(
            s.max_force_n <= limit,
            "{torque} N·mm: true force {} N > {limit} N",
            s.max_force_n
        );
    }
}
