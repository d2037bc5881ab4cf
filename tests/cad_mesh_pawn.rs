//! The turned pawn roughed out on the turntable (`config/sessions/cut-mesh-pawn.toml`,
//! issue 34): the table turns the block about the part's axis, a scripted operator who does
//! not know the part walks the tool out along the radius and back pushing the force-guided
//! coupling's guide spring, and the fixture made from the part's mesh, through the table's
//! measured angle, keeps the ball's envelope `fixtures.mesh.allowance_mm` off the part; the
//! part is judged against the mesh (docs/cutting.md, "A part from a CAD mesh").
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, SessionConfig};

/// The session with the link's one-way delay for `round_trip_ms` and `extra` overrides.
fn load(round_trip_ms: f64, extra: &[&str]) -> SessionConfig {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-mesh-pawn.toml");
    let mut o = vec![format!("link.delay_ms={}", round_trip_ms / 2.0)];
    o.extend(extra.iter().map(|e| e.to_string()));
    session::load(&path, &o).unwrap()
}

/// At 0 and 100 ms round trip: the part is not gouged (≤ 0.05 mm), the true force stays
/// within the slave's limit and the session is stable by the detector; the fixture held
/// the tool and the block was cut.
#[test]
fn the_mesh_fixture_keeps_the_pawn_whole_at_0_and_100_ms() {
    for rt in [0.0, 100.0] {
        let cfg = load(rt, &[]);
        let limit = cfg.slave.controller.force_limit_n;
        let s = session::run(&cfg, None).unwrap();
        h4_tests::report_mesh_cut(&format!("{rt} ms round trip"), &s);
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
        assert!(s.stable, "{rt} ms: {:?}", s.unstable_reasons);
        assert!(
            c.fixture_limited_cycles > 1000,
            "{rt} ms: the fixture never held the tool"
        );
        assert!(c.removed_volume_mm3 > 1000.0, "{rt} ms: nothing cut");
        assert!(
            c.material_to_remove_mm3.unwrap() > 100.0,
            "{rt} ms: nothing to remove"
        );
    }
}

/// The remaining targets for the pawn, not met: material left above the allowance
/// ≤ 5 % of what was to be removed and surface error p99 ≤ allowance + 0.2 mm, at 0 and
/// 100 ms. Measured 2026-12-08 at 0 ms: 143.1 of 802.6 mm³ left (17.8 %), surface error
/// p99 2.223 mm; at 100 ms: 142.3 mm³ (17.7 %), 2.167 mm. The scripted operator's single
/// walk out and back does not rough the whole part: in a trial with a 1 mm ball (17.3 %
/// left) the stock along the +x radius was left high over the steep neck under the head
/// (r = 1.5 to 2.5 mm) and over the base's rim (r ≥ 5.5 mm): the ball lags the walk and
/// did not reach past the base's rim at depth; three walks out and back did worse (32 %).
/// Run with `--ignored` to see the figures.
#[test]
#[ignore = "not met: material left 17.8 %, surface error p99 2.22 mm (targets 5 %, 0.5 mm)"]
fn the_pawn_is_roughed_to_the_allowance_and_within_the_surface_target() {
    for rt in [0.0, 100.0] {
        let cfg = load(rt, &[]);
        let allowance = cfg.fixtures.mesh.as_ref().unwrap().allowance_mm;
        let s = session::run(&cfg, None).unwrap();
        h4_tests::report_mesh_cut(&format!("{rt} ms round trip"), &s);
        let c = s.cutting.as_ref().unwrap();
        let (left, to_remove) = (
            c.material_left_mm3.unwrap(),
            c.material_to_remove_mm3.unwrap(),
        );
        assert!(
            left <= 0.05 * to_remove,
            "{rt} ms: {left} of {to_remove} mm³ left"
        );
        assert!(
            c.surface_error_p99_mm <= allowance + 0.2,
            "{rt} ms: surface error p99 {} mm",
            c.surface_error_p99_mm
        );
    }
}

/// The control: the same operator without the mesh fixture pushes the turning ball into
/// the part (the depth floor at the part's base still holds the tip).
#[test]
fn without_the_mesh_fixture_the_operator_gouges_the_pawn() {
    let mut cfg = load(0.0, &[]);
    cfg.fixtures.mesh = None;
    let s = session::run(&cfg, None).unwrap();
    h4_tests::report_mesh_cut("without the mesh fixture", &s);
    let c = s.cutting.as_ref().unwrap();
    assert!(c.gouge_max_mm > 1.0, "gouge {} mm", c.gouge_max_mm);
}
