//! The scripted pocket in resin (`config/sessions/cut-pocket.toml`): the operator rasters a
//! 2 mm pocket through the force-guided coupling, the slave's plant really cuts it, and the
//! part is judged against the pocket (docs/cutting.md).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Summary};

fn run(overrides: &[&str]) -> Summary {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let cfg = session::load(&path, &o).unwrap();
    session::run(&cfg, None).unwrap()
}

/// The volume of the target pocket: the ball's envelope over the 20 × 12 mm tip region
/// 2 mm deep (floor, straight walls swept by the ball's cap, the corners of revolution).
fn target_volume_mm3() -> f64 {
    let (r, d, a, b) = (3.0_f64, 2.0_f64, 20.0_f64, 12.0_f64);
    // Cross-section of the ball's cap beyond the region's edge: ∫₀^w (d − (r − √(r² − s²))) ds.
    let w = (r * r - (r - d) * (r - d)).sqrt();
    let n = 2000;
    let (mut area, mut rev) = (0.0, 0.0);
    for i in 0..n {
        let s = (i as f64 + 0.5) * w / n as f64;
        let depth = d - (r - (r * r - s * s).sqrt());
        area += depth * w / n as f64;
        rev += depth * 2.0 * std::f64::consts::PI * s * w / n as f64 / 4.0;
    }
    a * b * d + 2.0 * (a + b) * area + 4.0 * rev
}

/// Asserted today: the pocket is cut (its volume within 10 % of the target's), never more
/// than 0.05 mm below the depth floor, without a stall, and the true cutting force stays
/// far inside the slave's force limit.
#[test]
fn the_pocket_is_cut_to_the_floor_without_gouging() {
    let s = run(&[]);
    let c = s
        .cutting
        .as_ref()
        .expect("a cutting session has cutting fields");
    let target = target_volume_mm3();
    assert!(
        (c.removed_volume_mm3 - target).abs() < 0.1 * target,
        "removed {} mm³, the pocket holds {target}",
        c.removed_volume_mm3
    );
    assert!(c.gouge_max_mm <= 0.05, "gouge {} mm", c.gouge_max_mm);
    assert_eq!(c.spindle_stalls, 0);
    assert!(c.removal_rate_mm3_per_s > 1.0);
    assert!(s.max_force_n < 40.0, "true force {} N", s.max_force_n);
    assert!(
        c.fixture_limited_cycles > 1000,
        "the floor never held the tool"
    );
}

/// A control: without the depth floor the same operator cuts far below the pocket (the
/// force-guided push alone sets no depth: a turning ball end pushed with ~6 N sinks through
/// resin), so the floor is what holds the depth.
#[test]
fn without_the_floor_the_push_cuts_below_the_pocket() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let mut cfg = session::load(&path, &["duration_s=10".to_string()]).unwrap();
    cfg.fixtures.depth_floor = None;
    let s = session::run(&cfg, None).unwrap();
    let c = s.cutting.as_ref().unwrap();
    // Judged against the target's floor (no fixture floor).
    assert!(
        c.gouge_max_mm > 1.0,
        "without the floor: {} mm below the pocket",
        c.gouge_max_mm
    );
    let with = run(&["duration_s=10"]);
    assert!(with.cutting.as_ref().unwrap().gouge_max_mm <= 0.05);
}

/// The surface target for the scripted pocket in resin: surface error p99 ≤ 0.2 mm
/// and gouge ≤ 0.05 mm (measured 2026-12-03: 0.075 mm, 0.005 mm; 2026-12-04 with the
/// session's integrating sensor: 0.077 mm, 0.000 mm). The operator guides each
/// line 1.5 mm past the pocket's end and the region fixture holds the tool's tip on the
/// outline. Control: the same operator without the region cuts past both ends (measured
/// 1.03 mm p99); the operator who aims at the ends without a region stopped up to ~1 mm
/// short of them (1.12 mm p99 before 2026-12-03).
#[test]
fn the_pocket_meets_the_surface_target_with_its_region() {
    let s = run(&[]);
    let c = s.cutting.as_ref().unwrap();
    assert!(c.surface_error_p99_mm <= 0.2, "{}", c.surface_error_p99_mm);
    assert!(c.gouge_max_mm <= 0.05, "{}", c.gouge_max_mm);
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let mut cfg = session::load(&path, &[]).unwrap();
    cfg.fixtures.region = None;
    let without = session::run(&cfg, None).unwrap();
    let cw = without.cutting.as_ref().unwrap();
    assert!(
        cw.surface_error_p99_mm > 0.5,
        "without the region: {} mm",
        cw.surface_error_p99_mm
    );
    assert!(cw.removed_volume_mm3 > c.removed_volume_mm3 + 20.0);
}

/// The force target for the scripted pocket: cutting-force deviation p99 ≤ 10 % at
/// steady feed. Not measurable in this session: the depth floor holds the tool in nearly
/// every cycle (49 221 of 51 500 measured 2026-12-03), where the force loop is suspended
/// by design, so no cycle is steady feed. Off the floor the loop holds a steady cut but not
/// through line ends (a roughing pass: 79 % p99): docs/cutting.md, "The sensor and the
/// cut".
#[test]
#[ignore = "figure: force deviation not measurable (no steady feed off the floor); see docs/cutting.md"]
fn the_pocket_meets_the_force_target() {
    let s = run(&[]);
    let c = s.cutting.as_ref().unwrap();
    assert!(
        c.cutting_force_dev_p99_pct <= 10.0,
        "{}",
        c.cutting_force_dev_p99_pct
    );
}

/// `--out` writes the part (height map, deviation map, a closed binary STL) and the
/// recording carries the cut: the tool's tip in the workpiece frame and the cutting force,
/// which the public MCAP reader decodes.
#[test]
fn the_part_files_and_the_recording_carry_the_cut() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let cfg = session::load(&path, &["duration_s=6".to_string()]).unwrap();
    let dir = std::env::temp_dir().join(format!("h4-cut-pocket-{}", std::process::id()));
    let mut rec = h4_telemetry::recording::Recorder::in_memory().unwrap();
    let s = session::run_with_outputs(&cfg, Some(&mut rec), Some(&dir)).unwrap();
    let bytes = rec.finish_into_bytes().unwrap();
    h4_tests::check_cut_outputs(&dir);
    let (count, last) = h4_tests::cut_records(&bytes);
    assert_eq!(count, 6000);
    let last = last.unwrap();
    let removed = last["removed_mm3"].as_f64().unwrap();
    let summary_removed = s.cutting.as_ref().unwrap().removed_volume_mm3;
    assert!(
        (removed - summary_removed).abs() < 1e-6,
        "{removed} vs {summary_removed}"
    );
    let tip = last["tool_tip_in_workpiece_mm"].as_array().unwrap();
    assert!(tip[2].as_f64().unwrap() < -251.0, "{last}");
    assert_eq!(last["cutting_force_n"].as_array().unwrap().len(), 3);
}
