//! The turntable end to end: `config/sessions/cut-profile.toml` (a contour round the turning
//! part in aluminium) cuts its ring groove and writes the part; the turntable-synchronous
//! fixture makes the part round while the operator moves only radially, and holds the tool on
//! its radial line when the operator strays (docs/cutting.md).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::PI;
use std::path::PathBuf;

use h4_master_sim::operator::IntentSegment;
use h4_master_sim::session::{self, Session, SessionConfig};
use h4_slave_sim::plant::cutting::Stock;

fn profile(overrides: &[&str]) -> SessionConfig {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-profile.toml");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    session::load(&path, &o).unwrap()
}

/// The ball's segment 3 mm in radius, `d` deep: a groove's cross-section, mm².
fn segment_mm2(d: f64) -> f64 {
    let r = 3.0_f64;
    r * r * ((r - d) / r).acos() - (r - d) * (2.0 * r * d - d * d).max(0.0).sqrt()
}

/// The cut's depth below the top on the radial line at azimuth `phi` about the workpiece
/// point `c`, at radius `rho`, mm.
fn depth_at(stock: &Stock, c: [f64; 2], phi: f64, rho: f64) -> f64 {
    stock.top_mm()
        - stock
            .height_under(c[0] + rho * phi.cos(), c[1] + rho * phi.sin())
            .unwrap()
}

/// The radii between `r0` and `r1` (searched every 0.01 mm) where the cut on that radial
/// line is deeper than `d_mm`: the first and the last, mm (NaN: nowhere).
fn edges(stock: &Stock, c: [f64; 2], phi: f64, r0: f64, r1: f64, d_mm: f64) -> (f64, f64) {
    let (mut first, mut last) = (f64::NAN, f64::NAN);
    let mut rho = r0;
    while rho <= r1 {
        if depth_at(stock, c, phi, rho) > d_mm {
            if first.is_nan() {
                first = rho;
            }
            last = rho;
        }
        rho += 0.01;
    }
    (first, last)
}

/// `cut-profile.toml` as shipped: the ring groove is cut all round (its volume within 10 % of
/// the ball's segment 1 mm deep × the circumference at 25 mm), the part's files are written,
/// the recording carries the turntable's angle and its command, the true force stays within
/// the slave's force limit, no stall, no gouge below the floor, and the surface error p99
/// against the ring is within the 0.3 mm.
#[test]
fn the_profile_session_cuts_the_ring_and_writes_the_part() {
    let cfg = profile(&[]);
    let dir = std::env::temp_dir().join(format!("h4-cut-profile-{}", std::process::id()));
    let mut rec = h4_telemetry::recording::Recorder::in_memory().unwrap();
    let s = session::run_with_outputs(&cfg, Some(&mut rec), Some(&dir)).unwrap();
    let c = s.cutting.as_ref().expect("cutting fields");
    let ring = segment_mm2(1.0) * 2.0 * PI * 25.0;
    assert!(
        (c.removed_volume_mm3 - ring).abs() < 0.1 * ring,
        "removed {} mm³, the ring holds {ring}",
        c.removed_volume_mm3
    );
    let limit = cfg.slave.controller.force_limit_n;
    assert!(
        s.max_force_n <= limit,
        "true force {} N over the slave's limit {limit} N",
        s.max_force_n
    );
    assert!(c.cutting_force_max_n <= limit, "{}", c.cutting_force_max_n);
    assert_eq!(c.spindle_stalls, 0);
    assert!(c.gouge_max_mm <= 0.05, "gouge {}", c.gouge_max_mm);
    // The target for the aluminium profile on the turning part.
    assert!(
        c.surface_error_p99_mm <= 0.3,
        "surface error p99 {} mm",
        c.surface_error_p99_mm
    );
    h4_tests::check_cut_outputs(&dir);
    let bytes = rec.finish_into_bytes().unwrap();
    let last = h4_tests::cut_records(&bytes).1.unwrap();
    let angle = last["turntable_rad"].as_f64().unwrap();
    let cmd = last["turntable_cmd_rad"].as_f64().unwrap();
    // 17 s at 0.5 rad/s after a 0.25 s ramp (the safe stop never held it).
    assert!(
        (cmd - (0.5 * 17.0 - 0.0625)).abs() < 0.01,
        "commanded {cmd} rad"
    );
    assert!(
        (angle - cmd).abs() < 0.02,
        "true {angle} vs commanded {cmd}"
    );
    // The tip in the workpiece frame: 25 mm from the axis, turned with the part.
    let tip = last["tool_tip_in_workpiece_mm"].as_array().unwrap();
    let (x, y) = (tip[0].as_f64().unwrap() + 25.0, tip[1].as_f64().unwrap());
    assert!(((x * x + y * y).sqrt() - 25.0).abs() < 0.5, "{last}");
    let a = (y.atan2(x) + angle).rem_euclid(2.0 * PI);
    assert!(
        a.min(2.0 * PI - a) < 0.05,
        "the tip does not turn with the part: {last}"
    );
}

/// The operator's script for the synchronous-mode test: down at 25 mm from the axis for a
/// revolution and a quarter of the table (0.5 rad/s), then radially in to 19 mm (the hand,
/// feeling the cut's resistance, takes ~10 s to get there) and a revolution and more there,
/// then up; straying `stray_mm` sideways (along y) all the while.
fn radial_operator(stray_mm: f64) -> Vec<IntentSegment> {
    let seg = |at_s: f64, x: f64, y: f64, z: f64, move_s: f64, push_z: f64| IntentSegment {
        at_s,
        target_mm: [x, y, z],
        move_s,
        push_n: [0.0, 0.0, push_z],
        push_ramp_s: 0.5,
        clutch: false,
        theta_rad: 0.0,
    };
    let mut v = vec![
        seg(0.0, 0.0, 0.0, 0.0, 0.5, 0.0),
        seg(0.5, 0.0, 0.0, 0.0, 0.0, -5.0),
    ];
    let (inward_s, up_s) = (17.5, 42.0);
    let mut t = 1.0;
    let mut side = 1.0;
    while t < up_s {
        let x = if t < inward_s { 0.0 } else { -6.0 };
        v.push(seg(t, x, side * stray_mm, 0.0, 1.0, -5.0));
        side = -side;
        t += 1.5;
    }
    v.push(seg(up_s, -6.0, 0.0, 3.0, 0.5, 0.0));
    v
}

/// The cut of the synchronous session variant with `stray_mm` of sideways stray, with or
/// without the synchronous fixture; and the largest distance of the tool's true point from
/// the fixture's radial line (y = 0) while it cuts.
fn radial_run(sync: bool, stray_mm: f64) -> (Stock, f64) {
    let mut cfg = profile(&["duration_s=43"]);
    cfg.operator.intent = radial_operator(stray_mm);
    cfg.cut_target = None;
    if !sync {
        cfg.fixtures.turntable_sync = None;
    }
    let mut s = Session::new(&cfg).unwrap();
    let off = h4_tests::max_while_cutting(&mut s, 43_000, -250.5, |p| p[1].abs());
    (s.slave.arm().cut().unwrap().stock().clone(), off)
}

/// The synchronous fixture: the operator moves only radially (25 mm, then 19 mm from the
/// axis) and the turning part gets a round profile: two concentric grooves all round, whose
/// outer and inner edges (where the cut is 0.5 mm deep: the ball's half-width there, 1.66 mm,
/// beyond the tool's circle; the spiral between the two lies inside them) are circles at
/// those radii; straying 2 mm sideways, the tool stays on the radial line. Control: without
/// the fixture the table does not turn and only a radial slot is cut.
#[test]
fn the_synchronous_fixture_turns_radial_guidance_into_a_round_part() {
    let c = [-25.0, 0.0];
    let half = (2.0_f64 * 3.0 * 0.5 - 0.25).sqrt();
    let (stock, off) = radial_run(true, 2.0);
    assert!(off < 0.3, "the tool strayed {off} mm off the radial line");
    let (mut outer, mut inner) = (Vec::new(), Vec::new());
    for i in 0..36 {
        let phi = f64::from(i) * PI / 18.0 + 0.05;
        let (first, last) = edges(&stock, c, phi, 12.0, 32.0, 0.5);
        assert!(
            depth_at(&stock, c, phi, 25.0) > 0.8 && depth_at(&stock, c, phi, 19.0) > 0.8,
            "azimuth {phi:.2}: a groove is missing"
        );
        outer.push(last);
        inner.push(first);
    }
    for (edge, want, name) in [
        (&outer, 25.0 + half, "outer"),
        (&inner, 19.0 - half, "inner"),
    ] {
        let lo = edge.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = edge.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        assert!(
            (lo - want).abs() < 0.3 && (hi - want).abs() < 0.3,
            "the {name} edge runs from {lo} to {hi} mm, the operator's circle's at {want}"
        );
        assert!(
            hi - lo < 0.3,
            "the {name} edge is not round: {lo} to {hi} mm"
        );
    }
    let (still, _) = radial_run(false, 0.0);
    let round = (0..36)
        .filter(|i| {
            let phi = f64::from(*i) * PI / 18.0 + 0.05;
            depth_at(&still, c, phi, 25.0) > 0.8
        })
        .count();
    assert!(
        round <= 3,
        "without the fixture {round} of 36 azimuths are cut"
    );
}
