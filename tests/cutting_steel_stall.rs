//! A tool pushed into steel harder than its spindle can cut stalls: the spindle stops (the
//! cut needs more torque than it has), the tool then rubs on the steel and does not go
//! through the part; the slave's force limit is meant to hold the true force (the ignored
//! test below gives the measured figure).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Summary};

/// The pocket session in steel with no depth floor and a spindle of `torque_n_mm`.
fn run(torque_n_mm: Option<f64>) -> (Summary, f64) {
    run_in("steel", torque_n_mm, None, &[])
}

/// The pocket session in `material` with no depth floor, a spindle of `torque_n_mm`, the
/// simulation's `seed` and `extra` overrides.
fn run_in(
    material: &str,
    torque_n_mm: Option<f64>,
    seed: Option<u64>,
    extra: &[&str],
) -> (Summary, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let mut o: Vec<String> = vec![
        format!("cutting.material={material}"),
        format!("environment.material={material}"),
        // No depth floor: only the stall and the force limit stand between the push and
        // the part.
        "fixtures.depth_floor.z_mm=-400".to_string(),
        format!("duration_s={GRID_DURATION_S}"),
    ];
    if let Some(t) = torque_n_mm {
        o.push(format!("cutting.tool.max_torque_n_mm={t}"));
    }
    if let Some(seed) = seed {
        o.push(format!("seed={seed}"));
    }
    o.extend(extra.iter().map(|e| e.to_string()));
    // The control turns the stall stop (a safety layer) off: only with the override.
    let control = extra.contains(&"slave.controller.spindle_stall_safe_stop=false");
    let cfg = session::load_with(&path, &o, control).unwrap();
    let limit = cfg.slave.controller.force_limit_n;
    (session::run(&cfg, None).unwrap(), limit)
}

/// Spindles of 20 and 30 N·mm (about 25 and 40 W at 12 000 rev/min) stall in steel and the
/// tool does not cut below the pocket's depth; the shipped 300 N·mm spindle, the control,
/// cuts the same steel without stalling and removes more (each stall stops the cut: the safe
/// stop retracts the tool and the operator re-pairs; measured 2026-12-04 over 10 s, the
/// session's integrating sensor: 20 N·mm 8 stalls, 12.0 mm³; 30 N·mm 5 stalls, 32.7 mm³;
/// 300 N·mm 379.0 mm³. With the instant sampler the strong spindle removed 40.0 mm³: the
/// aliased reading held the true axial force at 0.3–5 N for a 6.25 N set-point).
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
            c.removed_volume_mm3 < 0.9 * c_strong.removed_volume_mm3,
            "{torque} N·mm removed {} mm³, the strong spindle {}",
            c.removed_volume_mm3,
            c_strong.removed_volume_mm3
        );
    }
}

/// One run of the stall grid.
struct Stall {
    case: String,
    max_force_n: f64,
    limit_n: f64,
    stalls: u64,
    /// When the last stall began, s (NaN: none).
    last_stall_s: f64,
    safe_stops: u64,
    /// Of those, the safety monitor's trips.
    monitor_trips: u64,
    repairs: u64,
}

/// The grid's session length, s (`run_in`).
const GRID_DURATION_S: f64 = 10.0;
/// A stall's safe stop lifts the tool until the spindle turns again, then the master
/// re-pairs: 1.1–2.3 s in the grid (measured 2026-12-04). A run that ends sooner after its
/// only stall is not asked to have re-paired.
const REPAIR_WINDOW_S: f64 = 3.0;

/// Resin, aluminium and steel × spindles of 20, 30, 45 and 60 N·mm (all too weak for the
/// pushed cut) × seeds 1–3, no depth floor, with `extra` overrides.
fn stall_grid(extra: &[&str]) -> Vec<Stall> {
    stall_runs(&[20.0, 30.0, 45.0, 60.0], &[1, 2, 3], extra)
}

/// The three materials × `torques_n_mm` × `seeds`, no depth floor, with `extra` overrides.
fn stall_runs(torques_n_mm: &[f64], seeds: &[u64], extra: &[&str]) -> Vec<Stall> {
    let mut runs = Vec::new();
    for material in ["resin", "aluminium", "steel"] {
        for &torque in torques_n_mm {
            for &seed in seeds {
                let (s, limit_n) = run_in(material, Some(torque), Some(seed), extra);
                let c = s.cutting.as_ref().unwrap();
                runs.push(Stall {
                    case: format!("{material}, {torque} N·mm, seed {seed}"),
                    max_force_n: s.max_force_n,
                    limit_n,
                    stalls: c.spindle_stalls,
                    last_stall_s: c.spindle_last_stall_s,
                    safe_stops: s.slave_safe_stops,
                    monitor_trips: s.safety_trips.total(),
                    repairs: s.repairs,
                });
            }
        }
    }
    runs
}

/// At least `min_stalled` runs stalled; every stalled run safe-stopped and re-paired (unless
/// its only stall began in its last [`REPAIR_WINDOW_S`]); every run's true force within the
/// slave's limit.
fn check_stalls(runs: &[Stall], min_stalled: usize) {
    let stalled = runs.iter().filter(|r| r.stalls > 0).count();
    assert!(
        stalled >= min_stalled,
        "only {stalled} of {} runs stalled",
        runs.len()
    );
    for r in runs {
        if r.stalls > 0 {
            assert!(
                r.safe_stops >= 1,
                "{}: stalled {} times, no safe stop",
                r.case,
                r.stalls
            );
            let only_stall_at_the_end =
                r.stalls == 1 && r.last_stall_s > GRID_DURATION_S - REPAIR_WINDOW_S;
            assert!(
                r.repairs >= 1 || only_stall_at_the_end,
                "{}: never re-paired after its stall at {} s",
                r.case,
                r.last_stall_s
            );
        }
        assert!(
            r.max_force_n <= r.limit_n,
            "{}: true force {} N > {} N",
            r.case,
            r.max_force_n,
            r.limit_n
        );
    }
}

/// Spindles and seeds the grid does not have (25, 40, 52, 70 N·mm × seeds 4–7 × the three
/// materials, 48 runs): the same guarantees. Measured 2026-12-04 night: all 48 stall, true
/// force at most 51.0 N (instant sampler: 39 stall, 61.5 N; 164.1 N, aluminium 40 N·mm
/// seed 7, before the rubbing followed each cell's way out of the tool).
#[test]
fn a_stall_off_the_grid_stays_within_the_force_limit() {
    let runs = stall_runs(&[25.0, 40.0, 52.0, 70.0], &[4, 5, 6, 7], &[]);
    check_stalls(&runs, 30);
}

/// A stall on any material, at any spindle too weak for the cut, with any seed: the slave
/// stops itself (its safe stop: the force ramps down, the tool retracts, and lifts further
/// while the spindle stays stalled; the master cannot clear it meanwhile), the spindle runs
/// again and the master re-pairs, and the true force stays within the slave's force limit.
/// Measured 2026-12-04 (night), with the session's integrating sensor
/// (`slave.sensor.adc_aperture = "period"`): 1–9 stalls per run (the scripted operator
/// pushes on after each), all 36 runs stall, true force at most 63.1 N (aluminium, 60 N·mm,
/// seed 2) against 80 N; with the instant sampler 30 runs stall, at most 58.2 N. Before the
/// stalled tool's rubbing took each cell's way out along the tool's surface (it took the
/// single deepest cell's, up or sideways, and the push flipped between the groove's walls as
/// the lifting tool rattled in it) the grid reached 77.0 N (instant) and 100.4 N (period),
/// and a case outside it 164.1 N (aluminium, 40 N·mm, seed 7, instant).
///
/// Two layers keep it there, each shown needed by a control over the same grid:
/// * without the stall's safe stop (`spindle_stall_safe_stop = false`, the behaviour before
///   2026-12-02) the operator feeds the stalled tool on: 12 of 36 runs above 80 N, up to
///   107.5 N (9 above 1.15 × the limit);
/// * without the cutter's feed limit (`max_feed_mm_per_s = 0`, before 2026-12-03) the tool
///   point, pulled towards the operator's point after a re-touch, is rammed sideways into
///   the stock at ~100 mm/s: the runs' peaks average 49.6 N against 29.4 N with it, 32 of
///   36 above half the limit against 14, up to 83.8 N (2 runs above the limit; 10, up to
///   96.9 N, with the old rubbing and the instant sampler).
#[test]
fn a_stall_stops_the_slave_within_the_force_limit_on_every_material() {
    let runs = stall_grid(&[]);
    check_stalls(&runs, 24);
    let control = stall_grid(&["slave.controller.spindle_stall_safe_stop=false"]);
    let over: Vec<&Stall> = control
        .iter()
        .filter(|r| r.max_force_n > 1.15 * r.limit_n)
        .collect();
    assert!(
        over.len() >= 4,
        "without the stall's safe stop only {} runs above 1.15 × the limit",
        over.len()
    );
    // Without the stall stop the only safe stops are the safety monitor's (the force over
    // the limit): it is a separate layer, still on.
    assert!(
        control.iter().all(|r| r.safe_stops == r.monitor_trips),
        "{:?}",
        control
            .iter()
            .map(|r| (r.safe_stops, r.monitor_trips))
            .collect::<Vec<_>>()
    );
    println!(
        "without the stall stop: {} monitor trips in {} runs",
        control.iter().map(|r| r.monitor_trips).sum::<u64>(),
        control.len()
    );
    // The feed limit's control: the peaks, not the limit (few runs pass it without).
    let peaks = |runs: &[Stall]| {
        let mean = runs.iter().map(|r| r.max_force_n).sum::<f64>() / runs.len() as f64;
        let over_half = runs
            .iter()
            .filter(|r| r.max_force_n > 0.5 * r.limit_n)
            .count();
        (mean, over_half)
    };
    let unlimited = stall_grid(&["slave.controller.max_feed_mm_per_s=0"]);
    let ((mean, over), (mean_limited, over_limited)) = (peaks(&unlimited), peaks(&runs));
    assert!(
        mean > 1.4 * mean_limited && over >= 2 * over_limited,
        "without the feed limit peaks {mean:.1} N on average, {over} runs above half the \
         limit; with it {mean_limited:.1} N, {over_limited}"
    );
}
