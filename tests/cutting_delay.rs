//! The scripted pocket in resin over a delayed, jittery, lossy link (100 ms and 500 ms round
//! trip, 20 % jitter, 5 % loss each way): the depth floor still holds (gouge ≤ 0.05 mm) and
//! the true force stays within the slave's force limit. The detector's verdict is reported
//! by the ignored test below.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use h4_master::session::{self, Summary};

fn run(round_trip_ms: f64) -> (Summary, f64) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/cut-pocket.toml");
    let d = round_trip_ms / 2.0;
    let o = vec![
        format!("link.delay_ms={d}"),
        format!("link.jitter_ms={}", 0.2 * d),
        "link.loss=0.05".to_string(),
    ];
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

/// The verdict: stable by the delay matrix's detector. Measured 2026-12-02 (seed
/// 11): 100 ms unstable by one "bounce" (the revolution-averaged true force fell below the
/// contact-lost level and rose past 2 N again while the operator pushed; not analysed yet);
/// 500 ms unstable (1 bounce, 168 watchdog safe stops from the jitter beyond the watchdog,
/// a fifth of the pocket cut).
#[test]
#[ignore = "figure: detector says unstable at 100 ms (1 bounce) and 500 ms (1 bounce, 168 safe stops); see docs/cutting.md"]
fn stable_by_the_detector_at_100_and_500_ms() {
    for rt in [100.0, 500.0] {
        let (s, _) = run(rt);
        assert!(s.stable, "{rt} ms: {:?}", s.unstable_reasons);
    }
}
