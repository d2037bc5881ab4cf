//! The dome-and-step block roughed out from above (`config/sessions/cut-mesh-dome.toml`,
//! issue 34): a scripted operator who does not know the part rasters a patch of the stock
//! over the dome, pushing the force-guided coupling's guide spring; the fixture made from
//! the part's mesh keeps the ball's envelope `fixtures.mesh.allowance_mm` off the part, and
//! the part is judged against the mesh (docs/cutting.md, "A part from a CAD mesh").
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, SessionConfig};

fn load(overrides: &[&str]) -> SessionConfig {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-mesh-dome.toml");
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    session::load(&path, &o).unwrap()
}

/// With the mesh fixture the part is not gouged (≤ 0.05 mm), the true force stays within
/// the slave's limit, and the stock over the patch is roughed down to the allowance: the
/// material left above it ≤ 5 % of what was to be removed.
#[test]
fn the_mesh_fixture_keeps_the_part_whole() {
    let cfg = load(&[]);
    let limit = cfg.slave.controller.force_limit_n;
    let s = session::run(&cfg, None).unwrap();
    h4_tests::report_mesh_cut("with the mesh fixture", &s);
    let c = s.cutting.as_ref().unwrap();
    assert!(c.gouge_max_mm <= 0.05, "gouge {} mm", c.gouge_max_mm);
    assert!(
        s.max_force_n <= limit,
        "true force {} N > {limit} N",
        s.max_force_n
    );
    assert!(
        c.fixture_limited_cycles > 1000,
        "the fixture never held the tool"
    );
    assert!(c.removed_volume_mm3 > 100.0, "nothing cut");
    let (left, to_remove) = (
        c.material_left_mm3.unwrap(),
        c.material_to_remove_mm3.unwrap(),
    );
    assert!(to_remove > 100.0, "{to_remove} mm³ to remove");
    assert!(left <= 0.05 * to_remove, "{left} of {to_remove} mm³ left");
}

/// The remaining targets: stable by the detector, and surface error p99 (the
/// machined points' distance to the part's surface) ≤ allowance + 0.2 mm. Measured
/// 2026-12-08: stable, 0 bounces, 0.360 mm (with the vertical height difference as the
/// error and the region fixture on the judged patch's edge, until 2026-12-07: 1 bounce and
/// 0.520 mm).
#[test]
fn the_mesh_session_is_stable_and_within_the_surface_target() {
    let cfg = load(&[]);
    let allowance = cfg.fixtures.mesh.as_ref().unwrap().allowance_mm;
    let s = session::run(&cfg, None).unwrap();
    h4_tests::report_mesh_cut("with the mesh fixture", &s);
    let c = s.cutting.as_ref().unwrap();
    assert!(s.stable, "{:?}", s.unstable_reasons);
    assert!(
        c.surface_error_p99_mm <= allowance + 0.2,
        "surface error p99 {} mm",
        c.surface_error_p99_mm
    );
}

/// The control: the same operator without the mesh fixture pushes the turning ball into
/// the part.
#[test]
fn without_the_mesh_fixture_the_operator_gouges_the_part() {
    let mut cfg = load(&[]);
    cfg.fixtures.mesh = None;
    let s = session::run(&cfg, None).unwrap();
    h4_tests::report_mesh_cut("without the mesh fixture", &s);
    let c = s.cutting.as_ref().unwrap();
    assert!(c.gouge_max_mm > 1.0, "gouge {} mm", c.gouge_max_mm);
}
