//! The scripted pocket in resin over a delayed, jittery, lossy link (100 ms and 500 ms round
//! trip, 20 % jitter, 5 % loss each way): the depth floor still holds (gouge ≤ 0.05 mm) and
//! the true force stays within the slave's force limit, and the delay matrix's detector calls
//! both runs stable; a tool bouncing on the part is caught by the same detector; and the
//! same over other round trips, seeds and materials.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Summary};

fn run(round_trip_ms: f64) -> (Summary, f64) {
    run_with(round_trip_ms, &[])
}

fn run_with(round_trip_ms: f64, extra: &[&str]) -> (Summary, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let d = round_trip_ms / 2.0;
    let mut o = vec![
        format!("link.delay_ms={d}"),
        format!("link.jitter_ms={}", 0.2 * d),
        "link.loss=0.05".to_string(),
    ];
    o.extend(extra.iter().map(|e| e.to_string()));
    let cfg = session::load(&path, &o).unwrap();
    let limit = cfg.slave.controller.force_limit_n;
    (session::run(&cfg, None).unwrap(), limit)
}

#[test]
fn the_floor_and_the_force_limit_hold_at_100_and_500_ms() {
    for rt in [100.0, 500.0] {
        let (s, limit) = run(rt);
        let c = s.cutting.as_ref().unwrap();
        assert!(
            c.gouge_max_mm <= 0.05,
            "{rt} ms: gouge {} mm",
            c.gouge_max_mm
        );
        assert!(
            s.max_force_n <= limit,
            "{rt} ms: true force {} N > {limit} N",
            s.max_force_n
        );
        assert!(c.removed_volume_mm3 > 100.0, "{rt} ms: nothing cut");
    }
}

/// The verdict: stable by the delay matrix's detector, at 100 and 500 ms, and the
/// part as without delay (measured 2026-12-03, seed 11: both stable, 0 bounces; surface
/// error p99 0.094 mm at 100 ms, 0.147 mm at 500 ms; 766 and 764 mm³; 2026-12-04 with the
/// session's integrating sensor: 0.096 and 0.157 mm, 766 and 764 mm³). At 500 ms the one-way
/// jitter (±50 ms) is beyond the slave's 20 ms watchdog; the session's playout buffer
/// (`slave.playout`) hands the commands on in order and evenly spaced (one safe stop while
/// it learns the link). Control: without it the watchdog trips 168 times and a fifth of the
/// pocket is cut (still stable and safe).
#[test]
fn stable_by_the_detector_at_100_and_500_ms() {
    for rt in [100.0, 500.0] {
        let (s, _) = run(rt);
        assert!(s.stable, "{rt} ms: {:?}", s.unstable_reasons);
        assert_eq!(s.bounces, 0, "{rt} ms");
        let c = s.cutting.as_ref().unwrap();
        assert!(
            c.surface_error_p99_mm <= 0.2,
            "{rt} ms: {}",
            c.surface_error_p99_mm
        );
        assert!(
            s.slave_safe_stops <= 2,
            "{rt} ms: {} safe stops",
            s.slave_safe_stops
        );
    }
    let (s, _) = run_with(500.0, &["slave.playout.enabled=false"]);
    assert!(s.slave_safe_stops > 50, "{} safe stops", s.slave_safe_stops);
    let c = s.cutting.as_ref().unwrap();
    assert!(c.removed_volume_mm3 < 400.0, "{}", c.removed_volume_mm3);
}

/// Cases the tests above do not have: round trips of 100, 250 and 500 ms (20 % jitter, 5 %
/// loss) × seeds 1–3 × resin, aluminium and steel (the session's tool, floor and push): every
/// run stable by the detector, the floor held (gouge ≤ 0.05 mm), the true force within the
/// slave's limit, the pocket cut. Measured 2026-12-04: all 27 stable; gouge ≤ 0.002 mm; true
/// force ≤ 11.9 N in resin, 23.3 N in aluminium, 24.1 N in steel; 763–766, 747–752 and
/// 682–697 mm³ removed.
#[test]
fn other_delays_seeds_and_materials_hold_the_floor_and_stay_stable() {
    for rt in [100.0, 250.0, 500.0] {
        for seed in [1, 2, 3] {
            for material in ["resin", "aluminium", "steel"] {
                let (s, limit) = run_with(
                    rt,
                    &[
                        &format!("seed={seed}"),
                        &format!("cutting.material={material}"),
                        &format!("environment.material={material}"),
                    ],
                );
                let case = format!("{rt} ms, seed {seed}, {material}");
                assert!(s.stable, "{case}: {:?}", s.unstable_reasons);
                let c = s.cutting.as_ref().unwrap();
                assert!(c.gouge_max_mm <= 0.05, "{case}: gouge {}", c.gouge_max_mm);
                assert!(s.max_force_n <= limit, "{case}: {} N", s.max_force_n);
                assert!(c.removed_volume_mm3 > 100.0, "{case}: nothing cut");
            }
        }
    }
}

/// The detector's control in a cut: the slave's force loop told the part is 2 N/mm (with its
/// estimator off), 50 times softer than resin, drives the tool on and off the part; over
/// the same 100 ms link the detector calls it unstable (measured: 2 bounces with the tool
/// lifted off the part). With the spindle stopped (the tool only rubs) it bounces hard.
#[test]
fn the_detector_catches_a_tool_bouncing_on_the_part() {
    let told_soft = [
        "duration_s=12",
        "slave.controller.estimate_env_stiffness=false",
        "slave.controller.initial_env_stiffness_n_per_mm=2",
    ];
    let (s, _) = run_with(100.0, &told_soft);
    assert!(!s.stable && s.bounces >= 1, "{s:?}");
    let mut stopped = told_soft.to_vec();
    stopped.push("cutting.tool.spindle_rpm=0");
    let (s, _) = run_with(0.0, &stopped);
    assert!(!s.stable && s.bounces >= 5, "{s:?}");
}
