//! The operator feels the cut: with `coupling.feed_force_gain` the master renders the
//! slave's cutting resistance along the feed direction, × `scale.force` (and nothing along
//! the feed without it; the guide spring acts along the normal only).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master_sim::session::{self, Session};

/// Over 6 s of the pocket session (the first passes): the mean rendered force along the
/// handle's horizontal motion while it feeds, and the slave's measured force along it × the
/// force scale, N.
fn feed_forces(gain: f64) -> (f64, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let o = vec![
        format!("coupling.feed_force_gain={gain}"),
        "duration_s=12".to_string(),
    ];
    let cfg = session::load(&path, &o).unwrap();
    let scale = cfg.scale.force;
    let mut s = Session::new(&cfg).unwrap();
    let (mut rendered, mut slave, mut n) = (0.0, 0.0, 0u32);
    for k in 0..12_000 {
        let (m, sl) = s.cycle().unwrap();
        if k < 3000 {
            continue;
        }
        let v = [m.handle.velocity[0], m.handle.velocity[1]];
        let speed = (v[0] * v[0] + v[1] * v[1]).sqrt();
        if speed < 5.0 {
            continue;
        }
        let e = [v[0] / speed, v[1] / speed];
        rendered += m.rendered_wrench[0] * e[0] + m.rendered_wrench[1] * e[1];
        let w = sl.out.wrench_measured;
        slave += scale * (w[0] * e[0] + w[1] * e[1]).min(0.0);
        n += 1;
    }
    assert!(n > 1000, "the handle hardly fed: {n} cycles");
    (rendered / f64::from(n), slave / f64::from(n))
}

#[test]
fn the_master_renders_the_cutting_resistance_along_the_feed() {
    let (rendered, slave) = feed_forces(1.0);
    assert!(
        slave < -0.2,
        "no cutting resistance at the slave: {slave} N"
    );
    assert!(
        rendered < 0.0,
        "the rendered force does not oppose the feed: {rendered} N"
    );
    // Through the passivity controller and one cycle's delay: within 30 % of the scaled
    // resistance.
    assert!(
        (rendered - slave).abs() < 0.3 * slave.abs(),
        "rendered {rendered} N vs scaled resistance {slave} N"
    );
    let (off, _) = feed_forces(0.0);
    assert!(
        off.abs() < 0.1 * slave.abs(),
        "without the gain {off} N along the feed"
    );
}
